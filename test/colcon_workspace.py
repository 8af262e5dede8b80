"""One colcon build of the package per test run, shared by the tests that need the layout.

The colcon layout test, the ``ros2 run`` layout test and the ``ros2 launch`` tests all
read the same install tree and none changes it, so it is built once: the first pytest-xdist
worker that asks builds it under the run's shared temporary directory, holding a lock
the other worker waits on.
"""

from __future__ import annotations

import fcntl
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PKG = "infomax_contingency"


def colcon_build(workspace: Path) -> Path:
    """Build the package into ``workspace``; returns its install prefix."""
    venv_bin = str(Path(sys.executable).parent)
    colcon = shutil.which("colcon", path=venv_bin) or shutil.which("colcon")
    if colcon is None:
        pytest.skip("colcon is not installed (make setup installs it)")
    env = dict(os.environ)
    env["AMENT_PREFIX_PATH"] = os.pathsep.join(
        p for p in (sys.prefix, env.get("AMENT_PREFIX_PATH", "")) if p
    )
    env["PATH"] = os.pathsep.join((venv_bin, env.get("PATH", "")))
    command = [colcon, "--log-base", str(workspace / "log"), "build", "--base-paths", str(ROOT)]
    command += ["--packages-select", PKG, "--build-base", str(workspace / "build")]
    command += ["--install-base", str(workspace / "install")]
    result = subprocess.run(
        command, cwd=workspace, env=env, capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 0, result.stdout + result.stderr
    # setuptools byte-compiles what it installs only where PYTHONDONTWRITEBYTECODE is not
    # set; the nodes the tests start from this tree should not compile it each time.
    compile_all = [sys.executable, "-m", "compileall", "-q", str(workspace / "install")]
    compiled = subprocess.run(compile_all, capture_output=True, text=True, timeout=300)
    assert compiled.returncode == 0, compiled.stdout + compiled.stderr
    return workspace / "install" / PKG


def shared_workspace(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The run's colcon workspace, built on first use.

    Its install prefix is ``WORKSPACE/install/infomax_contingency``. Tests read it and
    never change it (they write their own files beside it, not into ``install``).
    """
    base = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        base = base.parent  # shared by the workers of this run
    workspace = base / "colcon_ws"
    built = workspace / "built"
    with (base / "colcon_ws.lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not built.is_file():
            shutil.rmtree(workspace, ignore_errors=True)  # a build that failed half-way
            workspace.mkdir()
            colcon_build(workspace)
            built.touch()
    return workspace
