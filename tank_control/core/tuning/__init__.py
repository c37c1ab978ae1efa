"""Controller tuning rules ([Viteckova], [DeadTimeNotes], [Precup2013]); see rules.py."""
from tank_control.core.tuning.rules import RULES, tune

__all__ = ["RULES", "tune"]
