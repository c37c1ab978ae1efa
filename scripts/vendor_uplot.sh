#!/usr/bin/env bash
# Vendor uPlot (the dashboard's plotting library) from the npm registry into the package's
# static folder, so that the dashboard serves every asset itself and works offline.
# Usage: scripts/vendor_uplot.sh [VERSION]   (needs npm; the files are committed)
set -euo pipefail
VERSION="${1:-1.6.32}"
DEST="$(cd "$(dirname "$0")/.." && pwd)/tank_control/dashboard/static/vendor"
WORK="$(mktemp -d)"
trap 'rm -rf "$WORK"' EXIT
(cd "$WORK" && npm pack --silent "uplot@$VERSION" >/dev/null && tar xzf "uplot-$VERSION.tgz")
mkdir -p "$DEST"
cp "$WORK/package/dist/uPlot.iife.min.js" "$WORK/package/dist/uPlot.min.css" "$DEST/"
cp "$WORK/package/LICENSE" "$DEST/uPlot.LICENSE.txt"
echo "uPlot $VERSION" > "$DEST/VERSION.txt"
echo "uPlot $VERSION vendored into $DEST"
