"""Thin rclpy nodes wrapping memo_ros.core: parameters, QoS, conversions, diagnostics.

Every node is one process among several on the same cores (a contour_node per camera, the selector,
the tracker): numpy's BLAS and OpenCV get one thread each, unless the environment says otherwise,
so that the processes do not fight over the cores with idle-spinning worker threads (the tracker's
CPU per frame fell from about 100 ms to about 25 ms on two shared cores).
"""

import os

for _variable in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_variable, '1')
