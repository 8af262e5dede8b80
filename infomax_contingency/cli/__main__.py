"""``python -m infomax_contingency.cli``: the same as ``infomax-contingency``."""

import sys

from infomax_contingency.cli.main import main

sys.exit(main())
