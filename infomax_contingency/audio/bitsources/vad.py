"""The ``vad`` bit source: WebRTC's voice-activity detector (``webrtcvad``).

Frames of 10, 20 or 30 ms; the bit is 1 when the frames that end in the window and are
voiced add up to at least ``vad_min_voiced_s``. It takes 8, 16, 32 or 48 kHz only and has
no threshold. Samples are clipped to full scale for the detector's 16-bit frames;
digital silence is never voiced.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from infomax_contingency.audio.bitsources.base import (
    BitSource,
    NameArgument,
    SettingError,
    setting,
)
from infomax_contingency.errors import MissingPackageError

VAD_RATES_HZ = (8000, 16000, 32000, 48000)
"""Sample rates webrtcvad accepts."""

VAD_FRAMES_MS = (10, 20, 30)
"""Frame lengths webrtcvad accepts, ms."""


@dataclasses.dataclass(frozen=True)
class VadSettings:
    """Settings of ``vad`` (mic_node parameters of the same names)."""

    vad_aggressiveness: int = setting(
        2, "How readily the voice-activity detector calls a frame unvoiced (bit_source vad)",
        low=0, high=3,
    )
    vad_frame_ms: int = setting(
        30, "Voice-activity frame length: 10, 20 or 30 (bit_source vad)", low=10, high=30,
        unit="ms",
    )
    vad_min_voiced_s: float = setting(
        0.1, "Voiced time that makes a window active (bit_source vad; at most the window,"
        " the params' dt)",
        low=0.001, high=10.0, unit="s",
    )


class VadSource(BitSource):
    """WebRTC voice-activity detection: a window is active with ``vad_min_voiced_s`` of voice.

    Samples are clipped to [-1, 1] and rounded to 16-bit PCM; frames run on without regard
    to window edges (a frame counts for the window it ends in; the samples of an
    unfinished frame wait for the next window), so any window length works and no audio
    is skipped.
    """

    name = "vad"
    summary = "WebRTC voice-activity detector: at least vad_min_voiced_s of voiced frames"
    Settings = VadSettings
    name_modes = {"": (NameArgument("vad_aggressiveness", "AGGRESSIVENESS"),
                       NameArgument("vad_min_voiced_s", "MIN_VOICED_S"))}  # fmt: skip

    def __init__(
        self,
        settings: VadSettings,
        rate_hz: int,
        window_s: float,
        on_problem: Callable[[str], None] | None = None,
    ) -> None:
        try:
            import webrtcvad  # here, so the other sources need no webrtcvad
        except ModuleNotFoundError:  # optional (no rosdep key): say which package
            raise MissingPackageError("webrtcvad-wheels", "bit source 'vad'") from None

        super().__init__(settings, rate_hz, window_s, on_problem)
        self.aggressiveness = settings.vad_aggressiveness
        self.frame_ms = settings.vad_frame_ms
        self.min_voiced_s = settings.vad_min_voiced_s
        self._frame = rate_hz * self.frame_ms // 1000
        self._vad = webrtcvad.Vad(self.aggressiveness)
        self._rest = np.empty(0, dtype=np.int16)
        self.last_voiced_s = math.nan
        """Voiced time found in the last window, seconds."""
        self.voiced_windows = 0
        """Windows found active so far."""

    @classmethod
    def check_settings(cls, settings: VadSettings, rate_hz: int, window_s: float) -> None:
        """A rate and frame webrtcvad takes; a voiced time a window can hold."""
        if rate_hz not in VAD_RATES_HZ:
            rates = ", ".join(map(str, VAD_RATES_HZ))
            raise SettingError(
                "rate_hz", f"= {rate_hz}: bit_source vad takes audio at {rates} Hz only (webrtcvad)"
            )
        if settings.vad_frame_ms not in VAD_FRAMES_MS:
            frame_ms = settings.vad_frame_ms
            raise SettingError("vad_frame_ms", f"= {frame_ms}: must be 10, 20 or 30 ms")
        if settings.vad_min_voiced_s > window_s:
            raise SettingError("vad_min_voiced_s", f"= {settings.vad_min_voiced_s:g} s is longer"
                               f" than a window (window_s = {window_s:g} s): no window could be"
                               " active")  # fmt: skip

    def decide(self, x: NDArray[np.float64]) -> bool:
        """Voiced time in the window >= ``vad_min_voiced_s``."""
        pcm = np.round(np.clip(x, -1.0, 1.0) * 32767.0).astype(np.int16)
        pcm = np.concatenate((self._rest, pcm))
        n_frames = pcm.size // self._frame
        voiced = sum(
            self._vad.is_speech(frame.tobytes(), self.rate_hz)
            for frame in pcm[: n_frames * self._frame].reshape(n_frames, self._frame)
        )
        self._rest = pcm[n_frames * self._frame :].copy()
        self.last_voiced_s = voiced * self.frame_ms / 1000.0
        bit = self.last_voiced_s >= self.min_voiced_s - 1e-9
        self.voiced_windows += bit
        return bit

    def ready_message(self) -> str:
        return f"voice-activity detection ready (aggressiveness {self.aggressiveness})"

    def diagnostic_values(self) -> dict[str, Any]:
        """The VAD's settings and last window."""
        return {
            "vad_aggressiveness": self.aggressiveness,
            "vad_frame_ms": self.frame_ms,
            "vad_min_voiced_s": self.min_voiced_s,
            "last_voiced_s": self.last_voiced_s,
            "voiced_windows": self.voiced_windows,
            "calibration_state": self.state,
        }
