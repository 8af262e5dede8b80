"""The audio rooms experiment (being split by role)."""

from infomax_contingency.eval.rooms.binarizers import *  # noqa: F403
