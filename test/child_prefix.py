"""Child process of the colcon layout test: what ``ros2 run`` and resources would find.

Run as ``python test/child_prefix.py PACKAGE`` with ``AMENT_PREFIX_PATH`` set; prints
the package prefix from the ament index and the share directory resources serves data
files from, one per line.
"""

from __future__ import annotations

import sys

from ament_index_python.packages import get_package_prefix

from infomax_contingency import resources


def main(argv: list[str]) -> int:
    """Print the prefix of package ``argv[0]`` and the resources' share directory."""
    if len(argv) != 1:
        print("usage: child_prefix.py PACKAGE", file=sys.stderr)
        return 2
    print(get_package_prefix(argv[0]))
    print(resources.share_directory())
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
