"""Test-suite setup: keep every DDS participant on this machine and on a private domain.

This runs before any test module is imported, so before anything imports rclpy. Child
processes started by tests inherit the environment set here.

Fast DDS runs with the suite's profile, ``test/fastdds_quick.xml`` (announcements every
0.5 s, writer heartbeats every 0.2 s; the defaults: 3 s and 3 s), unless the caller chose a
profile: a graph's processes find each other and a stopping node's acknowledgment wait
ends within a fraction of a second instead of up to 3 s. Tests marked ``dds_defaults``
start their processes with Fast DDS's defaults, as a robot's nodes run (the test process
itself keeps the profile: Fast DDS reads it once per process).

Every process of the suite uses one BLAS thread, as the nodes' entry points give theirs
(``use_one_blas_thread``): a thread per core in each of hundreds of processes only costs
start-up CPU on a machine the suite already keeps busy.

Ctrl-C reaches the suite's child processes as it would from a terminal: a suite started
where SIGINT is ignored (a background job of a script, ``nohup``) would hand that on to
every child, and the tests of what a Ctrl-C does would wait for nothing.
"""

import os
import signal
from pathlib import Path

import pytest

import speech_bank
from colcon_workspace import shared_workspace
from domains import NoFreeDomainError, lock_domain_ids
from infomax_contingency.nodes.entry import use_one_blas_thread

use_one_blas_thread()

if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:  # children inherit an ignored signal
    signal.signal(signal.SIGINT, signal.default_int_handler)

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


PROFILES_VARIABLE = "FASTRTPS_DEFAULT_PROFILES_FILE"
"""Where Fast DDS 2.14 (Jazzy) looks for a profiles file (FASTDDS_... is the 3.x name)."""

SUITE_PROFILES = Path(__file__).with_name("fastdds_quick.xml")
"""The suite's Fast DDS profile (see the module docstring)."""

# The xdist workers inherit the controller's environment: the suite's own file there is
# still the suite's choice, so that dds_defaults tests leave it out in the workers too.
SUITE_CHOSE_PROFILES = os.environ.get(PROFILES_VARIABLE, "") in ("", str(SUITE_PROFILES))
if SUITE_CHOSE_PROFILES:
    os.environ[PROFILES_VARIABLE] = str(SUITE_PROFILES)


def pytest_configure(config: pytest.Config) -> None:
    """Register the markers used by the suite."""
    config.addinivalue_line(
        "markers", "slow: long-running test (several seconds or more); deselect with -m 'not slow'"
    )


@pytest.fixture(autouse=True)
def dds_defaults(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> None:
    """A ``dds_defaults`` test starts its processes with Fast DDS's own defaults."""
    if SUITE_CHOSE_PROFILES and request.node.get_closest_marker("dds_defaults"):
        monkeypatch.delenv(PROFILES_VARIABLE)


def pytest_report_header(config: pytest.Config) -> str:
    """Show the DDS isolation settings at the top of the run."""
    return (
        f"ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']} "
        f"ROS_AUTOMATIC_DISCOVERY_RANGE={os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE']} "
        f"{PROFILES_VARIABLE}={os.environ.get(PROFILES_VARIABLE, '')}"
    )


@pytest.fixture(scope="session")
def colcon_workspace(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A colcon build of the package, one per run (see ``colcon_workspace.py``)."""
    return shared_workspace(tmp_path_factory)


@pytest.fixture(scope="session", autouse=True)
def shared_speech_bank(tmp_path_factory: pytest.TempPathFactory) -> None:
    """espeak-ng's speech bank rendered once per run for every worker (``speech_bank.py``)."""
    speech_bank.install(tmp_path_factory.getbasetemp())
