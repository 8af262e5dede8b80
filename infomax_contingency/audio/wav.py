"""WAV files: header parsing, block-by-block reading, whole-file reading, mixdown, writing.

One reader for every use: :class:`WavReader` parses the header once and then decodes the
samples block by block (constant memory whatever the file length); :func:`read_wav` is
the same reader collecting every block. It reads PCM 8-bit (unsigned), 16/24/32-bit
(signed; any whole number of bytes up to 8) integer and 32/64-bit float data, in RIFF
(little-endian), RIFX (big-endian) and RF64 files, plain or WAVE_FORMAT_EXTENSIBLE, with
any channel count and sample rate. Unknown chunks are skipped.

Scaling: integer data of ``b`` bytes is divided by ``2**(8*b - 1)`` (8-bit is first
offset by 128), so it lies in [-1, 1); float data is returned as stored (nominally
[-1, 1], not clipped). Samples are float64 shaped ``(frames, channels)``.
"""

from __future__ import annotations

import dataclasses
import os
import struct
from collections.abc import Iterator
from pathlib import Path
from types import TracebackType
from typing import BinaryIO

import numpy as np
from numpy.typing import ArrayLike, NDArray

from infomax_contingency.audio.common import (
    AudioError,
    check_rate,
    float_samples,
)
from infomax_contingency.limits import refuse_over_budget, written_atomically

_WAV_MAGICS = (b"RIFF", b"RIFX", b"RF64")
_PCM, _FLOAT, _EXTENSIBLE = 0x0001, 0x0003, 0xFFFE
_RF64_SIZE = 0xFFFFFFFF
DEFAULT_BLOCK_FRAMES = 1 << 16
"""Frames decoded per block by default (65536: 4 s at 16 kHz)."""
MAX_DURATION_S = 24 * 3600.0
"""Longest audio a WAV file may hold, seconds (``frames / rate``: the length it keeps
once resampled to any rate). Every reader refuses a longer file before reading a sample:
a header that says 1 Hz makes 640 KB of 16-bit samples 88 hours of audio, 5 * 10^9
samples at 16 kHz."""


@dataclasses.dataclass(frozen=True)
class WavInfo:
    """What a WAV header says.

    Attributes:
        path: the file.
        rate: sample rate, Hz.
        channels: channel count.
        frames: complete frames in the data chunk.
        sample_bytes: bytes per sample of one channel.
        encoding: ``"uint"`` (8-bit PCM), ``"int"`` (signed PCM) or ``"float"``.
        big_endian: True for RIFX files.
        data_offset: byte offset of the first sample in the file.
    """

    path: Path
    rate: int
    channels: int
    frames: int
    sample_bytes: int
    encoding: str
    big_endian: bool
    data_offset: int

    @property
    def duration_s(self) -> float:
        """Length of the audio, seconds."""
        return self.frames / self.rate


def _corrupt(path: Path, detail: str) -> AudioError:
    return AudioError(f"{path} is a corrupt or truncated WAV file ({detail})")


def _unsupported(path: Path, detail: str) -> AudioError:
    return AudioError(
        f"{path} uses an unsupported WAV encoding ({detail}). Convert it to PCM, "
        "e.g. `ffmpeg -i input -c:a pcm_s16le output.wav`."
    )


def _check_file(path: Path) -> None:
    """Refuse a missing file, a directory, an unreadable or empty file, or a non-WAV file."""
    if not path.exists():
        raise AudioError(f"audio file {path} does not exist")
    if path.is_dir():
        raise AudioError(f"{path} is a directory, not a WAV file")
    if not path.is_file():  # a device or a FIFO: no header to trust, or a read that hangs
        raise AudioError(f"{path} is not a regular file (a device or a FIFO), not a WAV file")
    try:
        with path.open("rb") as f:
            head = f.read(12)
    except OSError as exc:
        raise AudioError(f"cannot read audio file {path}: {exc.strerror or exc}") from exc
    if not head:
        raise AudioError(f"{path} is a 0-byte file, not a WAV file")
    if head[:4] not in _WAV_MAGICS or (len(head) == 12 and head[8:12] != b"WAVE"):
        raise AudioError(
            f"{path} is not a WAV file (no RIFF/WAVE header; starts with {head[:12]!r}). "
            "Convert it to WAV, e.g. `ffmpeg -i input output.wav`."
        )


