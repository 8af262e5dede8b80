"""Small input files are regular files of bounded size and bounded expansion.

A device, a FIFO or a directory has no size to check (``st_size`` 0): it is refused
before it is read (a FIFO would hang, ``/dev/zero`` would fill the memory); a YAML file
whose aliases expand to millions of values is refused, and a value quoted in a message is
cut short.
"""

from __future__ import annotations

import os
import stat
import struct
from pathlib import Path

import numpy as np
import pytest
import yaml

from infomax_contingency.audio.bag import BagReadError, read_topics
from infomax_contingency.audio.common import AudioError
from infomax_contingency.audio.threshold_file import load_threshold
from infomax_contingency.audio.wav import open_wav_info, write_wav_int16
from infomax_contingency.core.model import ModelParams, ParameterError
from infomax_contingency.limits import (
    MAX_YAML_NODES,
    load_yaml,
    read_bytes_capped,
    short_repr,
    written_atomically,
    yaml_nodes,
)
from infomax_contingency.sim.actions import read_actions_csv


def _not_regular(tmp_path: Path, name: str) -> list[tuple[Path, str]]:
    """A symlink to /dev/zero, a FIFO and a directory, all named ``name`` + a suffix."""
    zero = tmp_path / f"zero{name}"
    zero.symlink_to("/dev/zero")
    fifo = tmp_path / f"fifo{name}"
    os.mkfifo(fifo)
    folder = tmp_path / f"dir{name}"
    folder.mkdir()
    return [(zero, "a character device"), (fifo, "a FIFO"), (folder, "a directory")]


def _bomb(levels: int = 6, width: int = 10) -> str:
    """A flow sequence of nested aliases expanding to about ``width ** levels`` values."""
    text = "[" + ", ".join(["xxxxxxxx"] * width) + "]"
    for level in range(levels):
        text = f"[&a{level} {text}" + f", *a{level}" * (width - 1) + "]"
    return text


def test_devices_fifos_and_directories_are_refused_before_they_are_read(tmp_path):
    for path, kind in _not_regular(tmp_path, ".yaml"):
        with pytest.raises(ParameterError, match=f"is refused: it is {kind}, not a regular"):
            ModelParams.load(path)
        with pytest.raises(AudioError, match=f"it is {kind}"):
            load_threshold(path)
    for path, kind in _not_regular(tmp_path, ".csv"):
        with pytest.raises(ValueError, match=f"actions file .* is refused: it is {kind}"):
            read_actions_csv(path)
    with pytest.raises(ValueError, match="does not exist"):
        read_actions_csv(tmp_path / "none.csv")


def test_a_file_larger_than_its_size_says_is_read_only_up_to_the_cap():
    # /proc files are regular files of st_size 0: the read itself is bounded
    with pytest.raises(ValueError, match="holds more than 100 bytes"):
        read_bytes_capped("/proc/self/status", "status file", max_bytes=100)


def test_a_yaml_alias_bomb_is_refused_in_one_short_line(tmp_path):
    bomb = tmp_path / "bomb.yaml"
    bomb.write_text(f"ts1: {_bomb()}\ndt: 0.5\nts2: 1\nta1: 2\nta2: 4\npi: 0.01\n")
    assert bomb.stat().st_size < 1000
    with pytest.raises(ParameterError, match="aliases expand to more than") as caught:
        ModelParams.load(bomb)
    assert len(str(caught.value)) < 300
    recursive = tmp_path / "loop.yaml"
    recursive.write_text("a: &x [1, *x]\n")
    with pytest.raises(ValueError, match="aliases expand"):
        load_yaml(recursive, "file")
    assert yaml_nodes({"a": [1, 2]}) == 5  # the mapping, its key, the list, two items
    assert yaml_nodes(list(range(10**6)), cap=10) == 11


