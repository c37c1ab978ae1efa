"""Public entry point of the tuning rules: ``from tank_control.tuning import tune``.

See ``tank_control.core.tuning.rules`` for the rules and their sources.
"""
from tank_control.core.tuning.rules import RULES, tune

__all__ = ['RULES', 'tune']
