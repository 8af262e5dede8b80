"""The ``infomax-contingency`` command line.

The ``infomax-contingency`` command line: offline tools (solve, info, simulate),
experiments, live-audio tools and the demo.

The top layer: may import every other subpackage. ``main.py`` holds the entry point; the
ROS parts (``demo``) import rclpy only when their command runs, so the offline commands
start without ROS.
"""

import signal
import sys
from typing import Any

INTERRUPTED_STATUS = 130
"""Exit status after a Ctrl-C (128 + SIGINT), as a shell reports it."""


def run() -> int:
    """The ``infomax-contingency`` console script: ``main.main()``, quiet on an early Ctrl-C.

    The command line loads numpy, the bag reader and every command's module before
    ``main()`` runs (1 s on a quiet machine, seconds on a loaded one); a Ctrl-C then is
    one line and status 130 too, as it is later — also when it lands inside a C extension
    module's import, which turns it into an ImportError.
    """
    interrupted: list[int] = []

    def on_interrupt(signum: int, frame: Any) -> None:
        interrupted.append(signum)
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGINT, on_interrupt)
    try:
        from infomax_contingency.cli.main import main
    except BaseException:
        if not interrupted:
            raise
        print("infomax-contingency: interrupted", file=sys.stderr)
        return INTERRUPTED_STATUS
    finally:
        signal.signal(signal.SIGINT, previous)
    return main()
