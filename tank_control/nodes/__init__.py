"""Thin rclpy adapters around core objects: plant_node, controller_node, reference_node.

Importing the package sets single-threaded BLAS unless the environment says otherwise: a
node solves one small problem per sample, and a multi-threaded BLAS only adds wake-up latency
and contention on a small machine (MPCS rebuild times: bench/RESULTS.md, "MPCS"). This must
happen before numpy is imported, which is why it lives in the package's ``__init__``.
"""
import os

for _var in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_var, '1')
del _var
