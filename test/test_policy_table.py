"""Policy table files: round trip, and every hostile or bad file refused in one line.

One test per probe: a flipped byte anywhere, truncation, an edited field, inverted bits,
a declared shape of 10^15, a zip bomb, deep or huge metadata JSON, text, random bytes,
a wav file, a directory, a foreign archive, an old format version, other parameters.
"""

from __future__ import annotations

import io
import json
import shutil
import tracemalloc
import zipfile
from pathlib import Path

import numpy as np
import pytest

from infomax_contingency.core.model import ModelParams, Statistic
from infomax_contingency.core.policy_table import (
    MAX_JSON_DEPTH,
    PolicyTable,
    PolicyTableError,
    content_digest,
)
from infomax_contingency.core.solver import solve_episodic, solve_receding
from infomax_contingency.core.statespace import count_tuples

WAV = Path(__file__).resolve().parent / "data" / "interaction.wav"


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


def refusal(path: Path, **load_arguments) -> str:
    """The message of the PolicyTableError that loading ``path`` raises (one line)."""
    with pytest.raises(PolicyTableError) as caught:
        PolicyTable.load(path, **load_arguments)
    message = str(caught.value)
    assert "\n" not in message and str(path) in message, message
    return message


@pytest.mark.parametrize("mode", ["episodic", "receding"])
def test_round_trip(tmp_path, tables, mode: str) -> None:
    table = tables[mode]
    path = tmp_path / "table.npz"
    table.save(path)
    loaded = PolicyTable.load(path, expected_params=table.params)
    assert loaded.same_policy_as(table)
    assert all_lookups(loaded) == all_lookups(table)
    assert loaded.metadata()["mode"] == mode
    assert loaded.metadata()["content_sha256"] == table.metadata()["content_sha256"]
    unpacked = np.concatenate([loaded.layer(i).T.ravel() for i in range(table.n_layers)])
    assert unpacked.tolist() == [bool(a) for a in all_lookups(table)]
    assert unpacked.any() and not unpacked.all()  # both actions are exercised
    assert [p.name for p in tmp_path.iterdir()] == ["table.npz"]  # no temporary left


def rewrite(path: Path, **arrays) -> None:
    with path.open("wb") as stream:
        np.savez(stream, **arrays)


def table_arrays(table: PolicyTable) -> dict:
    return {"actions": table.packed_actions, "metadata": np.array(json.dumps(table.metadata()))}


def sealed(metadata: dict, packed: np.ndarray) -> np.ndarray:
    """Metadata with a content digest recomputed for it: an edit the digest cannot see."""
    metadata = dict(metadata, content_sha256=content_digest(metadata, packed.tobytes()))
    return np.array(json.dumps(metadata))


def npy_bytes(array: np.ndarray) -> bytes:
    stream = io.BytesIO()
    np.lib.format.write_array(stream, array, allow_pickle=False)
    return stream.getvalue()


def npy_header(shape: tuple, descr: str) -> bytes:
    stream = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        stream, {"descr": descr, "fortran_order": False, "shape": shape}
    )
    return stream.getvalue()


def write_zip(path: Path, entries: dict[str, bytes]) -> None:
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, data in entries.items():
            archive.writestr(name, data)


def test_missing_file(tmp_path) -> None:
    assert "does not exist" in refusal(tmp_path / "nope.npz")


def test_directory_instead_of_file(tmp_path) -> None:
    folder = tmp_path / "table.npz"
    folder.mkdir()
    assert "is a directory" in refusal(folder)
    shutil.rmtree(folder)


@pytest.mark.parametrize(
    "content",
    [
        pytest.param(b"this is not a table\n", id="text"),
        pytest.param(np.random.default_rng(3).bytes(5000), id="random-bytes"),
        pytest.param(WAV.read_bytes(), id="wav"),
        pytest.param(b"", id="empty"),
    ],
)
def test_not_a_zip_archive(tmp_path, content: bytes) -> None:
    path = tmp_path / "table.npz"
    path.write_bytes(content)
    assert refusal(path).endswith("is not a policy table (not a zip archive)")


@pytest.mark.parametrize("keep", [0.5, 0.9, -1, -22])
def test_truncated_file(tmp_path, tables, keep: float) -> None:
    path = tmp_path / "table.npz"
    tables["episodic"].save(path)
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep) if keep > 0 else len(data) + keep])
    assert "truncated" in refusal(path)


def test_every_flipped_byte_is_refused_or_harmless(tmp_path, tables) -> None:
    """Flip each byte of a table file in turn: a refusal, or the very same table.

    Some zip header bytes (timestamps, the 'version made by') do not change the content;
    every byte that does must be refused, one line each.
    """
    table = tables["receding"]
    path = tmp_path / "table.npz"
    table.save(path)
    original = path.read_bytes()
    refused = 0
    for position in range(len(original)):
        damaged = bytearray(original)
        damaged[position] ^= 0x10
        path.write_bytes(bytes(damaged))
        try:
            loaded = PolicyTable.load(path)
        except PolicyTableError as error:
            assert "\n" not in str(error)
            refused += 1
        else:
            assert loaded.same_policy_as(table), f"byte {position} changed the table unnoticed"
    assert refused > 0.8 * len(original), (refused, len(original))  # the rest: zip headers


