"""Worker processes of the experiments: a pool that a Ctrl-C ends at once and quietly.

A Ctrl-C in a terminal reaches every process of the foreground group. The workers of
:func:`worker_pool` ignore it (no traceback from each of them); the parent gets the
KeyboardInterrupt, ends the workers (their running tasks are lost: the command is being
stopped) and lets it go on to the command line, which exits with status 130.
"""

from __future__ import annotations

import contextlib
import os
import signal
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor

from infomax_contingency.lifetime import signal_when_parent_dies

WORKERS_PER_CPU = 4
"""Most worker processes per CPU an experiment may start (more only cost memory and
start-up: the results do not depend on the number)."""
WORKER_BYTES = 100 * 2**20
"""Memory of one worker process before its first run (the interpreter, numpy, the
package; measured 60-90 MB resident), bytes: the experiments' estimates count it."""


def max_workers() -> int:
    """The most worker processes an experiment may start: :data:`WORKERS_PER_CPU` per CPU."""
    return WORKERS_PER_CPU * (os.cpu_count() or 1)


def check_workers(count: int, option: str) -> None:
    """ValueError (one line) for a number of worker processes below 1 or above :func:`max_workers`.

    ``option`` names it in the message (``"--workers"``).
    """
    if not 1 <= count <= max_workers():
        raise ValueError(f"{option} {count}: give 1 .. {max_workers()} processes"
                         f" ({WORKERS_PER_CPU} per CPU, os.cpu_count() = {os.cpu_count()})")


def _start_worker(parent: int) -> None:
    """A worker ignores Ctrl-C, and ends with the command that started it.

    The command may die without ending its workers (SIGKILL, an OOM kill, a CI timeout):
    they then get SIGTERM rather than compute on for minutes with nobody to read it.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal_when_parent_dies(signal.SIGTERM)
    if os.getppid() != parent:  # the command died before the signal was asked for
        os._exit(1)


def _end(pool: ProcessPoolExecutor) -> None:
    """Kill the workers (their running tasks are lost) and wait for the pool to end."""
    # shutdown alone would leave the running tasks to finish (minutes)
    for process in list((getattr(pool, "_processes", None) or {}).values()):
        process.kill()
    pool.shutdown(wait=True, cancel_futures=True)


@contextlib.contextmanager
def worker_pool(workers: int) -> Iterator[ProcessPoolExecutor]:
    """A ``ProcessPoolExecutor`` of ``workers`` processes, ended at once by an exception.

    While the workers start, a Ctrl-C is held (a worker hit before its initializer ran
    would die and break the pool) and raised once they run; a worker started later gets
    it only between its start and its initializer.
    """
    check_workers(workers, "workers")
    held: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: held.append(signum))
    try:
        pool = ProcessPoolExecutor(max_workers=workers, initializer=_start_worker,
                                   initargs=(os.getpid(),))
        pool.submit(int).result()  # starts the workers (all of them, with fork)
    finally:
        signal.signal(signal.SIGINT, previous)
    try:
        if held:
            raise KeyboardInterrupt
        yield pool
    except BaseException:
        _end(pool)
        raise
    pool.shutdown()
