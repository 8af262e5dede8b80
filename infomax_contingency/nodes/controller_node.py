"""controller_node: answers every ``sound`` bit with one ``vocalize`` decision.

The decision comes from a solved policy table
(:class:`~infomax_contingency.core.controllers.PolicyController`): ``policy_file``, a file or
the name of a table in the package's ``policies/`` directory (default: the committed
robot table, found through the share directory). A table solved for other model
parameters than ``params`` is refused at start-up with the differences named. Episodic
tables restart an episode at their horizon; receding tables keep a sliding memory of M
counted observations.

Subscribes ``sound`` (Bool); publishes ``vocalize`` (Bool, one per bit) and
``/diagnostics``.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from std_msgs.msg import Bool

from infomax_contingency.core.controllers import PolicyController
from infomax_contingency.core.policy_table import PolicyTable
from infomax_contingency.nodes.graph_node import OK, GraphNode
from infomax_contingency.nodes.parameters import ConfigError
from infomax_contingency.nodes.qos import STREAM_QOS
from infomax_contingency.nodes.runtime import run_node
from infomax_contingency.resources import resource_path

DEFAULT_TABLE = ("policies", "robot_receding_H24_M60.npz")
"""The committed table for the ``robot`` parameters (share-directory relative)."""


def _table_path(value: str) -> str:
    """The table file: ``value`` itself, or a table of that name in ``policies/``."""
    name = value or DEFAULT_TABLE[1]
    if value and (Path(value).exists() or len(Path(value).parts) > 1):
        return value
    try:
        return str(resource_path(DEFAULT_TABLE[0], name))
    except FileNotFoundError as error:
        raise ConfigError(f"parameter 'policy_file' = {value!r}: {error}") from None


class ControllerNode(GraphNode):
    """Controller: decides after every window whether to vocalize."""

    NODE_NAME = "controller_node"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.NODE_NAME, **kwargs)
        params = self.parameters.model()
        path = self.parameters.text(
            "policy_file",
            "",
            "Policy table (.npz) solved for 'params': a file, or the name of a table in the"
            f" package's policies/ directory; empty = {DEFAULT_TABLE[1]}",
        )
        self.table_path = _table_path(path)
        table = PolicyTable.load(self.table_path, expected_params=params)
        self.controller = PolicyController(table)
        self.steps = 0
        self.vocalizations = 0
        self.vocalize_pub = self.create_publisher(Bool, "vocalize", STREAM_QOS)
        self.subscribe(Bool, "sound", self._on_sound)
        self.start_diagnostics()
        self.get_logger().info(
            f"policy {self.table_path}: {table.mode}, horizon {table.horizon}"
            + (f", memory {table.memory}" if table.mode == "receding" else "")
        )

    def _on_sound(self, msg: Bool, stamp: int) -> None:
        u = self.controller.step(int(msg.data))
        self.steps += 1
        self.vocalizations += u
        self.vocalize_pub.publish(Bool(data=bool(u)))

    def diagnostic_status(self) -> tuple[bytes, str, dict[str, Any]]:
        """Steps, vocalizations, the table and the current statistic."""
        table = self.controller.table
        return (
            OK,
            f"{self.steps} steps, {self.vocalizations} vocalizations",
            {
                "steps": self.steps,
                "vocalizations": self.vocalizations,
                "policy_file": self.table_path,
                "mode": table.mode,
                "horizon": table.horizon,
                "memory": table.memory,
                "statistic": tuple(self.controller.tracker.statistic),
            },
        )


def main(args: list[str] | None = None) -> int:
    """Run the controller node."""
    return run_node(ControllerNode, args)


if __name__ == "__main__":
    sys.exit(main())