def test_flipped_action_bit_and_inverted_bits(tmp_path, tables) -> None:
    arrays = table_arrays(tables["episodic"])
    path = tmp_path / "table.npz"
    flipped = arrays["actions"].copy()
    flipped[len(flipped) // 2] ^= 0x04
    for actions in (flipped, np.invert(arrays["actions"])):
        rewrite(path, actions=actions, metadata=arrays["metadata"])
        assert "is damaged: content digest mismatch" in refusal(path)


@pytest.mark.parametrize(
    "edit",
    [
        lambda m: m.update(horizon=m["horizon"] + 1),
        lambda m: m.update(solver_version=7),
        lambda m: m.update(n_statistics=1),
        lambda m: m.update(memory=3),
        lambda m: m["params"].update(pi=0.5),
        lambda m: m.update(comment="edited"),
    ],
)
def test_edited_metadata_breaks_the_digest(tmp_path, tables, edit) -> None:
    arrays = table_arrays(tables["episodic"])
    metadata = json.loads(str(arrays["metadata"]))
    edit(metadata)
    path = tmp_path / "table.npz"
    rewrite(path, actions=arrays["actions"], metadata=np.array(json.dumps(metadata)))
    message = refusal(path)
    assert "is damaged: content digest mismatch" in message or "parameter hash" in message


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda m: m.update(format_version=99), "format version 99"),
        (lambda m: m.update(mode="sideways"), "unknown mode"),
        (lambda m: m.update(layer_max_counts=[1, 2]), "layer sizes"),
        (lambda m: m["params"].update(pi=0.5), "parameter hash does not match"),
        (lambda m: m["params"].update(pi=2.0), "malformed metadata.*pi"),
        (lambda m: m.pop("horizon"), "malformed metadata"),
        (lambda m: m.update(horizon=True), "malformed metadata"),
        (lambda m: m.update(n_statistics=1), "does not describe its actions"),
    ],
)
def test_resealed_bad_metadata(tmp_path, tables, edit, message: str) -> None:
    """Edits with a recomputed digest still meet the structural checks."""
    arrays = table_arrays(tables["episodic"])
    metadata = json.loads(str(arrays["metadata"]))
    edit(metadata)
    path = tmp_path / "table.npz"
    rewrite(path, actions=arrays["actions"], metadata=sealed(metadata, arrays["actions"]))
    with pytest.raises(PolicyTableError, match=message):
        PolicyTable.load(path)


def test_old_format_version_says_to_solve_again(tmp_path, tables) -> None:
    arrays = table_arrays(tables["episodic"])
    metadata = json.loads(str(arrays["metadata"]))
    metadata.pop("content_sha256")
    metadata["format_version"] = 1
    path = tmp_path / "table.npz"
    rewrite(path, actions=arrays["actions"], metadata=np.array(json.dumps(metadata)))
    assert refusal(path).endswith(
        "has format version 1; this version reads 2: solve it again with `infomax-contingency"
        " solve --params NAME|FILE --mode episodic --horizon 9 --out FILE`"
    )


def test_truncated_action_array(tmp_path, tables) -> None:
    arrays = table_arrays(tables["receding"])
    actions = arrays["actions"][:-3]
    metadata = json.loads(str(arrays["metadata"]))
    path = tmp_path / "table.npz"
    rewrite(path, actions=actions, metadata=sealed(metadata, actions))
    assert "action array has shape" in refusal(path)


def test_huge_declared_shape_is_refused_before_allocation(tmp_path, tables) -> None:
    arrays = table_arrays(tables["episodic"])
    path = tmp_path / "table.npz"
    write_zip(
        path,
        {
            "actions.npy": npy_header((10**15,), "|u1") + b"\0" * 64,
            "metadata.npy": npy_bytes(arrays["metadata"]),
        },
    )
    assert "action array has shape (1000000000000000,), more than" in refusal(path)
    write_zip(
        path,
        {
            "actions.npy": npy_bytes(arrays["actions"]),
            "metadata.npy": npy_header((), f"<U{10**8}") + b"\0" * 64,
        },
    )
    assert "metadata declares 100,000,000 characters" in refusal(path)
    write_zip(
        path,
        {
            "actions.npy": npy_bytes(arrays["actions"]),
            "metadata.npy": npy_header((10**15,), "<U8") + b"\0" * 64,
        },
    )
    assert "its metadata is a <U8 array of shape (1000000000000000,), not a text" in refusal(path)


def test_metadata_claiming_a_huge_table_is_too_large(tmp_path, tables) -> None:
    arrays = table_arrays(tables["episodic"])
    metadata = json.loads(str(arrays["metadata"]))
    metadata.update(horizon=10**15, layer_max_counts=[])
    path = tmp_path / "table.npz"
    rewrite(path, actions=arrays["actions"], metadata=np.array(json.dumps(metadata)))
    assert "is too large: its metadata describes" in refusal(path)


