"""Evaluation of infomax controllers (being split into one module per experiment)."""

from infomax_contingency.eval.experiments.efficiency import *  # noqa: F403