def _read_exact(f: BinaryIO, n: int, path: Path, what: str) -> bytes:
    data = f.read(n)
    if len(data) != n:
        raise _corrupt(path, f"the file ends inside the {what}")
    return data


MAX_HEADER_CHUNK_BYTES = 1 << 16
"""Largest ``fmt `` or ``ds64`` chunk read, bytes (real ones: 16 .. 40 and 28)."""


def _header_chunk(f: BinaryIO, size: int, file_size: int, path: Path, what: str) -> bytes:
    """The body of a header chunk (``fmt ``, ``ds64``) of ``size`` bytes, checked first.

    A size beyond the file's end or :data:`MAX_HEADER_CHUNK_BYTES` is a corrupt header
    (a 2 KB file whose fmt chunk claimed 4 GiB ran out of memory).
    """
    remaining = max(0, file_size - f.tell())
    if size > min(remaining, MAX_HEADER_CHUNK_BYTES):
        raise _corrupt(path, f"its {what} declares {size:,} bytes: more than the"
                             f" {remaining:,} left in the file or {MAX_HEADER_CHUNK_BYTES:,}")
    return _read_exact(f, size, path, what)


def _parse_fmt(body: bytes, endian: str, path: Path) -> tuple[int, int, int, str]:
    """``(channels, rate, sample_bytes, encoding)`` from a fmt chunk."""
    if len(body) < 16:
        raise _corrupt(path, f"fmt chunk of {len(body)} bytes, expected at least 16")
    tag, channels, rate, _, _, bits = struct.unpack(endian + "HHIIHH", body[:16])
    if tag == _EXTENSIBLE:
        if len(body) < 26:
            raise _corrupt(path, "WAVE_FORMAT_EXTENSIBLE fmt chunk without its sub-format")
        tag = struct.unpack(endian + "H", body[24:26])[0]
    if channels == 0:
        raise _corrupt(path, "the header says 0 channels")
    if tag not in (_PCM, _FLOAT):
        raise _unsupported(path, f"Unknown wave file format: format tag {tag:#06x}")
    if bits == 0 or bits % 8 or bits > 64:
        raise _unsupported(path, f"Unsupported bit depth: {bits}-bit samples")
    sample_bytes = bits // 8
    if tag == _FLOAT:
        if sample_bytes not in (4, 8):
            raise _unsupported(path, f"Unsupported bit depth: {bits}-bit float samples")
        return channels, rate, sample_bytes, "float"
    return channels, rate, sample_bytes, "uint" if sample_bytes == 1 else "int"


def open_wav_info(path: str | os.PathLike[str]) -> WavInfo:  # noqa: C901
    """Parse a WAV header without reading the samples.

    Raises:
        AudioError: the file is missing, a directory, not a RIFF/WAVE file, truncated or
            corrupt, uses an unsupported encoding, holds no frames, or has a 0 Hz rate.
    """
    path = Path(path)
    _check_file(path)
    file_size = path.stat().st_size
    with path.open("rb") as f:
        head = _read_exact(f, 12, path, "RIFF header")
        endian = ">" if head[:4] == b"RIFX" else "<"
        fmt: tuple[int, int, int, str] | None = None
        data_size_64: int | None = None
        while True:
            chunk = f.read(8)
            if len(chunk) < 8:
                raise _corrupt(path, "no data chunk" if fmt else "no fmt chunk")
            chunk_id, size = chunk[:4], struct.unpack(endian + "I", chunk[4:])[0]
            if chunk_id == b"ds64":
                body = _header_chunk(f, size, file_size, path, "ds64 chunk")
                if len(body) < 16:
                    raise _corrupt(path, f"ds64 chunk of {len(body)} bytes, expected at least"
                                         " 16 (RF64 sizes)")
                data_size_64 = struct.unpack("<Q", body[8:16])[0]
            elif chunk_id == b"fmt ":
                fmt = _parse_fmt(_header_chunk(f, size, file_size, path, "fmt chunk"), endian,
                                 path)
            elif chunk_id == b"data":
                if fmt is None:
                    raise _corrupt(path, "data chunk before the fmt chunk")
                if size == _RF64_SIZE and data_size_64 is not None:
                    size = data_size_64
                break
            else:
                f.seek(size + size % 2, os.SEEK_CUR)
        offset = f.tell()
    channels, rate, sample_bytes, encoding = fmt
    if size > file_size - offset:
        raise AudioError(
            f"{path} is a truncated WAV file (its data chunk declares {size} bytes but"
            f" {max(0, file_size - offset)} remain). If it was recorded to a stream,"
            " rewrite its header, e.g. `sox input.wav output.wav`."
        )
    if rate <= 0:
        raise AudioError(f"{path} has a sample rate of {rate} Hz in its header (corrupt file)")
    frames = size // (channels * sample_bytes)
    if frames == 0:
        raise AudioError(f"{path} is empty: it holds no audio frames")
    info = WavInfo(path, rate, channels, frames, sample_bytes, encoding, endian == ">", offset)
    check_duration(info)
    return info


