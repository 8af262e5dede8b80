"""Infomax contingency detection for ROS 2.

A robot finds out, from sound alone, whether someone in the room responds to it, and
chooses when to vocalize so that it finds out as fast as possible. The core modules
(model, solver, policy tables, audio, simulated world) import no ROS code; the nodes in
``infomax_contingency.nodes`` are thin rclpy shells around them.
"""

__version__ = "0.1.0"
