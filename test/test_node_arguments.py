"""Malformed --ros-args end a node with one line and status 2, not a traceback."""

from __future__ import annotations

import subprocess
import sys

import pytest


@pytest.mark.parametrize("module", ["belief_node", "bringup"])
def test_malformed_ros_arguments(module: str) -> None:
    result = subprocess.run(
        [sys.executable, "-m", f"infomax_contingency.nodes.{module}", "--ros-args", "-p", "x:="],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2
    assert f"{module}: invalid ROS arguments" in result.stderr
    assert "x:=" in result.stderr
    assert "Traceback" not in result.stderr