def entries_opened(monkeypatch) -> list[str]:
    """The names of the archive entries opened from now on, in order (zipfile spied on)."""
    opened: list[str] = []
    real_open = zipfile.ZipFile.open

    def spy(self, name, *args, **kwargs):
        opened.append(name if isinstance(name, str) else name.filename)
        return real_open(self, name, *args, **kwargs)

    monkeypatch.setattr(zipfile.ZipFile, "open", spy)
    return opened


def test_zip_bomb_is_refused_before_decompression(tmp_path, tables, monkeypatch) -> None:
    """64 MiB of zeros deflated to 64 KiB under a small table's metadata."""
    arrays = table_arrays(tables["episodic"])
    path = tmp_path / "table.npz"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        with archive.open("actions.npy", "w") as entry:
            entry.write(npy_header((64 * 2**20,), "|u1"))
            zeros = bytes(2**20)
            for _ in range(64):
                entry.write(zeros)
        archive.writestr("metadata.npy", npy_bytes(arrays["metadata"]))
    assert path.stat().st_size < 2**20
    opened = entries_opened(monkeypatch)
    tracemalloc.start()
    try:
        message = refusal(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert "entry actions.npy expands" in message and "fold" in message
    assert "actions.npy" not in opened
    assert peak < 4 * 2**20, peak


def test_action_entry_larger_than_its_metadata_allows(tmp_path, tables) -> None:
    arrays = table_arrays(tables["episodic"])
    actions = np.random.default_rng(1).integers(0, 256, 300_000, dtype=np.uint8)
    path = tmp_path / "table.npz"
    rewrite(path, actions=actions, metadata=arrays["metadata"])
    assert "more than a episodic table of horizon 9 can" in refusal(path)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        pytest.param("[" * 200_000 + "]" * 200_000, "metadata entry holds", id="200000-deep"),
        pytest.param("[" * 100 + "]" * 100, "nested 100 deep", id="100-deep"),
        pytest.param(json.dumps({"pad": "x" * 3_000_000}), "metadata entry holds", id="3-MB"),
    ],
)
def test_deep_or_huge_json_is_refused_before_parsing(tmp_path, tables, text, message) -> None:
    path = tmp_path / "table.npz"
    rewrite(path, actions=tables["episodic"].packed_actions, metadata=np.array(text))
    assert message in refusal(path)
    assert MAX_JSON_DEPTH < 100


def test_foreign_npz(tmp_path) -> None:
    path = tmp_path / "table.npz"
    rewrite(path, weights=np.zeros(3))
    assert "not the 'actions' and 'metadata' arrays" in refusal(path)
    rewrite(path, actions=np.zeros(3, np.uint8), metadata=np.array(json.dumps({"format": "x"})))
    assert "is not an infomax_contingency policy table" in refusal(path)


def test_pickled_object_arrays_are_refused(tmp_path) -> None:
    path = tmp_path / "table.npz"
    rewrite(path, actions=np.array([object()]), metadata=np.array([{"a": 1}], dtype=object))
    assert "is not a policy table: its metadata is a object array" in refusal(path)


def test_table_for_other_parameters(tmp_path, tables) -> None:
    path = tmp_path / "table.npz"
    tables["episodic"].save(path)
    message = refusal(path, expected_params=ModelParams.named("robot"))
    assert "was built for other model parameters" in message and "dt: 0.8 != 0.5" in message


def test_a_zip_of_many_entries_is_refused_before_its_directory_is_parsed(
    tmp_path, monkeypatch
) -> None:
    path = tmp_path / "table.npz"
    with zipfile.ZipFile(path, "w") as archive:
        for index in range(1000):
            archive.writestr(f"entry{index}.npy", b"")
    monkeypatch.setattr(
        zipfile.ZipFile, "__init__", lambda *a, **k: pytest.fail("zip directory parsed")
    )
    assert "its zip directory lists 1,000 entries" in refusal(path)


def test_an_unreadable_file_says_so(tmp_path, tables, monkeypatch) -> None:
    path = tmp_path / "table.npz"
    tables["receding"].save(path)

    def denied(self, *args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(Path, "open", denied)
    assert refusal(path).endswith("cannot be read (Permission denied)")


def test_a_table_larger_than_the_memory_budget_is_refused_before_it_is_read(
        tmp_path, tables, monkeypatch) -> None:
    from infomax_contingency.limits import MemoryBudget

    path = tmp_path / "table.npz"
    tables["episodic"].save(path)
    monkeypatch.setattr("infomax_contingency.limits.memory_budget",
                        lambda: MemoryBudget(16, "ulimit -v 0"))
    opened = entries_opened(monkeypatch)
    message = refusal(path)
    assert "refusing to load policy table" in message and "its action entry declares" in message
    assert "more than 16 bytes (ulimit -v 0)" in message and "actions.npy" not in opened
