"""tank_control: process-control runtime for dead-time processes on ROS 2 Jazzy.

Importing the package sets single-threaded BLAS unless the environment says otherwise, for
the nodes and the in-process loop alike: each solves one small problem per sample, and a
multi-threaded BLAS only adds wake-up latency and contention on a small machine
(bench/RESULTS.md, "MPCS"). It must happen before numpy is imported, so it lives here.
"""
import os

for _var in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_var, '1')
del _var