def test_values_quoted_in_messages_are_cut_short(tmp_path):
    wide = tmp_path / "wide.yaml"
    wide.write_text("ts1: 1\nts2: 1\nta1: 2\nta2: 4\npi: 0.01\ndt: ["
                    + ", ".join(["[" + ", ".join(["word"] * 50) + "]"] * 200) + "]\n")
    with pytest.raises(ParameterError, match="dt must be a number, got") as caught:
        ModelParams.load(wide)
    assert len(str(caught.value)) < 200
    threshold = tmp_path / "threshold.yaml"
    threshold.write_text("format_version: 1\nthreshold_db: [" + "1, " * 5000 + "1]\n")
    with pytest.raises(AudioError, match="must be a number") as caught:
        load_threshold(threshold)
    assert len(str(caught.value)) < 250
    assert len(short_repr("x" * 10_000)) <= 80
    assert MAX_YAML_NODES > (1 << 16)  # more than a 64 KiB file can hold written out


def test_integers_beyond_a_float_are_not_finite_and_are_named_by_their_size(tmp_path):
    """YAML reads any number of digits as an int: refused in one line, no OverflowError.

    Before, a prior of 400 digits ended solve, simulate, calibrate and info with a
    traceback, a threshold of 400 digits room-wav; one of 5,000 quoted Python's limit.
    """
    params = tmp_path / "params.yaml"
    params.write_text("{dt: 0.5, ts1: 0, ts2: 1, ta1: 2, ta2: 4, pi: 0.01, b11: 1" + "0" * 400
                      + "}\n")
    with pytest.raises(ParameterError, match="b11 must be finite, got an integer of about 401"):
        ModelParams.load(params)
    threshold = tmp_path / "threshold.yaml"
    threshold.write_text("format_version: 1\nthreshold_db: -1" + "0" * 400 + "\n")
    with pytest.raises(AudioError, match="threshold_db must be finite, got -an integer of about"):
        load_threshold(threshold)
    params.write_text("{dt: 0.5, ts1: 0, ts2: 1, ta1: 2, ta2: 4, pi: 0.01, b11: 1" + "0" * 5000
                      + "}\n")
    with pytest.raises(ValueError, match="holds a number of more than 4,300 digits"):
        ModelParams.load(params)
    assert short_repr(10**5000) == "an integer of about 5,001 digits"
    assert short_repr(-(10**50)).startswith("-10000")  # within 3 x 80 bits: its digits


def _bag(tmp_path: Path, relative_file_paths: str) -> Path:
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "metadata.yaml").write_text(
        "rosbag2_bagfile_information:\n  storage_identifier: mcap\n"
        f"  relative_file_paths: {relative_file_paths}\n")
    return bag


@pytest.mark.parametrize(("listed", "message"), [
    ("[/dev/zero]", "lies outside the bag directory"),
    ("['../outside.mcap']", "lies outside the bag directory"),
    ("[link.mcap]", "lies outside the bag directory"),
    ("[fifo.mcap]", "is not a regular file"),
    ("[sub]", "is not a regular file"),
    ("[[a, b]]", "is not a list of names"),
    (_bomb(), "aliases expand"),
    ("[s.mcap, t.mcap, s.mcap]", r"lists \['s.mcap'\] more than once"),
], ids=["absolute", "parent", "symlink", "fifo", "directory", "nested", "bomb", "twice"])
def test_a_bag_names_only_regular_files_inside_it(tmp_path, listed, message):
    (tmp_path / "outside.mcap").write_bytes(b"")
    bag = _bag(tmp_path, listed)
    (bag / "link.mcap").symlink_to("/dev/zero")
    os.mkfifo(bag / "fifo.mcap")
    (bag / "sub").mkdir()
    with pytest.raises(BagReadError, match=message) as caught:
        read_topics(bag, ["/sound_step"])
    assert len(str(caught.value)) < 400


def test_a_bag_metadata_that_is_a_device_is_refused(tmp_path):
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "metadata.yaml").symlink_to("/dev/zero")
    with pytest.raises(BagReadError, match="character device"):
        read_topics(bag, ["/sound_step"])


