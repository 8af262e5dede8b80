"""Reading a child process's piped output with a deadline, so that no test waits for ever.

``process.stdout.readline()`` blocks until the child writes a line or closes its
output; a child that hangs before its first line would hang the test, and with it the
whole suite. :func:`readline_within` reads on a helper thread and gives up after a
deadline, killing the child so that the read ends.
"""

from __future__ import annotations

import subprocess
import threading
import time

LINE_TIMEOUT_S = 120.0
"""Default wait for one line of a starting node or command (generous: a loaded machine)."""


def readline_within(process: subprocess.Popen, timeout_s: float = LINE_TIMEOUT_S) -> str:
    """The next line of ``process.stdout`` ("" at its end); AssertionError after ``timeout_s``.

    On the timeout the process gets SIGTERM (a command that started nodes stops them),
    then SIGKILL after 10 s; its pipe then ends, and the reader with it.
    """
    result: list[str] = []
    failure: list[BaseException] = []

    def read() -> None:
        try:
            result.append(process.stdout.readline())
        except BaseException as error:  # noqa: BLE001 - handed to the caller below
            failure.append(error)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    reader.join(timeout_s)
    if reader.is_alive():
        _stop(process)
        reader.join(10.0)
        raise AssertionError(f"pid {process.pid} wrote no line within {timeout_s:g} s")
    if failure:
        raise failure[0]
    return result[0]


def _stop(process: subprocess.Popen) -> None:
    """SIGTERM, then SIGKILL if it is still running 10 s later."""
    process.terminate()
    try:
        process.wait(10.0)
    except subprocess.TimeoutExpired:
        process.kill()


def read_until(process: subprocess.Popen, marker: str, timeout_s: float = LINE_TIMEOUT_S) -> str:
    """The output up to and including the first line holding ``marker`` (or up to its end).

    AssertionError (the process killed) when neither comes within ``timeout_s`` in all.
    """
    deadline = time.monotonic() + timeout_s
    seen: list[str] = []
    while True:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            _stop(process)
            raise AssertionError(f"no {marker!r} within {timeout_s:g} s in:\n{''.join(seen)}")
        line = readline_within(process, remaining)
        seen.append(line)
        if not line or marker in line:
            return "".join(seen)
