"""Worker processes of the experiments: a pool that a Ctrl-C ends at once and quietly.

A Ctrl-C in a terminal reaches every process of the foreground group. The workers of
:func:`worker_pool` ignore it (no traceback from each of them); the parent gets the
KeyboardInterrupt, ends the workers (their running tasks are lost: the command is being
stopped) and lets it go on to the command line, which exits with status 130.
"""

from __future__ import annotations

import contextlib
import signal
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor


def _ignore_interrupts() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)


@contextlib.contextmanager
def worker_pool(workers: int) -> Iterator[ProcessPoolExecutor]:
    """A ``ProcessPoolExecutor`` of ``workers`` processes, ended at once by an exception."""
    pool = ProcessPoolExecutor(max_workers=workers, initializer=_ignore_interrupts)
    try:
        yield pool
    except BaseException:
        # shutdown(wait=False) alone would leave the running tasks to finish (minutes)
        for process in list((getattr(pool, "_processes", None) or {}).values()):
            process.terminate()
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown()
