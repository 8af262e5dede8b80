"""The ``infomax-contingency`` command line.

The ``infomax-contingency`` command line: offline tools (solve, info, simulate),
experiments, live-audio tools and the demo.

The top layer: may import every other subpackage. ``main.py`` holds the entry point; the
ROS parts (``demo``) import rclpy only when their command runs, so the offline commands
start without ROS.
"""
