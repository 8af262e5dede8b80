"""Running the node graph as separate processes and watching it.

Running the node graph as separate processes and watching it: the process
harness and recorder used by the test suite, the benchmarks and the demo.

Imports rclpy. May import every subpackage except ``cli``.
"""
