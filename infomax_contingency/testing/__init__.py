"""Running the node graph as separate processes and watching it.

The process harness and recorder used by the test suite, the benchmarks and
the demo, and the lean instrument nodes (no parameter or type-description
services, no default event callbacks) that tests and benchmarks watch with.

Imports rclpy. May import every subpackage except ``cli``.
"""
