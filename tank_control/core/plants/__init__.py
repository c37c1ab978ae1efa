"""Plant models (pure numpy/scipy): IPDT, FOPDT, the nonlinear mixing tank; delay lines; noise.

Each model has a configuration dataclass whose fields are its parameters and changes them live
with ``configure(**changes)`` (all-or-nothing, ``ValueError`` with a one-line reason). The kinds
plant_node offers are in ``kinds/registry.py``.
"""
