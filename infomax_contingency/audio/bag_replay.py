"""A recorded session's windows served again: what mic_node's ``source: bag`` publishes.

A session bag (recorder_node) holds the audio when it was recorded (``/audio``, chunks of
mono float32 samples at the rate of the graph's ``audio`` topic) and always the bits of
the microphone stream it heard (``/sound_step``, with ``/sound_energy`` beside them).
:class:`BagReplay` serves one window at a time:

* with audio: the recorded samples windowed again (one window = ``window_s``), their
  energy and **no bit** — the caller binarizes them with its own threshold, so a
  replay can try another threshold; the bits equal the recorded ones for the threshold
  the session used. With ``samples=True`` each window's samples are kept as well
  (:attr:`BagReplay.last_samples`), for a bit source that looks at the samples
  (:mod:`~infomax_contingency.audio.bitsources`);
* without audio: the recorded energy and the **recorded bit** of each step of the first
  stream heard, in step order.

Either way a window the session recorded as withheld (heard during the robot's declared
own sound) is served withheld again (:attr:`BagReplay.last_withheld`); with audio, the
recorded steps are the last windows of the audio (calibration windows come first).

The robot's recorded decisions for the same steps are :attr:`BagReplay.decisions`
(controller_node's ``controller: recorded:BAG`` answers with them, for a faithful
replay). Nothing here imports rclpy: the bag is read with ``rosbags``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

from infomax_contingency.audio.bag import read_topics
from infomax_contingency.audio.common import AudioError
from infomax_contingency.audio.energy import WindowAssembler, frame_energies_db
from infomax_contingency.audio.threshold import calibration_window_count
from infomax_contingency.audio.windows import SourceWindow, WindowSource
from infomax_contingency.core.model import Withheld
from infomax_contingency.core.stepfields import StepBit, bit_of, decision_of, valid_messages

BAG_TOPICS = ("/audio", "/sound_step", "/sound_energy", "/vocalize_step")
"""Topics a bag replay reads (their types: :data:`~infomax_contingency.audio.bag.SESSION_TYPES`)."""


def recorded_decisions(directory: Path, warn: Callable[[str], None] | None = None
                       ) -> list[bool]:
    """The robot's recorded decision for each step (from 1) of the session's first stream.

    ``decisions[t - 1]`` answers step ``t``; a step without a recorded decision is False.
    ``warn`` is told of a bag cut by a killed recorder (read up to its last chunk) and of
    malformed step messages (skipped, as the live nodes ignore them).

    Raises:
        BagReadError: the bag cannot be read, is damaged, or is not a session (no
            ``sound_step``, or topics of other types).
        AudioError: it holds no valid ``sound_step`` message (no stream to follow).
    """
    topics = read_topics(directory, ("/sound_step", "/vocalize_step"),
                         required=("/sound_step", "/vocalize_step"), warn=warn)
    bits = _valid_bits(directory, topics["/sound_step"], warn)
    stream, steps = _first_stream(directory, bits)
    decisions = valid_messages(((t, m.data) for t, m in topics["/vocalize_step"]), decision_of,
                               "/vocalize_step", warn)
    decided = {d.step: d.vocalize for _, d in decisions if d.stream == stream}
    return [decided.get(step, False) for step in range(1, steps + 1)]


def _valid_bits(directory: Path, sound_steps: list, warn: Callable[[str], None] | None
                ) -> list[StepBit]:
    """The well-formed recorded bits, in order (the malformed ones skipped, ``warn`` told).

    Raises:
        AudioError: there is none (no stream to follow).
    """
    bits = [bit for _, bit in valid_messages(((t, m.data) for t, m in sound_steps), bit_of,
                                             "/sound_step", warn)]
    if not bits:
        raise _no_stream(directory)
    return bits


def _no_stream(directory: Path) -> AudioError:
    """The error of a session without a valid recorded bit (no stream to follow)."""
    return AudioError(f"the session {directory} holds no valid sound_step messages: nothing to"
                      " replay")


def _first_stream(directory: Path, bits: list[StepBit]) -> tuple[int, int]:
    """(stream id, last step) of the first mic stream recorded."""
    stream = bits[0].stream
    return stream, max(bit.step for bit in bits if bit.stream == stream)


class BagReplay(WindowSource):
    """The windows of a session bag, one at a time (see the module docstring).

    Args:
        directory: the bag.
        window_s: window length, seconds (the model's dt).
        audio_rate_hz: sample rate of the recorded ``audio`` topic, Hz.
        samples: keep each window's samples (a bag with audio only; a bag without
            audio has none to keep).

    A bag cut by a killed recorder is replayed up to its last complete chunk; what was
    cut, and how many malformed step messages were skipped (as the live nodes ignore
    them), are in :attr:`warnings` (to be logged by the caller).

    Raises:
        BagReadError: the bag cannot be read, is damaged, or holds neither audio nor
            bits (topics of other types, or another robot's: named in the message).
        AudioError: it holds no complete window, or no audio and no valid bit.
    """

    def __init__(
        self, directory: Path, window_s: float, audio_rate_hz: int, samples: bool = False
    ) -> None:
        self.directory = Path(directory)
        self.warnings: list[str] = []
        """What the replay lacks (a bag cut by a killed recorder, malformed step messages
        skipped), one line each."""
        topics = read_topics(self.directory, BAG_TOPICS, required=[("/audio", "/sound_step")],
                             warn=self.warnings.append)
        self.has_audio = bool(topics["/audio"])
        self.windows: list[tuple[float, bool | None]]
        self.window_samples: np.ndarray | None = None
        """The windows' samples, one per row (``samples=True`` and audio), else None."""
        bits = [bit for _, bit in valid_messages(
            ((t, m.data) for t, m in topics["/sound_step"]), bit_of, "/sound_step",
            self.warnings.append)]
        if not bits and not self.has_audio:
            raise _no_stream(self.directory)
        stream = bits[0].stream if bits else None
        recorded = sorted((bit.step, bit.observation) for bit in bits if bit.stream == stream)
        if self.has_audio:
            assembler = WindowAssembler(audio_rate_hz, window_s)
            energies: list[float] = []
            rows: list[np.ndarray] = []
            for _, chunk in topics["/audio"]:
                chunk_samples = np.asarray(chunk.data, dtype=np.float32)
                if samples:
                    rows.extend(assembler.push_windows(chunk_samples))
                else:
                    energies.extend(assembler.push(chunk_samples))
            if samples:
                width = assembler.samples_per_window
                self.window_samples = np.array(rows, dtype=np.float64).reshape(-1, width)
                energies = list(frame_energies_db(self.window_samples))
            self.windows = [(float(e), None) for e in energies]
        else:
            # Calibration windows (energy, no bit) come first: the last energies are the
            # steps' (an energy not recorded is nan).
            energies = [float(m.data) for _, m in topics["/sound_energy"]][-len(recorded):]
            energies = [math.nan] * (len(recorded) - len(energies)) + energies
            self.windows = [(energy, y.bit if isinstance(y, Withheld) else y) for energy, (_, y)
                            in zip(energies, recorded, strict=True)]
        withheld = [isinstance(y, Withheld) for _, y in recorded][-len(self.windows):]
        self.withheld = [False] * (len(self.windows) - len(withheld)) + withheld
        """Per window: recorded as withheld."""
        if not self.windows:
            raise AudioError(f"the session {self.directory} holds no complete window of audio")
        self.position = 0

    replay = True

    def take(self) -> list[SourceWindow]:
        """The next window (its samples if kept, its recorded bit if no audio); [] at the end."""
        found = self.next_window()
        if found is None:
            return []
        energy, bit = found
        return [SourceWindow(energy, self.last_samples, bit, withheld=self.last_withheld)]

    @property
    def finished(self) -> bool:
        """True once the last window was served."""
        return self.position >= len(self.windows)

    def read_ahead(
        self, seconds: float, window_s: float
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Energies and (if kept) samples of the first ``seconds``' windows."""
        energies = self.calibration_energies(seconds, window_s)
        if self.window_samples is None:
            return energies, None
        return energies, self.calibration_windows(seconds, window_s)

    def describe(self) -> str:
        what = "its audio" if self.has_audio else "its recorded bits (no audio recorded)"
        return f"the session {self.directory}: {self.n_windows} windows from {what}"

    @property
    def n_windows(self) -> int:
        """Windows in the session."""
        return len(self.windows)

    def next_window(self) -> tuple[float, bool | None] | None:
        """(energy dB, recorded bit or None to binarize) of the next window; None at the end."""
        if self.position >= len(self.windows):
            return None
        self.position += 1
        return self.windows[self.position - 1]

    @property
    def last_withheld(self) -> bool:
        """Was the window :meth:`next_window` served last recorded as withheld."""
        return self.position > 0 and self.withheld[self.position - 1]

    @property
    def last_samples(self) -> np.ndarray | None:
        """Samples of the window :meth:`next_window` served last (None without samples)."""
        if self.window_samples is None or self.position == 0:
            return None
        return self.window_samples[self.position - 1]

    def calibration_energies(self, calibration_s: float, window_s: float) -> np.ndarray:
        """Energies of the first ``calibration_s`` seconds (for ``threshold_mode`` calibrate)."""
        count = calibration_window_count(calibration_s, window_s)
        return np.array([energy for energy, _ in self.windows[:count]])

    def calibration_windows(self, calibration_s: float, window_s: float) -> np.ndarray:
        """Samples of the first ``calibration_s`` seconds' windows, one per row.

        Raises:
            AudioError: the replay keeps no samples (``samples=False`` or no audio).
        """
        if self.window_samples is None:
            raise AudioError(f"the replay of {self.directory} keeps no samples of audio")
        return self.window_samples[: calibration_window_count(calibration_s, window_s)]
