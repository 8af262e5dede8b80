"""Packaging checks: package.xml, setup.py, setup.cfg, resources lookup, lint config."""

import ast
import configparser
import json
import os
import subprocess
import sys
import tomllib
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

import infomax_contingency
from infomax_contingency import resources
from infomax_contingency.nodes import entry

ROOT = Path(__file__).resolve().parent.parent
HERE = Path(__file__).resolve().parent
PKG = "infomax_contingency"

EXEC_DEPENDS = {
    "rclpy",
    "std_msgs",
    "std_srvs",
    "sensor_msgs",
    "trajectory_msgs",
    "diagnostic_msgs",
    "ament_index_python",
    "python3-numpy",
    "python3-scipy",
    "python3-yaml",
    "python3-sounddevice-pip",
    "python3-rosbags-pip",
    "portaudio19-dev",
}
NO_SUCH_ROSDEP_KEYS = {
    "python3-webrtcvad-wheels-pip",
    "python3-mcap-pip",
    "python3-mcap-ros2-support-pip",
}
"""Keys that the rosdistro rules do not define: `rosdep install` stops at them
(.ci/run checks every key with ../shared/tools/rosdep/check.sh)."""
EXECUTABLES = {"infomax-contingency", *entry.NODE_MODULES}
"""The console scripts setup.py must declare: the command line and every node program."""


def _setup_call() -> ast.Call:
    tree = ast.parse((ROOT / "setup.py").read_text())
    calls = [
        node
        for node in ast.walk(tree)
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "setup"
    ]
    assert len(calls) == 1, "setup.py must call setup() exactly once"
    return calls[0]


def _setup_keyword(name: str) -> object:
    for keyword in _setup_call().keywords:
        if keyword.arg == name:
            return ast.literal_eval(keyword.value)
    raise AssertionError(f"setup.py: setup() has no literal keyword {name!r}")


@pytest.fixture(scope="module")
def package_xml() -> ET.Element:
    return ET.parse(ROOT / "package.xml").getroot()


def test_package_xml_identity(package_xml: ET.Element) -> None:
    assert package_xml.tag == "package"
    assert package_xml.get("format") == "3"
    assert package_xml.findtext("name") == PKG
    assert package_xml.findtext("license") == "Apache-2.0"
    maintainer = package_xml.find("maintainer")
    assert maintainer is not None and maintainer.get("email")
    assert package_xml.findtext("export/build_type") == "ament_python"


def test_package_xml_dependencies(package_xml: ET.Element) -> None:
    exec_depends = {element.text for element in package_xml.findall("exec_depend")}
    assert EXEC_DEPENDS <= exec_depends, f"missing: {sorted(EXEC_DEPENDS - exec_depends)}"
    test_depends = {element.text for element in package_xml.findall("test_depend")}
    assert {"python3-pytest", "mcap-ros2-support"} <= test_depends
    keys = {element.text for element in package_xml.iter() if element.tag.endswith("depend")}
    assert not keys & NO_SUCH_ROSDEP_KEYS


def test_versions_agree(package_xml: ET.Element) -> None:
    version = package_xml.findtext("version")
    assert version == infomax_contingency.__version__ == _setup_keyword("version")


def test_setup_py_entry_points_and_name() -> None:
    tree = ast.parse((ROOT / "setup.py").read_text())
    names = {
        node.targets[0].id: node.value.value
        for node in tree.body
        if isinstance(node, ast.Assign)
        and isinstance(node.targets[0], ast.Name)
        and isinstance(node.value, ast.Constant)
    }
    assert names.get("package_name") == PKG
    scripts = _setup_keyword("entry_points")["console_scripts"]
    parsed = dict(
        (name.strip(), target.strip()) for name, target in (s.split("=") for s in scripts)
    )
    assert set(parsed) == EXECUTABLES
    assert parsed["infomax-contingency"] == f"{PKG}.cli:run"  # quiet on an early Ctrl-C
    for node in EXECUTABLES - {"infomax-contingency"}:
        assert parsed[node] == f"{PKG}.nodes.entry:{node}"  # quiet when stopped starting


def test_setup_cfg_puts_executables_where_ros2_run_looks() -> None:
    config = configparser.ConfigParser(interpolation=None)
    config.read(ROOT / "setup.cfg")
    assert config["develop"]["script_dir"] == f"$base/lib/{PKG}"
    assert config["install"]["install_scripts"] == f"$base/lib/{PKG}"


def test_ament_index_marker_present() -> None:
    marker = ROOT / "resource" / PKG
    assert marker.is_file()


def test_ruff_config_present() -> None:
    config = tomllib.loads((ROOT / "ruff.toml").read_text())
    assert config["line-length"] == 100
    assert config["target-version"] == "py311"
    assert {"E", "F", "W", "I", "B", "UP", "N", "D"} <= set(config["lint"]["select"])
    assert not (ROOT / "pyproject.toml").exists(), "pip must keep building from setup.py"


# --- resources: installed share directory first, source tree as the fallback ----------


@pytest.fixture
def no_installed_share(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Path:
    """An ament prefix without this package, and a sys.prefix without a share dir."""
    prefix = tmp_path / "empty_prefix"
    (prefix / "share" / "ament_index" / "resource_index" / "packages").mkdir(parents=True)
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(prefix))
    monkeypatch.setattr(sys, "prefix", str(tmp_path / "venv"))
    return prefix


