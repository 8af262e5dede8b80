"""The body of every node's ``main()``: ROS argument parsing, spinning, clean shutdown.

:func:`run_node` spins the node until it is done or interrupted (Ctrl-C, SIGTERM) and
ends with ``rclpy.try_shutdown()``.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.node import Node
from rclpy.task import Future

from infomax_contingency.errors import USER_ERRORS


def init_ros(args: Sequence[str] | None, program: str) -> bool:
    """``rclpy.init``; malformed ``--ros-args`` give one line on stderr and False."""
    try:
        rclpy.init(args=args)
    except rclpy_implementation.RCLError as error:
        reason = str(error).split(", at ")[0]
        print(
            f"{program}: invalid ROS arguments: {reason} (a parameter is given as"
            " `-p name:=value` with a non-empty value)",
            file=sys.stderr,
        )
        return False
    return True


def run_node(factory: Callable[[], Node], args: Sequence[str] | None = None) -> int:
    """Create the node, spin it until it finishes or is interrupted; return the exit status.

    Bad parameters and other user errors are logged as one error line (status 2);
    Ctrl-C and SIGTERM end the node cleanly (status 0).
    """
    if not init_ros(args, getattr(factory, "NODE_NAME", "node")):
        return 2
    executor = SingleThreadedExecutor()
    node = None
    try:
        node = factory()
        executor.add_node(node)
        finished = getattr(node, "finished", None) or Future()
        executor.spin_until_future_complete(finished)
        return int(finished.result()) if finished.done() else 0
    except (KeyboardInterrupt, ExternalShutdownException):
        return 0
    except USER_ERRORS as error:
        name = node.get_name() if node is not None else getattr(factory, "NODE_NAME", "node")
        rclpy.logging.get_logger(name).error(str(error))
        return 2
    except Exception:
        if not rclpy.ok():  # Ctrl-C or SIGTERM while the node was being set up
            return 0
        raise
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()

