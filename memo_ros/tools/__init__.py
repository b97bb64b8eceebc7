"""The `memo-ros` command line tools (third layer: built on core and rclpy).

Like the nodes (see memo_ros.nodes), the tools run numpy's BLAS on one thread unless the
environment says otherwise: they share the cores with the graph they launch or play into, and the
benchmarks measure one core.
"""

import os

for _variable in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_variable, '1')