def check_duration(info: WavInfo, max_duration_s: float = MAX_DURATION_S) -> None:
    """Refuse audio longer than ``max_duration_s`` (AudioError naming frames, rate and length)."""
    if info.frames > max_duration_s * info.rate:
        raise AudioError(
            f"{info.path} is refused: its header says {info.frames:,} frames at {info.rate:,} Hz,"
            f" {info.duration_s / 3600:.3g} hours of audio (at most {max_duration_s / 3600:g}"
            " hours); if the sample rate in its header is wrong, rewrite it, e.g."
            " `sox -r 16000 input.wav output.wav`"
        )


def _decode(raw: bytes, info: WavInfo) -> NDArray[np.float64]:
    """Bytes of whole frames to float64 samples shaped ``(frames, channels)``."""
    b, order = info.sample_bytes, ">" if info.big_endian else "<"
    if info.encoding == "float":  # NaN, infinite or absurd samples refused, naming the file
        x = float_samples(np.frombuffer(raw, dtype=f"{order}f{b}"), f"{info.path}'s samples")
    elif info.encoding == "uint":
        x = (np.frombuffer(raw, dtype=np.uint8).astype(np.float64) - 128.0) / 128.0
    elif b in (2, 4, 8):
        x = np.frombuffer(raw, dtype=f"{order}i{b}").astype(np.float64) / float(2 ** (8 * b - 1))
    else:  # 3, 5, 6, 7 bytes: widen to int64, sign-extended
        cells = np.frombuffer(raw, dtype=np.uint8).reshape(-1, b)
        if info.big_endian:
            cells = cells[:, ::-1]
        wide = np.zeros((cells.shape[0], 8), dtype=np.uint8)
        wide[:, 8 - b :] = cells  # the value in the top bytes: left-justified
        values = wide.view("<i8")[:, 0] >> (8 * (8 - b))
        x = values.astype(np.float64) / float(2 ** (8 * b - 1))
    return x.reshape(-1, info.channels)


