"""A linear scan of an MCAP file: every record from its start, no summary or index needed.

The bag reader (:func:`infomax_contingency.audio.bag.read_topics`) reads a session's MCAP
files with :func:`scan_mcap`. Every length is bounds-checked against what the file holds,
and what the scan will hold is checked against the memory budget
(:func:`~infomax_contingency.limits.refuse_over_budget`) before it is read: the file
(:data:`FILE_COPIES` x its size) and each zstd chunk once decompressed
(:data:`CHUNK_COPIES` x the size it declares, at most 16 x its compressed size + 1 MiB).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from infomax_contingency.limits import refuse_over_budget


class BagReadError(OSError):
    """The session cannot be read; the message says why in one line."""


class _OverBudgetError(ValueError):
    """A file or chunk that would need more memory than the budget (not damage)."""


FILE_COPIES = 2
"""Copies of an MCAP file's bytes a scan holds: the file, and its messages' bytes."""
_ADVICE = "read it on a machine with more memory, or record shorter sessions"
CHUNK_COPIES = 3
"""Copies of a chunk's decompressed bytes a scan holds: the chunk, its messages' bytes
and their room as decoded messages."""


MCAP_MAGIC = b"\x89MCAP0\r\n"
"""First (and last) 8 bytes of an MCAP file."""
_SCHEMA, _CHANNEL, _MESSAGE, _CHUNK, _DATA_END = 0x03, 0x04, 0x05, 0x06, 0x0F


@dataclasses.dataclass
class Scan:
    """What a linear scan of an MCAP file found (:func:`scan_mcap`)."""

    schemas: dict[int, str] = dataclasses.field(default_factory=dict)
    channels: dict[int, tuple[str, str]] = dataclasses.field(default_factory=dict)
    """channel id -> (topic, message type)."""
    messages: list[tuple[int, int, bytes]] = dataclasses.field(default_factory=list)
    """(channel id, log time ns, CDR bytes), in file order."""
    complete: bool = False
    """The data section ended with its DataEnd record (the writer closed the file)."""
    read_bytes: int = 0
    """Bytes of the file read up to the last complete record."""


class _Records:
    """MCAP records of a byte string, bounds-checked: lengths never reach past its end."""

    def __init__(self, data: bytes | memoryview, what: str) -> None:
        self.data, self.what, self.pos = memoryview(data), what, 0

    def take(self, size: int) -> memoryview:
        if size < 0 or self.pos + size > len(self.data):
            raise ValueError(f"{self.what} ends inside a record")
        part = self.data[self.pos:self.pos + size]
        self.pos += size
        return part

    def uint(self, size: int) -> int:
        return int.from_bytes(self.take(size), "little")

    def string(self) -> str:
        return bytes(self.take(self.uint(4))).decode("utf-8")


def _read_records(records: _Records, scan: Scan, in_chunk: bool) -> bool:
    """Read records into ``scan`` until the end (True) or a DataEnd record (False, top level).

    Raises ValueError on a record cut short or malformed; ``scan.read_bytes`` then holds
    the end of the last complete top-level record.
    """
    while records.pos < len(records.data):
        opcode = records.uint(1)
        body = _Records(records.take(records.uint(8)), records.what)
        if opcode == _SCHEMA:
            key = body.uint(2)
            scan.schemas[key] = body.string()
        elif opcode == _CHANNEL:
            key, schema = body.uint(2), body.uint(2)
            topic = body.string()
            scan.channels[key] = (topic, scan.schemas.get(schema, "(no schema)"))
        elif opcode == _MESSAGE:
            channel, _, log_time = body.uint(2), body.uint(4), body.uint(8)
            body.uint(8)  # publish time
            scan.messages.append((channel, log_time, bytes(body.data[body.pos:])))
        elif opcode == _CHUNK and not in_chunk:
            before = len(scan.messages)
            try:
                _read_chunk(body, scan)
            except (ValueError, UnicodeDecodeError):
                del scan.messages[before:]  # a chunk counts whole or not at all
                raise
        elif opcode == _DATA_END and not in_chunk:
            scan.read_bytes = records.pos
            return False
        if not in_chunk:
            scan.read_bytes = records.pos
    return True


def _read_chunk(body: _Records, scan: Scan) -> None:
    body.uint(8), body.uint(8)  # message start and end times
    uncompressed_size, _ = body.uint(8), body.uint(4)
    compression = body.string()
    data = body.take(body.uint(8))
    if compression == "zstd":
        if uncompressed_size > 16 * len(data) + 2**20 or uncompressed_size > 2**31:
            raise ValueError(f"a chunk declares {uncompressed_size:,} bytes once uncompressed")
        refuse_over_budget(CHUNK_COPIES * uncompressed_size,
                           f"decompress a chunk of {body.what} that declares"
                           f" {uncompressed_size:,} bytes", _ADVICE, _OverBudgetError)
        data = memoryview(_decompressed(bytes(data), uncompressed_size))
    elif compression:
        raise ValueError(f"a chunk is compressed with {compression}, which is not read here")
    # a chunk is written whole: a message cut inside it is damage, not a cut file
    _read_records(_Records(data, "a chunk"), scan, in_chunk=True)


def _decompressed(data: bytes, size: int) -> bytes:
    """A zstd chunk's bytes, exactly ``size`` of them (ValueError otherwise).

    Streamed, never more than ``size + 1`` bytes out: a frame whose own header claims
    more than the chunk declares (a decompression bomb) is refused, not expanded.
    """
    import zstandard

    pieces, total = [], 0
    try:
        with zstandard.ZstdDecompressor().stream_reader(data) as reader:
            while total <= size and (piece := reader.read(size + 1 - total)):
                pieces.append(piece)
                total += len(piece)
    except zstandard.ZstdError as error:
        raise ValueError(f"a zstd chunk cannot be decompressed ({error})") from None
    if total != size:
        more = "more" if total > size else f"only {total:,}"
        raise ValueError(f"a zstd chunk holds {more} bytes than the {size:,} it declares")
    return b"".join(pieces)


def scan_mcap(path: Path) -> tuple[Scan, str | None]:
    """Every record of an MCAP file, read from its start (no summary, no index needed).

    Returns the scan and, when the file stops before its data section ends, why (a file
    cut by a killed writer; damage) — the scan then holds everything before.
    """
    try:
        refuse_over_budget(FILE_COPIES * path.stat().st_size, f"read the bag file {path}",
                           _ADVICE, _OverBudgetError)
    except _OverBudgetError as error:
        raise BagReadError(str(error)) from None
    data = path.read_bytes()
    if not data.startswith(MCAP_MAGIC):
        raise BagReadError(f"{path} is not an MCAP file (it starts with {data[:8]!r})")
    scan, records = Scan(), _Records(memoryview(data)[len(MCAP_MAGIC):], str(path))
    try:
        scan.complete = not _read_records(records, scan, in_chunk=False)
        stopped = None if scan.complete else "the file ends before its data section does"
    except _OverBudgetError as error:
        raise BagReadError(str(error)) from None
    except (ValueError, UnicodeDecodeError) as error:
        stopped = str(error)
    scan.read_bytes += len(MCAP_MAGIC)
    return scan, stopped
