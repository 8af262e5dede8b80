"""A process that ends with its parent, and one stopped while it starts.

The parent-death signal and a liveness check; and whether a stop signal came while a node
process was still starting (:func:`note_stop_while_starting`). No rclpy, no package
imports: node processes (:mod:`~infomax_contingency.nodes.entry`,
:mod:`~infomax_contingency.nodes.runtime`) and the experiments' worker processes
(:mod:`~infomax_contingency.eval.workers`) use it.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
from pathlib import Path

_PR_SET_PDEATHSIG = 1
"""``prctl`` option (linux/prctl.h): the signal this process gets when its parent dies."""


def signal_when_parent_dies(signum: int = signal.SIGTERM) -> None:
    """Ask the kernel to send this process ``signum`` when its parent thread dies (Linux).

    Elsewhere nothing happens. The parent is the thread that started this process; a
    caller that must not outlive a parent which died before this call checks
    :func:`process_alive` (or ``os.getppid()``) after it.
    """
    if sys.platform.startswith("linux"):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, int(signum), 0, 0, 0)


def process_alive(pid: int) -> bool:
    """True while ``pid`` runs (a zombie, dead but not yet reaped, does not count)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        return False
    except OSError:  # no /proc: ask the kernel (a zombie then counts as alive)
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        except PermissionError:
            return True
        return True
    return stat.rsplit(")", 1)[1].split()[0] not in ("Z", "X")


_stop_while_starting = [False]  # one per process, however the node's entry module was run


def note_stop_while_starting(came: bool = True) -> None:
    """Note (``came``) or forget that a stop signal came before the node's ``main()`` took over.

    Kept here rather than in :mod:`~infomax_contingency.nodes.entry`: run with ``python -m``,
    that module is ``__main__``, and the node's own modules import a second copy of it.
    """
    _stop_while_starting[0] = came


def stop_came_while_starting() -> bool:
    """True once :func:`note_stop_while_starting` noted a stop (until it is forgotten)."""
    return _stop_while_starting[0]
