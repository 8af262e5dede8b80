"""ROS 2 nodes: the executables and the thin rclpy shell around the core.

One node per module with a ``main()`` that the console script of the same name (and
``ros2 run infomax_contingency <name>``) calls; the shell they share is ``qos.py`` (QoS
profiles), ``parameters.py`` (declared, range-checked parameters), ``graph_node.py``
(the base node) and ``runtime.py`` (``main()``'s body). No mathematics lives here. May
import ``core``, ``audio`` and ``sim`` (the fake room), never ``eval``, ``cli`` or
``testing``. Importing this package imports nothing from rclpy; each node module does.
"""
