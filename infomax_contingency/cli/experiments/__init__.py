"""Command-line sub-commands of the evaluation suite (being split into one module per command)."""

from infomax_contingency.cli.experiments.efficiency import *  # noqa: F403
