"""Child process of the import tests: which forbidden modules an import pulls in.

Run as ``python test/child_imports.py MODULE,... FORBIDDEN,...`` (comma-separated
lists). Imports every MODULE in a fresh interpreter and prints, as one JSON list, the
FORBIDDEN modules that are then loaded (``[]``: none). A MODULE may be
``module:function:argument``: the function is also called with the (string) argument.
"""

from __future__ import annotations

import importlib
import json
import sys


def main(argv: list[str]) -> int:
    """Import the modules of ``argv[0]``; print which of ``argv[1]`` got loaded."""
    if len(argv) != 2:
        print("usage: child_imports.py MODULE,... FORBIDDEN,...", file=sys.stderr)
        return 2
    for entry in argv[0].split(","):
        module, _, call = entry.partition(":")
        loaded = importlib.import_module(module)
        if call:
            function, _, argument = call.partition(":")
            getattr(loaded, function)(argument)
    print(json.dumps([name for name in argv[1].split(",") if name in sys.modules]))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
