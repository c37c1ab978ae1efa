"""Example kinds for tank_control (docs/extending.md): ``on_off`` and ``heater``."""
