"""Controllers (pure numpy): 2-DOF PID, two-loop PI with decoupling, Smith predictor, relay
auto-tuner, MPCS; the kinds controller_node offers are in ``kinds/registry.py``."""