def test_session_files_are_regular_text_files_or_refused(tmp_path):
    from infomax_contingency.nodes.parameter_files import undeclared_parameters
    from infomax_contingency.nodes.parameters import ConfigError
    from infomax_contingency.nodes.recorder_node import session_description

    binary = tmp_path / "binary.yaml"
    binary.write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe")
    refused = [*_not_regular(tmp_path, ".yaml"), (binary, "is not UTF-8 text")]
    for path, kind in refused:
        with pytest.raises(ConfigError, match=f"'session_files': .*{path.name}.*{kind}"):
            session_description([str(path)])
    text = tmp_path / "params.yaml"
    text.write_text("dt: 0.5\n")
    described = yaml.safe_load(session_description([str(text), str(tmp_path / "none.yaml")]))
    assert described["files"][str(text)] == "dt: 0.5\n"
    assert described["files"][str(tmp_path / "none.yaml")].startswith("<unreadable")
    # the check of parameter files' keys skips what it cannot read (rcl read them first)
    assert undeclared_parameters([str(path) for path, _ in refused], []) == []


def _wav_bytes(chunks: list[tuple[bytes, bytes]], riff: bytes = b"RIFF") -> bytes:
    body = b"WAVE" + b"".join(cid + struct.pack("<I", len(data)) + data for cid, data in chunks)
    return riff + struct.pack("<I", len(body)) + body


FMT = struct.pack("<HHIIHH", 1, 1, 16_000, 32_000, 2, 16)


@pytest.mark.parametrize(("chunks", "message"), [
    ([(b"ds64", b"\0" * 4), (b"fmt ", FMT), (b"data", b"\0" * 64)], "ds64 chunk of 4 bytes"),
    ([(b"fmt ", FMT), (b"data", b"\0" * 64)], "fmt chunk declares 4,294,967,280 bytes"),
    ([(b"ds64", b"\0" * 28), (b"fmt ", FMT), (b"data", b"\0" * 64)],
     "ds64 chunk declares 4,294,967,280 bytes"),
], ids=["short-ds64", "huge-fmt", "huge-ds64"])
def test_a_corrupt_wav_header_is_one_line_not_a_traceback(tmp_path, chunks, message):
    data = bytearray(_wav_bytes(chunks, b"RF64" if chunks[0][0] == b"ds64" else b"RIFF"))
    if "declares" in message:  # the first chunk's size field claims 4 GiB
        data[16:20] = struct.pack("<I", 0xFFFFFFF0)
    path = tmp_path / "bad.wav"
    path.write_bytes(bytes(data) + b"\0" * 2000)
    with pytest.raises(AudioError, match=f"corrupt or truncated WAV file .*{message}"):
        open_wav_info(path)


def test_a_wav_that_is_a_device_or_fifo_is_refused(tmp_path):
    for path, _ in _not_regular(tmp_path, ".wav")[:2]:
        with pytest.raises(AudioError, match="is not a regular file"):
            open_wav_info(path)


def test_a_rate_whose_resampling_filter_is_too_long_is_refused_at_once(tmp_path, monkeypatch):
    from infomax_contingency.audio.energy import iter_wav_windows
    from infomax_contingency.audio.resample import StreamResampler, check_resampling
    from infomax_contingency.audio.wav import write_wav_int16
    from infomax_contingency.limits import MemoryBudget

    prime = tmp_path / "prime.wav"
    write_wav_int16(prime, np.zeros(2000), 999_983)
    with pytest.raises(AudioError, match=r"prime.wav from 999,983 Hz to 16,000 Hz: .* filter"
                       r" of 19,999,661 taps .*`sox in.wav -r 16000 out.wav`"):
        next(iter_wav_windows(prime, 0.5))
    with pytest.raises(AudioError, match="refusing to resample audio"):
        StreamResampler(15_485_863, 16_000)
    check_resampling(44_100, 48_000)
    check_resampling(44_056, 16_000)  # an odd but real rate: 5,507 / 2,000
    monkeypatch.setattr("infomax_contingency.limits.memory_budget",
                        lambda: MemoryBudget(1 << 20, "ulimit -v 1024"))
    with pytest.raises(AudioError, match="needs about .* more than 1 MiB .*sox"):
        check_resampling(44_056, 16_000)


def _mcap_record(opcode: int, body: bytes) -> bytes:
    return bytes([opcode]) + struct.pack("<Q", len(body)) + body


