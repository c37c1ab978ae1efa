// tank_control dashboard: the loop monitor's indices per loop on a controller's faceplate
// (docs/monitoring.md, docs/dashboard.md). controller_node's /diagnostics carries, per loop y,
// `loop_performance.<y>` (the verdict, shown as a badge) and `loop_indices.<y>` (compact JSON
// of the indices: tank_control/nodes/loop_performance.py `indices_field`); this draws one line
// under the loop's SP/PV/OP meters: Harris index (with its dead time), oscillation, stiction,
// time saturated, in manual and on the fail-safe output.
'use strict';

window.tankLoops = (() => {
  const PREFIX = 'loop_indices.';
  const num = (v, digits = 2) => (typeof v === 'number' && Number.isFinite(v) ? v.toFixed(digits) : '–');
  const pct = (v) => (typeof v === 'number' && Number.isFinite(v) ? `${v.toFixed(0)} %` : '–');

  function parts(ix, verdict) {
    const harris = typeof ix.harris_index === 'number'
      ? `${num(ix.harris_index)}${typeof ix.dead_time === 'number' ? ` (L ${Number(ix.dead_time.toPrecision(3))} s)` : ''}`
      : '–';
    const osc = ix.oscillation
      ? `${Number(ix.period.toPrecision(3))} s, amplitude ${Number(ix.amplitude.toPrecision(3))}` : 'none';
    const stiction = typeof ix.stiction_index === 'number'
      ? `${ix.stiction ? 'suspected' : 'no'} (index ${num(ix.stiction_index)})` : 'not assessed';
    return [
      ['verdict', 'verdict', verdict || '–', 'the loop monitor\'s verdict over its window'],
      ['harris', 'Harris', harris, ix.harris_reason || 'minimum-variance benchmark: 1 = minimum variance (L: the dead time used)'],
      ['oscillation', 'oscillation', osc, 'regular oscillation of the control error (period, amplitude)'],
      ['stiction', 'stiction', stiction, 'Horch cross-correlation test, on an oscillating loop'],
      ['saturation', 'saturated', pct(ix.saturation_pct), 'time with the output at a limit'],
      ['manual', 'manual', pct(ix.manual_pct), 'time in manual mode'],
      ['fail-safe', 'fail-safe', pct(ix.fail_safe_pct), 'time on the held / fail-safe output'],
    ];
  }

  // fields: the node's /diagnostics values; box: its faceplate (with .loop[data-loop] parts)
  function show(box, fields) {
    for (const [key, text] of Object.entries(fields || {})) {
      if (!key.startsWith(PREFIX)) continue;
      const y = key.slice(PREFIX.length);
      const loop = box.querySelector(`.loop[data-loop="${CSS.escape(y)}"]`);
      if (!loop) continue;
      let ix;
      try { ix = JSON.parse(text); } catch (e) { continue; }   // a truncated or foreign value
      if (!ix || typeof ix !== 'object') continue;
      let line = loop.querySelector('.loop-indices');
      if (!line) {
        line = document.createElement('div');
        line.className = 'loop-indices';
        line.setAttribute('data-testid', `indices-${y}`);
        loop.append(line);
      }
      const shown = parts(ix, fields[`loop_performance.${y}`]);
      const signature = JSON.stringify(shown);
      if (line.dataset.text === signature) continue;
      line.dataset.text = signature;
      line.replaceChildren(...shown.map(([id, label, value, title]) => {
        const item = document.createElement('span');
        item.setAttribute('data-testid', id);
        item.title = title;
        const b = document.createElement('b');
        b.textContent = value;
        item.append(`${label} `, b);
        return item;
      }));
    }
  }

  return {show};
})();
