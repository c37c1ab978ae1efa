"""Controller tuning rules (000, 001, 004); see rules.py."""
from tank_control.core.tuning.rules import RULES, tune

__all__ = ["RULES", "tune"]
