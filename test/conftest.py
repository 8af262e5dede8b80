"""Test-suite setup: keep every DDS participant on this machine and on a private domain.

This runs before any test module is imported, so before anything imports rclpy. Child
processes started by tests inherit the environment set here.
"""

import fcntl
import os
import random
import tempfile

import pytest

#: Domain ids used when the environment does not force one. ROS 2 allows 0-232 on Linux;
#: 0 (the default every other ROS program uses) is left out.
_DOMAIN_RANGE = (1, 200)

_DOMAIN_LOCKS: list[int] = []
"""Open lock files of the domain ids this process holds (kept open until it exits)."""


def _run_domain_id() -> int:
    """A domain id that no other test process on this machine holds.

    Every test process (each pytest-xdist worker too) takes an exclusive lock on a file
    per domain id, tried in random order; the lock lasts as long as the process. Two
    test runs at once (two checkouts, two users) then never share a domain and never
    hear each other's nodes.
    """
    low, high = _DOMAIN_RANGE
    ids = list(range(low, high + 1))
    random.SystemRandom().shuffle(ids)
    directory = os.path.join(tempfile.gettempdir(), "infomax_contingency-domains")
    os.makedirs(directory, exist_ok=True)
    for domain_id in ids:
        fd = os.open(os.path.join(directory, f"{domain_id}.lock"), os.O_CREAT | os.O_RDWR, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            continue
        _DOMAIN_LOCKS.append(fd)
        return domain_id
    raise pytest.UsageError(f"every ROS domain id {low}..{high} is held by another test run")


os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
_forced = os.environ.get("INFOMAX_TEST_DOMAIN_ID", "").strip()
if _forced:
    if not _forced.isdigit() or not 0 <= int(_forced) <= 232:
        raise pytest.UsageError(
            f"INFOMAX_TEST_DOMAIN_ID={_forced!r}: expected an integer in 0..232"
        )
    os.environ["ROS_DOMAIN_ID"] = _forced
else:
    os.environ["ROS_DOMAIN_ID"] = str(_run_domain_id())


def pytest_configure(config: pytest.Config) -> None:
    """Register the markers used by the suite."""
    config.addinivalue_line(
        "markers", "slow: long-running test (several seconds or more); deselect with -m 'not slow'"
    )


def pytest_report_header(config: pytest.Config) -> str:
    """Show the DDS isolation settings at the top of the run."""
    return (
        f"ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']} "
        f"ROS_AUTOMATIC_DISCOVERY_RANGE={os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE']}"
    )
