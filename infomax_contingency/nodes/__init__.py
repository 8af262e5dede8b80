"""ROS 2 nodes: thin rclpy shells around the core (one node per module).

Importing this package imports nothing from rclpy; each node module does. Every module
has a ``main()`` that the console script of the same name (and ``ros2 run
infomax_contingency <name>``) calls.
"""
