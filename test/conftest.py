"""Test-suite setup: keep every DDS participant on this machine and on a private domain.

This runs before any test module is imported, so before anything imports rclpy. Child
processes started by tests inherit the environment set here.
"""

import hashlib
import os
import random

import pytest

#: Domain ids used when the environment does not force one. ROS 2 allows 0-232 on Linux;
#: 0 (the default every other ROS program uses) is left out.
_DOMAIN_RANGE = (1, 200)



def _run_domain_id() -> int:
    """A fresh domain id per run, so that test runs in parallel do not hear each other.

    Under pytest-xdist every worker process imports this file: the workers of one run
    share a random base (from the run's id) and add their worker number to it, so two
    workers of one run never share a domain.
    """
    low, high = _DOMAIN_RANGE
    run_id = os.environ.get("PYTEST_XDIST_TESTRUNUID", "")
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    if not run_id or not worker.removeprefix("gw").isdigit():
        return random.SystemRandom().randint(low, high)
    base = int(hashlib.sha256(run_id.encode()).hexdigest(), 16)
    return low + (base + int(worker.removeprefix("gw"))) % (high - low + 1)


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
