"""``python -m infomax_contingency.cli``: the same as ``infomax-contingency``."""

import sys

from infomax_contingency.cli import run

sys.exit(run())
