"""Build script for the infomax_contingency ament_python package."""

from glob import glob

from setuptools import find_packages, setup

package_name = "infomax_contingency"


def _share(subdir: str, *patterns: str) -> list[tuple[str, list[str]]]:
    """Return a data_files entry for share/<package>/<subdir>, or none if nothing matches.

    Globs are sorted for reproducible builds; a missing or empty directory yields no
    entry, so the build works before config/, policies/ or launch/ hold any file.
    """
    files = sorted({path for pattern in patterns for path in glob(f"{subdir}/{pattern}")})
    return [(f"share/{package_name}/{subdir}", files)] if files else []


setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{package_name}"]),
        (f"share/{package_name}", ["package.xml"]),
        *_share("config", "*.yaml", "*.xml"),
        *_share("policies", "*.npz", "*.md"),
        *_share("launch", "*.py"),
    ],
    install_requires=["numpy", "scipy", "pyyaml", "sounddevice", "rosbags"],
    # Optional: mic_node's bit_source vad (without it, asking for vad is one error line).
    extras_require={"vad": ["webrtcvad-wheels"]},
    zip_safe=True,
    maintainer="infomax_contingency maintainers",
    maintainer_email="maintainers@example.com",
    description=(
        "Infomax contingency detection: a robot finds out from sound whether a "
        "responsive partner is present."
    ),
    license="Apache-2.0",
    python_requires=">=3.10",
    entry_points={
        "console_scripts": [
            "infomax-contingency = infomax_contingency.cli:run",
            "mic_node = infomax_contingency.nodes.entry:mic_node",
            "controller_node = infomax_contingency.nodes.entry:controller_node",
            "belief_node = infomax_contingency.nodes.entry:belief_node",
            "posture_node = infomax_contingency.nodes.entry:posture_node",
            "fake_audio_node = infomax_contingency.nodes.entry:fake_audio_node",
            "speaker_node = infomax_contingency.nodes.entry:speaker_node",
            "recorder_node = infomax_contingency.nodes.entry:recorder_node",
            "bringup = infomax_contingency.nodes.entry:bringup",
        ],
    },
)
