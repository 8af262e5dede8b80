"""DDS domain ids for test processes: each one held by exactly one process on this machine.

A test process (each pytest-xdist worker too) takes an exclusive lock on a file per
domain id, tried in random order; the lock lasts as long as the process. Two test runs
at once (two checkouts, two users), two workers of one run, and a test that needs extra
graphs of its own then never share a domain and never hear each other's nodes.
"""

from __future__ import annotations

import fcntl
import os
import random
import tempfile

DOMAIN_RANGE = (1, 200)
"""Domain ids handed out. ROS 2 allows 0-232 on Linux; 0 (every other program's default) is
left out."""

_held: dict[int, int] = {}
"""Domain id -> open lock file, for the ids this process holds (until it exits or releases)."""


class NoFreeDomainError(RuntimeError):
    """Every domain id of :data:`DOMAIN_RANGE` is held by other processes."""


def lock_path(domain_id: int) -> str:
    """The lock file of ``domain_id`` (in the temporary directory, shared by every run)."""
    return os.path.join(tempfile.gettempdir(), "infomax_contingency-domains", f"{domain_id}.lock")


def lock_domain_ids(count: int) -> list[int]:
    """``count`` domain ids that no other process of any test run holds, now held by this one.

    The domain this process is on (``ROS_DOMAIN_ID``, locked or forced) is never one of them.
    """
    low, high = DOMAIN_RANGE
    current = os.environ.get("ROS_DOMAIN_ID", "").strip()
    candidates = [d for d in range(low, high + 1) if str(d) != current]
    random.SystemRandom().shuffle(candidates)
    directory = os.path.dirname(lock_path(low))
    if not os.path.isdir(directory):
        os.makedirs(directory, exist_ok=True)
        try:  # shared by every user's runs, like /tmp itself
            os.chmod(directory, 0o1777)
        except OSError:
            pass
    taken: list[int] = []
    for domain_id in candidates:
        if len(taken) == count:
            break
        try:
            fd = os.open(lock_path(domain_id), os.O_CREAT | os.O_RDWR, 0o666)
        except OSError:  # another user's file, not writable here: theirs
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            continue
        try:
            os.fchmod(fd, 0o666)  # for other users' runs, whatever the umask
        except OSError:
            pass
        _held[domain_id] = fd
        taken.append(domain_id)
    if len(taken) < count:
        raise NoFreeDomainError(
            f"only {len(taken)} of {count} ROS domain ids in {low}..{high} are free:"
            " the others are held by other test runs"
        )
    return taken


def release_domain_ids(domain_ids: list[int]) -> None:
    """Give back ids taken with :func:`lock_domain_ids` (once nothing uses them any more)."""
    for domain_id in domain_ids:
        fd = _held.pop(domain_id, None)
        if fd is not None:
            os.close(fd)  # closing the file releases its lock