def _fake_ament_install(prefix: Path, files: dict[str, str]) -> Path:
    index = prefix / "share" / "ament_index" / "resource_index" / "packages"
    index.mkdir(parents=True)
    (index / PKG).write_text("")
    share = prefix / "share" / PKG
    for name, text in files.items():
        (share / name).parent.mkdir(parents=True, exist_ok=True)
        (share / name).write_text(text)
    return share


def test_resource_path_falls_back_to_source_tree(no_installed_share: Path) -> None:
    pytest.importorskip("ament_index_python")
    assert resources.resource_path("package.xml") == ROOT / "package.xml"
    assert resources.share_directory() == ROOT


def test_resource_path_without_ament_prefix_path(
    no_installed_share: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("AMENT_PREFIX_PATH")
    assert resources.resource_path("package.xml") == ROOT / "package.xml"


def test_resource_path_without_ament_index_python(
    no_installed_share: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A None entry in sys.modules makes the import raise ImportError.
    monkeypatch.setitem(sys.modules, "ament_index_python", None)
    monkeypatch.setitem(sys.modules, "ament_index_python.packages", None)
    assert resources.resource_path("package.xml") == ROOT / "package.xml"


def test_resource_path_prefers_installed_share(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    pytest.importorskip("ament_index_python")
    share = _fake_ament_install(
        tmp_path / "install", {"package.xml": "<package/>", "config/robot.yaml": "{}"}
    )
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(tmp_path / "install"))
    assert resources.share_directory() == share
    assert resources.resource_path("config", "robot.yaml") == share / "config" / "robot.yaml"
    # A file the install lacks still comes from the source tree.
    assert resources.resource_path("setup.py") == ROOT / "setup.py"


def test_resource_path_finds_plain_pip_install(
    no_installed_share: Path, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    share = tmp_path / "venv" / "share" / PKG
    (share / "config").mkdir(parents=True)
    (share / "config" / "only_installed.yaml").write_text("{}")
    path = resources.resource_path("config", "only_installed.yaml")
    assert path == share / "config" / "only_installed.yaml"


def test_missing_resource_names_every_place_searched(no_installed_share: Path) -> None:
    with pytest.raises(FileNotFoundError) as excinfo:
        resources.resource_path("config", "no_such_file.yaml")
    message = str(excinfo.value)
    assert "no_such_file.yaml" in message
    for directory in resources.candidate_directories():
        assert str(directory) in message


@pytest.mark.parametrize("parts", [(), ("/etc", "passwd"), ("..", "secret")])
def test_resource_path_rejects_paths_outside_the_package(parts: tuple[str, ...]) -> None:
    with pytest.raises(ValueError):
        resources.resource_path(*parts)


def test_resources_module_does_not_import_rclpy() -> None:
    out = subprocess.run(
        [sys.executable, str(HERE / "child_imports.py"),
         "infomax_contingency.resources:resource_path:package.xml", "rclpy"],
        check=True, cwd=ROOT, capture_output=True, text=True,
    ).stdout  # fmt: skip
    assert json.loads(out) == []


# --- a real colcon build yields the layout that `ros2 run` and launch files expect -----


@pytest.mark.slow
def test_colcon_build_layout(colcon_workspace: Path) -> None:
    prefix = colcon_workspace / "install" / PKG
    for executable in EXECUTABLES:
        path = prefix / "lib" / PKG / executable
        assert path.is_file() and os.access(path, os.X_OK), f"missing executable {path}"
    assert (prefix / "share" / "ament_index" / "resource_index" / "packages" / PKG).is_file()
    assert (prefix / "share" / PKG / "package.xml").is_file()
    for subdir, patterns in {
        "config": ["*.yaml", "*.xml"],
        "policies": ["*.npz", "*.md"],
        "launch": ["*.py"],
    }.items():
        for pattern in patterns:
            for source in (ROOT / subdir).glob(pattern):
                assert (prefix / "share" / PKG / subdir / source.name).is_file()

    # What `ros2 run` does first: find the package prefix through the ament index; and
    # resources then serves data files from the installed share directory.
    env = dict(os.environ, AMENT_PREFIX_PATH=str(prefix))
    out = subprocess.run(
        [sys.executable, str(HERE / "child_prefix.py"), PKG],
        env=env, capture_output=True, text=True, check=True,
    ).stdout.split()
    assert out == [str(prefix), str(prefix / "share" / PKG)]


# --- optional packages: asked for and missing, one line naming the package --------------


def test_the_vad_bit_source_without_webrtcvad_names_the_package(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from infomax_contingency.audio.bitsources import make_bit_source
    from infomax_contingency.errors import USER_ERRORS, MissingPackageError

    monkeypatch.setitem(sys.modules, "webrtcvad", None)  # the import then fails
    with pytest.raises(MissingPackageError) as missing:
        make_bit_source("vad", 16000, 0.5)
    assert isinstance(missing.value, USER_ERRORS)
    assert str(missing.value) == (
        "bit source 'vad' needs the Python package 'webrtcvad-wheels', which is not"
        " installed: pip install webrtcvad-wheels"
    )
