"""Helpers shared by the tests (importable as ``support.*``; pytest.ini puts test/ on the path)."""
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
CONFIG = REPO / 'config'
SCENARIOS = CONFIG / 'scenarios'
