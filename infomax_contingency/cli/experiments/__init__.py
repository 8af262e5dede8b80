"""Command-line sub-commands of the evaluation suite: ``experiment``, ``learn``, ``plot``.

One module per command, mirroring :mod:`infomax_contingency.eval.experiments`:

* ``experiment NAME`` (:mod:`.commands`): ``baby9`` (:mod:`.baby9`), ``rule``
  (:mod:`.rule`), ``greedy`` (:mod:`.greedy`), ``horizon`` (:mod:`.horizon`),
  ``efficiency`` (:mod:`.efficiency`) — readable tables, or ``--json``; ``experiment
  rooms`` — :mod:`infomax_contingency.eval.rooms` (:mod:`infomax_contingency.cli.rooms`).
* ``learn`` (:mod:`.learn`) — infomax TD learning curves.
* ``plot`` (:mod:`.plot`) — the four-panel figure of a simulated or recorded session.
* :mod:`.options` — what they share: option types, JSON output, the cache directory.

Every command is deterministic given its seeds; docs/RESULTS.md lists the commands that
produced every reported number and figure.
"""

from __future__ import annotations

from infomax_contingency.cli.experiments.commands import EXPERIMENTS, register_experiment
from infomax_contingency.cli.experiments.efficiency import print_efficiency
from infomax_contingency.cli.experiments.learn import register_learn
from infomax_contingency.cli.experiments.plot import register_plot
from infomax_contingency.eval.experiments.learn import parse_method

__all__ = [
    "EXPERIMENTS",
    "parse_method",
    "print_efficiency",
    "register_experiment",
    "register_learn",
    "register_plot",
]
