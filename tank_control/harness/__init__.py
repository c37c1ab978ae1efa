"""Launch-free scenario harness: processes, recording, metrics, plots, CLI."""
