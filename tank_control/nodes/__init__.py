"""Thin rclpy adapters around core objects.

A control node computes one small problem per sample; a multi-threaded BLAS
only adds wake-up latency and contention on a small machine (seen: an MPCS
rebuild taking ~1 s instead of ~0.1 s on 2 loaded cores). Nodes therefore run
single-threaded BLAS unless the user asks otherwise. This must happen before
numpy is imported, which is why it lives in the package's ``__init__``.
"""
import os

for _var in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_var, '1')
del _var