def _mcap_string(text: str) -> bytes:
    return struct.pack("<I", len(text)) + text.encode()


def _zstd_session(directory: Path, messages: int, declared: int | None = None,
                  padding: int = 0) -> Path:
    """A bag of one zstd chunk: ``messages`` /sound_step messages (compressible).

    ``declared``: the uncompressed size the chunk claims (default: its true size);
    ``padding``: zero bytes after the messages (a frame that expands far).
    """
    import zstandard

    from infomax_contingency.audio.bag import encode

    data = encode("std_msgs/msg/Int64MultiArray", data=[5, 1, 1, 500_000, 0])
    inner = b"".join([
        _mcap_record(3, struct.pack("<H", 1) + _mcap_string("std_msgs/msg/Int64MultiArray")
                     + _mcap_string("ros2msg") + struct.pack("<I", 0)),
        _mcap_record(4, struct.pack("<HH", 1, 1) + _mcap_string("/sound_step")
                     + _mcap_string("cdr") + struct.pack("<I", 0)),
        *[_mcap_record(5, struct.pack("<HIQQ", 1, 0, 10**18 + j, 10**18 + j) + data)
          for j in range(messages)]])
    packed = zstandard.ZstdCompressor().compress(inner + bytes(padding))
    size = len(inner) + padding if declared is None else declared
    chunk = (struct.pack("<QQQI", 0, 0, size, 0) + _mcap_string("zstd")
             + struct.pack("<Q", len(packed)) + packed)
    directory.mkdir()
    magic = b"\x89MCAP0\r\n"
    (directory / "s.mcap").write_bytes(
        magic + _mcap_record(1, _mcap_string("ros2") + _mcap_string("x"))
        + _mcap_record(6, chunk) + _mcap_record(0x0F, struct.pack("<I", 0)) + magic)
    return directory


def test_a_bag_is_read_and_decoded_only_within_the_memory_budget(tmp_path, monkeypatch):
    from infomax_contingency.limits import MemoryBudget

    bag = _zstd_session(tmp_path / "bag", 2000)
    assert len(read_topics(bag, ["/sound_step"])["/sound_step"]) == 2000
    size = (bag / "s.mcap").stat().st_size
    assert size < 8192  # 2000 messages of about 80 bytes: 160 KB once decompressed
    monkeypatch.setattr("infomax_contingency.limits.memory_budget",
                        lambda: MemoryBudget(4 * size, "ulimit -v 1"))
    with pytest.raises(BagReadError, match="refusing to decompress a chunk of .*s.mcap that"
                       " declares 1[0-9]{2},[0-9]{3} bytes: it needs about"):
        read_topics(bag, ["/sound_step"])
    monkeypatch.setattr("infomax_contingency.limits.memory_budget",
                        lambda: MemoryBudget(1 << 20, "ulimit -v 1024"))
    with pytest.raises(BagReadError, match="refusing to decode the session .* more than 1 MiB"):
        read_topics(bag, ["/sound_step"])


def test_a_zstd_chunk_is_never_expanded_past_what_it_declares(tmp_path):
    """A decompression bomb, or bytes that are not zstd: the scan stops there, saying why.

    The bomb: a frame whose own header claims 64 MB in a chunk declaring 2 KB. No more
    than the declared size is ever decompressed.
    """
    import resource

    from infomax_contingency.audio.mcap_scan import scan_mcap

    bomb = _zstd_session(tmp_path / "bomb", 20, declared=2048, padding=64 << 20)
    assert (bomb / "s.mcap").stat().st_size < 8192
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB
    scan, stopped = scan_mcap(bomb / "s.mcap")
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 32 << 10
    assert stopped == "a zstd chunk holds more bytes than the 2,048 it declares"
    assert not scan.messages
    garbage = _zstd_session(tmp_path / "garbage", 20)
    mcap = garbage / "s.mcap"
    data = bytearray(mcap.read_bytes())
    start = data.index(b"zstd") + 4 + 8  # the compressed bytes, after their length
    data[start:start + 16] = bytes(range(16))
    mcap.write_bytes(bytes(data))
    scan, stopped = scan_mcap(mcap)
    assert stopped is not None and stopped.startswith("a zstd chunk cannot be decompressed (")
    assert not scan.messages


