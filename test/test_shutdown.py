"""Stopping under load: SIGTERM, and Ctrl-C twice, end a stepping graph without a traceback.

Four ``bringup --fake-room`` processes step their lockstep graphs as fast as they can
(each on a DDS domain of its own), which loads both cores; once each has started its
step clock it gets a different ending: SIGTERM, SIGINT twice in a row, SIGINT then
SIGTERM, and a node process on its own gets SIGINT twice.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from domains import lock_domain_ids, release_domain_ids
from processes import read_until, readline_within

# The graph tests that start many node processes run one at a time (on one pytest-xdist
# worker, with `--dist loadgroup`), so that they do not starve each other of CPU.
pytestmark = pytest.mark.xdist_group("node_graphs")

ROOT = Path(__file__).resolve().parent.parent
STARTED = "starting the step clock"

ENDINGS = {
    "sigterm": (signal.SIGTERM,),
    "sigterm_again": (signal.SIGTERM,),
    "sigint_twice": (signal.SIGINT, signal.SIGINT),
    "sigint_then_sigterm": (signal.SIGINT, signal.SIGTERM),
}


def _bringup(domain: int) -> subprocess.Popen:
    command = [sys.executable, "-m", "infomax_contingency.nodes.bringup", "--fake-room",
               "--ros-args", "--params-file", str(ROOT / "config" / "robot.yaml"),
               "--params-file", str(ROOT / "config" / "fake_room.yaml")]  # fmt: skip
    env = {**os.environ, "ROS_DOMAIN_ID": str(domain)}
    return subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, env=env)  # fmt: skip


@pytest.mark.slow
def test_a_stepping_graph_ends_cleanly_on_every_signal() -> None:
    domains = lock_domain_ids(len(ENDINGS))  # a graph each, heard by no other test
    processes = {name: _bringup(domain) for name, domain in zip(ENDINGS, domains, strict=True)}
    outputs = {}
    try:
        for name, process in processes.items():
            outputs[name] = read_until(process, STARTED)
            assert STARTED in outputs[name] and process.poll() is None, outputs[name]
        for name, process in processes.items():
            for sig in ENDINGS[name]:
                process.send_signal(sig)
        for name, process in processes.items():
            out, _ = process.communicate(timeout=60)
            outputs[name] += out
    finally:
        for process in processes.values():
            if process.poll() is None:
                process.kill()
                process.communicate()
        release_domain_ids(domains)
    for name, process in processes.items():
        assert process.returncode == 0, f"{name}: {outputs[name]}"
        assert "Traceback" not in outputs[name], f"{name}: {outputs[name]}"
        assert "RCLError" not in outputs[name], f"{name}: {outputs[name]}"


def test_a_node_stopped_with_ctrl_c_twice_says_nothing_more() -> None:
    command = [sys.executable, "-m", "infomax_contingency.nodes.controller_node"]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                               text=True)  # fmt: skip
    try:
        first = readline_within(process)  # the node logs its table once it is up
        assert "receding, horizon 24" in first, first
        process.send_signal(signal.SIGINT)
        process.send_signal(signal.SIGINT)
        out, _ = process.communicate(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    assert process.returncode == 0, out
    assert "Traceback" not in out and "KeyboardInterrupt" not in out, out
