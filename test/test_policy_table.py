"""Policy table files: round trip, and every bad file refused with a message that says why."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from infomax_contingency.core.model import ModelParams, Statistic
from infomax_contingency.core.policy_table import PolicyTable, PolicyTableError
from infomax_contingency.core.solver import solve_episodic, solve_receding
from infomax_contingency.core.statespace import count_tuples


@pytest.fixture(scope="module")
def tables() -> dict[str, PolicyTable]:
    return {
        "episodic": solve_episodic(ModelParams.named("paper"), 9),
        "receding": solve_receding(ModelParams.named("robot"), 4, 6),
    }


def all_lookups(table: PolicyTable) -> list[int]:
    actions = []
    for layer in range(table.n_layers):
        step = layer + 1 if table.mode == "episodic" else None
        for counts in count_tuples(table.layer_max_counts[layer]):
            for z in range(table.params.n_timer_values):
                actions.append(table.action(Statistic(z, *map(int, counts)), step=step))
    return actions


@pytest.mark.parametrize("mode", ["episodic", "receding"])
def test_round_trip(tmp_path, tables, mode: str) -> None:
    table = tables[mode]
    path = tmp_path / "table.npz"
    table.save(path)
    loaded = PolicyTable.load(path, expected_params=table.params)
    assert loaded.same_policy_as(table)
    assert all_lookups(loaded) == all_lookups(table)
    assert loaded.metadata()["mode"] == mode
    unpacked = np.concatenate([loaded.layer(i).T.ravel() for i in range(table.n_layers)])
    assert unpacked.tolist() == [bool(a) for a in all_lookups(table)]
    assert unpacked.any() and not unpacked.all()  # both actions are exercised


def rewrite(path, **arrays) -> None:
    with path.open("wb") as stream:
        np.savez(stream, **arrays)


def table_arrays(table: PolicyTable) -> dict:
    return {"actions": table.packed_actions, "metadata": np.array(json.dumps(table.metadata()))}


def test_missing_file(tmp_path) -> None:
    with pytest.raises(PolicyTableError, match="does not exist.*infomax-contingency solve"):
        PolicyTable.load(tmp_path / "nope.npz")


def test_truncated_file(tmp_path, tables) -> None:
    path = tmp_path / "table.npz"
    tables["episodic"].save(path)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(PolicyTableError, match="truncated or corrupt"):
        PolicyTable.load(path)


def test_garbage_file(tmp_path) -> None:
    path = tmp_path / "table.npz"
    path.write_text("this is not a table")
    with pytest.raises(PolicyTableError, match="truncated or corrupt"):
        PolicyTable.load(path)


def test_foreign_npz(tmp_path) -> None:
    path = tmp_path / "table.npz"
    rewrite(path, weights=np.zeros(3))
    with pytest.raises(PolicyTableError, match="not a policy table"):
        PolicyTable.load(path)
    rewrite(path, actions=np.zeros(3, np.uint8), metadata=np.array(json.dumps({"format": "x"})))
    with pytest.raises(PolicyTableError, match="not an infomax_contingency policy table"):
        PolicyTable.load(path)


def test_pickled_object_arrays_are_refused(tmp_path) -> None:
    path = tmp_path / "table.npz"
    rewrite(path, actions=np.array([object()]), metadata=np.array([{"a": 1}], dtype=object))
    with pytest.raises(PolicyTableError, match="truncated or corrupt"):
        PolicyTable.load(path)


def test_table_for_other_parameters(tmp_path, tables) -> None:
    path = tmp_path / "table.npz"
    tables["episodic"].save(path)
    with pytest.raises(PolicyTableError, match=r"other model parameters.*dt: 0\.8 != 0\.5"):
        PolicyTable.load(path, expected_params=ModelParams.named("robot"))


def test_truncated_action_array(tmp_path, tables) -> None:
    arrays = table_arrays(tables["receding"])
    arrays["actions"] = arrays["actions"][:-3]
    path = tmp_path / "table.npz"
    rewrite(path, **arrays)
    with pytest.raises(PolicyTableError, match="action array has shape"):
        PolicyTable.load(path)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda m: m.update(format_version=99), "format version 99"),
        (lambda m: m.update(mode="sideways"), "unknown mode"),
        (lambda m: m.update(layer_max_counts=[1, 2]), "layer sizes"),
        (lambda m: m["params"].update(pi=0.5), "hash does not match"),
        (lambda m: m["params"].update(pi=2.0), "malformed metadata.*pi"),
        (lambda m: m.pop("horizon"), "malformed metadata"),
    ],
)
def test_bad_metadata(tmp_path, tables, edit, message: str) -> None:
    arrays = table_arrays(tables["episodic"])
    metadata = json.loads(str(arrays["metadata"]))
    edit(metadata)
    arrays["metadata"] = np.array(json.dumps(metadata))
    path = tmp_path / "table.npz"
    rewrite(path, **arrays)
    with pytest.raises(PolicyTableError, match=message):
        PolicyTable.load(path)


def test_directory_instead_of_file(tmp_path) -> None:
    folder = tmp_path / "table.npz"
    folder.mkdir()
    with pytest.raises(PolicyTableError, match="does not exist"):
        PolicyTable.load(folder)
    shutil.rmtree(folder)
