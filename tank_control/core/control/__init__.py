"""Controllers (pure numpy): 2-DOF PID, two-loop PI with decoupling, Smith predictor."""
from tank_control.core.control.pid import Pid2Dof, PidConfig, PidController, pid_params

__all__ = ['Pid2Dof', 'PidConfig', 'PidController', 'pid_params']