def test_a_plotted_session_file_is_a_regular_file(tmp_path, capsys):
    from infomax_contingency.cli.main import main

    for path, kind in _not_regular(tmp_path, ".jsonl")[:2]:
        assert main(["plot", "--session", str(path), "--out", str(tmp_path / "x.png")]) == 2
        error = capsys.readouterr().err
        assert f"session file {path} is refused: it is {kind}" in error
        assert error.count("\n") == 1


def test_a_file_written_atomically_replaces_only_a_regular_file(tmp_path):
    """Whole or not at all; nothing but a regular file is written over, also mid-way."""
    path = tmp_path / "out.txt"
    path.write_text("old")
    with pytest.raises(RuntimeError), written_atomically(path, "out file") as stream:
        stream.write(b"half")
        raise RuntimeError("the writer failed")
    assert path.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["out.txt"]
    with (pytest.raises(ValueError, match=r"out file .* is not a regular file \(it is a FIFO\)"),
          written_atomically(path, "out file") as stream):
        stream.write(b"new")
        path.unlink()
        os.mkfifo(path)  # a FIFO put there while the file is written
    assert stat.S_ISFIFO(path.lstat().st_mode)
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]


@pytest.mark.parametrize(("argv", "source"), [
    (["calibrate", "--wav", "in.wav", "--out", "in.wav"], "in.wav"),
    (["calibrate", "--wav", "in.wav", "--bit-source", "speech_band", "--out", "./in.wav"],
     "in.wav"),
    (["solve", "--params", "p.yaml", "--mode", "episodic", "--horizon", "2", "--out", "p.yaml"],
     "p.yaml"),
    (["plot", "--session", "s.png", "--out", "s.png"], "s.png"),
    (["room-wav", "quiet", "--seconds", "5", "--out", "r.wav", "--binarizer", "file:t.yaml",
      "--actions", "t.yaml"], "t.yaml"),
    (["experiment", "rooms", "--params", "p.yaml", "--out", "p.yaml", "--rooms", "quiet",
      "--partner-states", "absent", "--controllers", "fixed", "--runs", "1"], "p.yaml"),
])
def test_an_output_that_names_an_input_is_refused_and_the_input_kept(
        tmp_path, monkeypatch, capsys, argv, source):
    """An output that would replace an input file: one line, status 2, the input as it was.

    Before, calibrate wrote its threshold over the recording it read, solve its table
    over the parameter file, plot its figure over the session, room-wav its actions over
    the threshold file: exit status 0 and the input gone.
    """
    from infomax_contingency.cli.main import main

    monkeypatch.chdir(tmp_path)
    write_wav_int16(tmp_path / "in.wav", np.full(16000, 0.01), 16000)
    (tmp_path / "p.yaml").write_text("{dt: 0.5, ts1: 0, ts2: 1, ta1: 2, ta2: 4, pi: 0.01}\n")
    (tmp_path / "s.png").write_text('{"step": 1, "y": 0, "u": 0, "z": 5, "time_s": 0.5}\n')
    (tmp_path / "t.yaml").write_text("format_version: 1\nthreshold_db: -40\n")
    before = (tmp_path / source).read_bytes()
    assert main(argv) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "writing it would destroy the input" in error, error
    assert (tmp_path / source).read_bytes() == before


def test_room_wav_refuses_a_parameter_set_of_another_window(tmp_path, capsys):
    """--params paper (dt 0.8 s) ran its periods on the rooms' 0.5-s windows, unsaid."""
    from infomax_contingency.cli.main import main

    out = tmp_path / "r.wav"
    assert main(["room-wav", "quiet", "--seconds", "5", "--out", str(out), "--params",
                 "paper"]) == 2  # fmt: skip
    assert "dt = 0.8 s, but the rooms' windows are 0.5 s" in capsys.readouterr().err
    assert not out.exists()
