"""The conformance kit for controller and plant kinds (docs/extending.md, "Testing a kind").

``check_controller_kind(kind, values)`` and ``check_plant_kind(kind, values)`` run the
contract every built-in kind meets and raise :class:`ContractError` naming the property that
broke, with numbers; ``run_scenario(path, overrides)`` runs a scenario file and returns its
metrics; ``check_lockstep(path)`` compares a lockstep ROS run with the in-process loop.
Installed as a pytest plugin (entry point ``pytest11``: :mod:`tank_control.testing.plugin`),
which offers the fixture ``tank_control_run`` (``run_scenario`` writing under the test's
``tmp_path``).
"""
from tank_control.testing.contract import (ContractError, ContractReport, check_controller_kind,
                                           check_lockstep, check_plant_kind, run_scenario)

__all__ = ['ContractError', 'ContractReport', 'check_controller_kind', 'check_plant_kind',
           'check_lockstep', 'run_scenario']
