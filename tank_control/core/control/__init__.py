"""Controllers (pure numpy): 2-DOF PID, two-loop PI with decoupling, Smith predictor."""
from tank_control.core.control.multiloop import TwoLoopPi, TwoLoopPiConfig, two_loop_pi_params
from tank_control.core.control.pid import Pid2Dof, PidConfig, PidController, pid_params
from tank_control.core.control.smith import SmithConfig, SmithPredictor, smith_params

__all__ = ['Pid2Dof', 'PidConfig', 'PidController', 'pid_params',
           'TwoLoopPi', 'TwoLoopPiConfig', 'two_loop_pi_params',
           'SmithConfig', 'SmithPredictor', 'smith_params']
