"""Online structural mode identification (recursive DSRA) for ROS 2.

Subpackages: ``core`` (pure numpy/scipy numerics, no rclpy), ``tools`` (command-line
executables). Modules at this level adapt the core to ROS topics and bags.
"""
