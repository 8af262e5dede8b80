"""Calibration audio: window energies from a WAV file or a live recording, and their histogram.

The threshold itself is fitted by :mod:`infomax_contingency.audio.threshold`; this
module gathers the energies it is fitted on and draws them for the user.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from infomax_contingency.audio.background import level_and_faults
from infomax_contingency.audio.bitsources import WindowLevels
from infomax_contingency.audio.capture import MicrophoneStream
from infomax_contingency.audio.common import PROCESSING_RATE_HZ, check_positive
from infomax_contingency.audio.devices import AudioBackend, AudioDeviceError, LogFunction
from infomax_contingency.audio.energy import iter_wav_windows
from infomax_contingency.audio.windows import WavReplay


def energies_from_wav(
    path: str | Path,
    window_s: float,
    channel: int | None = None,
    rate: int = PROCESSING_RATE_HZ,
    max_windows: int | None = None,
    bit_source: str = "energy",
    meter: WindowMeter | None = None,
) -> NDArray[np.float64]:
    """Window levels (dB) of a WAV file, exactly as the wav source computes them.

    The file is read block by block (:func:`~infomax_contingency.audio.energy.iter_wav_windows`),
    so memory does not grow with its length; ``max_windows`` stops after the first ones.
    The level is ``bit_source``'s (:class:`~infomax_contingency.audio.bitsources.WindowLevels`):
    the window energy for ``energy``, the speech band's for ``speech_band``; or ``meter``'s.
    """
    levels = meter or WindowLevels(bit_source, rate)
    parts: list[NDArray[np.float64]] = []
    count = 0
    for windows in iter_wav_windows(path, window_s, channel, rate):
        parts.append(levels.levels_db(windows))
        count += windows.shape[0]
        if max_windows is not None and count >= max_windows:
            break
    out = np.concatenate(parts) if parts else np.empty(0)
    return out if max_windows is None else out[:max_windows]


class WindowMeter(Protocol):
    """What gives calibration audio its levels: windows in order (one per row) to dB."""

    def levels_db(self, windows: ArrayLike) -> NDArray[np.float64]: ...


@dataclasses.dataclass(frozen=True)
class Recording:
    """Window energies recorded from a live device.

    Attributes:
        energies_db: one energy per window (or the bit source's level: the speech band), dB.
        device: name of the device.
        device_rate: rate the device ran at, Hz.
        lost_samples: device-rate samples lost during the recording.
        gaps: gaps (reconnects) during the recording.
    """

    energies_db: NDArray[np.float64]
    device: str
    device_rate: int
    lost_samples: int
    gaps: int


def record_energies(
    device: int | str | None,
    seconds: float,
    window_s: float,
    channel: int | None = None,
    log: LogFunction | None = None,
    backend: AudioBackend | None = None,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] | None = None,
    bit_source: str = "energy",
    meter: WindowMeter | None = None,
) -> Recording:
    """Record ``seconds`` of live audio and return its window energies.

    Records ``floor(seconds / window_s)`` windows (at least 2). The queue holds the whole
    recording, so a slow reader loses nothing.

    ``clock`` and ``sleep`` go to the :class:`~infomax_contingency.audio.capture.MicrophoneStream`.
    ``bit_source`` ``speech_band``: the speech-band levels instead; ``meter``: its levels.

    Raises:
        AudioDeviceError: the device is missing, or delivers no audio for more than
            ``seconds + 5`` seconds in all.
    """
    seconds = check_positive(seconds, "seconds")
    n = max(2, int(seconds / check_positive(window_s, "window_s") + 1e-9))
    mic = MicrophoneStream(
        device,
        window_s=window_s,
        channel=channel,
        queue_s=n * window_s + 2.0,
        log=log,
        backend=backend,
        clock=clock,
        sleep=sleep,
    )
    speech = bit_source != "energy"
    levels = meter or (WindowLevels(bit_source, PROCESSING_RATE_HZ) if speech else None)
    energies: list[float] = []
    with mic:
        deadline = clock() + n * window_s + 5.0
        while len(energies) < n:
            if clock() > deadline:
                raise AudioDeviceError(
                    f"recorded only {len(energies)} of {n} windows from {mic.status().device}"
                    f" in {n * window_s + 5.0:g} s: {mic.status().last_error or 'no audio'}"
                )
            windows = mic.read_windows(0.1)[: n - len(energies)]  # a meter sees only these
            if levels is None:
                energies.extend(w.energy_db for w in windows)
            elif windows:
                energies.extend(levels.levels_db([w.samples for w in windows]).tolist())
        status = mic.status()
    return Recording(
        energies_db=np.asarray(energies),
        device=status.device,
        device_rate=status.device_rate,
        lost_samples=status.lost_samples,
        gaps=status.gaps,
    )


def energy_histogram(
    energies_db: ArrayLike,
    threshold_db: float,
    bin_db: float = 3.0,
    width: int = 40,
    max_bins: int = 30,
) -> str:
    """A text histogram of window energies with the threshold marked.

    Bin edges are placed at ``threshold_db + k * bin_db``, so the threshold falls between
    two bins and a marker line separates the quiet bins from the sound bins. Bins widen
    (to whole dB) when the range would need more than ``max_bins`` bins.

    Returns:
        Lines ``"  -63.0 .. -60.0 dB | ####### 12"``, lowest energies first.
    """
    x = np.asarray(energies_db, dtype=np.float64).ravel()
    if x.size == 0:
        return "(no windows)"
    bin_db = check_positive(bin_db, "bin_db")
    lo = min(float(x.min()), threshold_db)
    hi = max(float(x.max()), threshold_db)
    if (hi - lo) / bin_db > max_bins:
        bin_db = float(math.ceil((hi - lo) / max_bins))
    k_lo = math.floor((lo - threshold_db) / bin_db)
    k_hi = max(math.floor((hi - threshold_db) / bin_db) + 1, k_lo + 1)
    edges = threshold_db + bin_db * np.arange(k_lo, k_hi + 1)
    counts, _ = np.histogram(x, bins=edges)
    # np.histogram puts a value equal to an inner edge in the upper bin; the bit rule is
    # energy > threshold, so recount the windows exactly at the threshold as quiet.
    at_threshold = int(np.count_nonzero(x == threshold_db))
    zero = -k_lo  # index of the first bin above the threshold
    if at_threshold and 0 < zero < counts.size:
        counts[zero] -= at_threshold
        counts[zero - 1] += at_threshold
    peak = max(int(counts.max()), 1)
    lines = []
    for i, c in enumerate(counts):
        if i == zero:
            lines.append(f"  {'-' * 20} threshold {threshold_db:.1f} dB {'-' * 10}")
        bar = "#" * math.ceil(width * c / peak) if c else ""
        lines.append(f"  {edges[i]:6.1f} .. {edges[i + 1]:6.1f} dB | {bar} {c}")
    return "\n".join(lines)


def dc_offset_note(path: Path, window_s: float, channel: int | None) -> str:
    """``"; N of M windows have a DC offset ..."`` for a k-means refusal, or ``""``.

    The energy rule counts a DC offset as sound: a recording whose windows carry one
    looks as loud when quiet as with sound. The default bit source removes it.
    """
    replay = WavReplay(path, window_s, channel, samples=True)
    windows = offset = 0
    while (window := replay.next_window()) is not None:
        windows += 1
        offset += level_and_faults(window)[1].dc_offset
    if not offset:
        return ""
    return (f"; {offset} of {windows} windows have a DC offset, which the energy counts as"
            " sound: remove it (check the microphone), or use the default bit source"
            " (background), which removes it")
