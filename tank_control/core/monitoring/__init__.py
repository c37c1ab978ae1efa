"""Control performance monitoring: indices from routine data, a verdict per loop (docs/monitoring.md)."""
from tank_control.core.monitoring.assess import (LoopMonitor, MonitorConfig, assess,
                                                 diagnostics_line, loop_monitors, verdict)

__all__ = ['LoopMonitor', 'MonitorConfig', 'assess', 'diagnostics_line', 'loop_monitors',
           'verdict']
