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

    On the timeout the process is killed (its pipe then ends, and the reader with it).
    """
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.append(process.stdout.readline()), daemon=True)
    reader.start()
    reader.join(timeout_s)
    if reader.is_alive():
        process.kill()
        reader.join(10.0)
        raise AssertionError(f"pid {process.pid} wrote no line within {timeout_s:g} s")
    return lines[0]


def read_until(process: subprocess.Popen, marker: str, timeout_s: float = LINE_TIMEOUT_S) -> str:
    """The output up to and including the first line holding ``marker`` (or up to its end).

    AssertionError (the process killed) when neither comes within ``timeout_s`` in all.
    """
    deadline = time.monotonic() + timeout_s
    seen: list[str] = []
    while True:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            process.kill()
            raise AssertionError(f"no {marker!r} within {timeout_s:g} s in:\n{''.join(seen)}")
        line = readline_within(process, remaining)
        seen.append(line)
        if not line or marker in line:
            return "".join(seen)
