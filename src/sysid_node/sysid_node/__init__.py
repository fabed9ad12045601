"""Online structural mode identification (recursive DSRA) for ROS 2.

Subpackages: ``core`` (pure numpy/scipy numerics, no rclpy), ``tools`` (command-line
executables). Modules at this level adapt the core to ROS topics and bags.

Importing the package before numpy limits BLAS to one thread unless the environment says
otherwise: the DSRA's matrices have a few hundred rows at most, so extra BLAS threads gain
nothing and spin-wait on the cores the node, its worker process and the subscriptions need
(measured: a 1 kHz, 7-channel stream used 1.5 cores with the default threads).
"""

import os as _os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")
