"""Test-suite setup: keep every DDS participant on this machine and on a private domain.

This runs before any test module is imported, so before anything imports rclpy. Child
processes started by tests inherit the environment set here.
"""

import os
from pathlib import Path

import pytest

from colcon_workspace import shared_workspace
from domains import NoFreeDomainError, lock_domain_ids

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
_forced = os.environ.get("INFOMAX_TEST_DOMAIN_ID", "").strip()
if _forced:
    if not _forced.isdigit() or not 0 <= int(_forced) <= 232:
        raise pytest.UsageError(
            f"INFOMAX_TEST_DOMAIN_ID={_forced!r}: expected an integer in 0..232"
        )
    os.environ["ROS_DOMAIN_ID"] = _forced
else:
    try:
        os.environ["ROS_DOMAIN_ID"] = str(lock_domain_ids(1)[0])
    except NoFreeDomainError as error:
        raise pytest.UsageError(str(error)) from None


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


@pytest.fixture(scope="session")
def colcon_workspace(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A colcon build of the package, one per run (see ``colcon_workspace.py``)."""
    return shared_workspace(tmp_path_factory)
