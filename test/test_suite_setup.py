"""The test suite's own setup: what `make test` relies on to run the graph tests safely."""

from __future__ import annotations

import fcntl
import os

import pytest

from domains import lock_domain_ids, lock_path, release_domain_ids


@pytest.mark.xdist_group("node_graphs")
def test_the_node_graph_group_reaches_the_scheduler(request: pytest.FixtureRequest) -> None:
    """With ``--dist loadgroup`` the tests marked ``node_graphs`` share one worker.

    pytest-xdist puts the group into the test's node id; a pytest that ignores it (pytest
    9 with xdist 3.8) runs two node graphs at once, each starving the other of CPU.
    """
    if not getattr(request.config.option, "loadgroup", False):
        pytest.skip("not run with --dist loadgroup (make test runs with it)")
    assert request.node.nodeid.endswith("@node_graphs"), request.node.nodeid


def test_every_test_process_has_a_domain_of_its_own() -> None:
    """The worker's domain and extra ones locked for a test are all different, and held.

    (A domain forced with INFOMAX_TEST_DOMAIN_ID is the caller's choice, and not locked.)
    """
    own = int(os.environ["ROS_DOMAIN_ID"])
    forced = bool(os.environ.get("INFOMAX_TEST_DOMAIN_ID", "").strip())
    extra = lock_domain_ids(3)
    try:
        assert len(set(extra)) == 3 and own not in extra
        # another process (another open file) cannot take them
        for domain_id in extra if forced else (own, *extra):
            fd = os.open(lock_path(domain_id), os.O_RDWR)
            try:
                with pytest.raises(BlockingIOError):
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            finally:
                os.close(fd)
    finally:
        release_domain_ids(extra)
    for domain_id in extra:  # given back: free for others again
        fd = os.open(lock_path(domain_id), os.O_RDWR)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        finally:
            os.close(fd)
    assert os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"


SUITE_PROFILES = os.path.join(os.path.dirname(os.path.abspath(__file__)), "fastdds_quick.xml")


def _caller_chose_profiles() -> bool:
    """A profile other than the suite's is set (the suite then leaves DDS as it is)."""
    import conftest

    return not conftest.SUITE_CHOSE_PROFILES and os.environ.get(
        "FASTRTPS_DEFAULT_PROFILES_FILE", ""
    ) not in ("", SUITE_PROFILES)


def test_processes_run_with_the_suite_profile_unless_the_caller_chose_one() -> None:
    """In every worker too (they inherit the controller's environment)."""
    if _caller_chose_profiles():
        pytest.skip("the caller chose a Fast DDS profile; the suite leaves it as it is")
    assert os.environ["FASTRTPS_DEFAULT_PROFILES_FILE"] == SUITE_PROFILES


@pytest.mark.dds_defaults
def test_a_dds_defaults_test_starts_its_processes_with_fast_dds_defaults() -> None:
    if _caller_chose_profiles():
        pytest.skip("the caller chose a Fast DDS profile; the suite leaves it as it is")
    assert "FASTRTPS_DEFAULT_PROFILES_FILE" not in os.environ


def test_a_tests_instruments_carry_no_services_and_the_demos_monitor_keeps_them() -> None:
    """The recorder and probe a test watches with add nothing to each wait of its executor.

    A hand-stepped graph rebuilds its wait set from every service and QoS event handler of
    its nodes several times per step; the demo's monitor, which a user may query, keeps its
    parameter services.
    """
    import rclpy
    from std_msgs.msg import Float64

    from infomax_contingency.testing.graph import StepRecorder
    from infomax_contingency.testing.stepped import Probe

    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        recorder = StepRecorder("instrument_recorder", context=context, instrument=True)
        monitor = StepRecorder("demo_monitor", context=context)
        probe = Probe(context=context)
        probe.listen("/instrument_check", Float64)
        probe.talk("/instrument_check", Float64)
        try:
            for instrument in (recorder, probe):
                assert list(instrument.services) == [], instrument.get_name()
                assert not instrument.get_parameter("start_type_description_service").value
            # the recorder's one handler per subscription counts the messages DDS lost
            assert {len(sub.event_handlers) for sub in recorder.subscriptions} == {1}
            assert [len(sub.event_handlers) for sub in probe.subscriptions] == [0]
            assert [len(pub.event_handlers) for pub in probe.pubs.values()] == [0]
            assert list(monitor.services), "the demo's monitor lost its parameter services"
            assert min(len(sub.event_handlers) for sub in monitor.subscriptions) > 1
        finally:
            for node in (recorder, monitor, probe):
                node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