class WavReader:
    """A WAV file read block by block: the memory used does not grow with the file.

    Use as a context manager (or call :meth:`close`)::

        with WavReader(path) as reader:
            for block in reader.blocks(65536):   # float64, (frames, channels)
                ...

    Args:
        path: the WAV file.

    Raises:
        AudioError: as :func:`open_wav_info`.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.info = open_wav_info(path)
        self._file: BinaryIO | None = self.info.path.open("rb")

    def __enter__(self) -> WavReader:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def close(self) -> None:
        """Release the file (safe to call twice)."""
        if self._file is not None:
            self._file.close()
            self._file = None

    def blocks(self, block_frames: int = DEFAULT_BLOCK_FRAMES) -> Iterator[NDArray[np.float64]]:
        """The samples from the first frame on, ``block_frames`` frames at a time.

        Each block is float64 shaped ``(frames, channels)``; the last may be shorter.
        """
        if isinstance(block_frames, bool) or not isinstance(block_frames, int) or block_frames < 1:
            raise AudioError(f"block_frames must be a positive integer, got {block_frames!r}")
        if self._file is None:
            raise AudioError(f"{self.info.path} is closed")
        info = self.info
        frame_bytes = info.channels * info.sample_bytes
        self._file.seek(info.data_offset)
        left = info.frames
        while left > 0:
            n = min(block_frames, left)
            raw = self._file.read(n * frame_bytes)
            if len(raw) != n * frame_bytes:
                raise AudioError(f"{info.path} is a truncated WAV file (it shrank while read)")
            left -= n
            yield _decode(raw, info)


def check_samples(path: str | os.PathLike[str]) -> WavInfo:
    """Refuse a WAV file any reader would refuse, its samples too; returns its header.

    Every sample of a float file is decoded block by block as every reader decodes it
    (:meth:`WavReader.blocks`, :data:`DEFAULT_BLOCK_FRAMES` frames at a time: the memory
    of one block whatever the file's length), so NaN, infinite or absurd samples are
    refused by the readers' one check (``audio.common.float_samples``) with their
    message. Integer PCM holds no such sample: only its header is read.

    Raises:
        AudioError: as :func:`open_wav_info`, or a float sample the readers refuse.
    """
    with WavReader(path) as reader:
        if reader.info.encoding == "float":
            for _ in reader.blocks():
                pass
        return reader.info


def read_wav(path: str | os.PathLike[str]) -> tuple[NDArray[np.float64], int]:
    """Read a whole WAV file as float samples (see the module docstring for formats).

    Returns:
        ``(samples, rate)``: float64 samples shaped ``(frames, channels)`` and the sample
        rate in Hz.

    Raises:
        AudioError: the file is missing, a directory, not a RIFF/WAVE file, truncated or
            corrupt, uses an unsupported encoding, holds no frames, has a 0 Hz rate, or
            holds NaN/infinite float samples.
    """
    with WavReader(path) as reader:
        info = reader.info
        refuse_over_budget(
            2 * info.frames * info.channels * np.dtype(np.float64).itemsize,
            f"read all of {info.path} at once ({info.duration_s:.4g} s, {info.channels}"
            " channel(s))",
            "give a shorter file",
            AudioError,
        )
        samples = np.concatenate(list(reader.blocks()))
        return samples, info.rate


def to_mono(samples: ArrayLike, channel: int | None = None) -> NDArray[np.float64]:
    """Reduce ``(frames, channels)`` samples to mono.

    Args:
        samples: shaped ``(frames, channels)``, or 1-D (already mono, one channel).
        channel: ``None`` for the mean of all channels, or the 0-based channel to keep.

    Returns:
        float64 samples shaped ``(frames,)``.
    """
    x = np.asarray(samples, dtype=np.float64)
    if x.ndim == 1:
        x = x[:, np.newaxis]
    elif x.ndim != 2:
        raise AudioError(f"samples must be shaped (frames, channels), got shape {x.shape}")
    n_channels = x.shape[1]
    if n_channels == 0:
        raise AudioError("samples have no channels (shape (frames, 0))")
    if channel is None:
        return x.mean(axis=1)
    if isinstance(channel, bool) or not isinstance(channel, int | np.integer):
        raise AudioError(f"channel must be an integer index or None, got {channel!r}")
    if not 0 <= channel < n_channels:
        raise AudioError(
            f"channel {channel} does not exist: the audio has {n_channels} channel(s), "
            f"numbered 0..{n_channels - 1}"
        )
    return x[:, int(channel)].copy()


def write_wav_int16(path: str | os.PathLike[str], samples: ArrayLike, rate: int) -> None:
    """Write samples in [-1, 1] as a 16-bit PCM WAV (values outside are clipped).

    Args:
        path: file to write (its directory must exist; nothing or a regular file there,
            replaced whole: ``limits.written_atomically``).
        samples: shaped ``(frames,)`` or ``(frames, channels)``.
        rate: sample rate, Hz.
    """
    rate = check_rate(rate)
    x = float_samples(samples, "samples")
    if x.ndim not in (1, 2):
        raise AudioError(f"samples must be shaped (frames,) or (frames, channels), got {x.shape}")
    data = np.round(np.clip(x, -1.0, 1.0) * 32767.0).astype(np.int16)
    from scipy.io import wavfile  # here: scipy.io takes ~0.3 s to load, and nodes never write

    try:
        with written_atomically(path, "wav file") as stream:
            wavfile.write(stream, rate, data)
    except (OSError, ValueError) as error:  # one line naming the file and why
        raise AudioError(str(error)) from None
