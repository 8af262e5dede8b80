"""Real synthetic speech for the simulated rooms: sentences spoken by espeak-ng.

The rooms of :data:`~infomax_contingency.sim.rooms.ROOM_SOUNDS` whose talkers, TV or
partner speak with ``voice`` ``tts`` play excerpts of a bank of sentences rendered by
the ``espeak-ng`` program (a local text-to-speech engine: nothing is downloaded; Debian
and Ubuntu package it as ``espeak-ng``, which ``make setup`` installs). espeak-ng is
deterministic, so a room built on it is deterministic from its seed, as the other rooms.

Each voice of :data:`TTS_VOICES` (an espeak-ng voice with a variant, a speed in words per
minute and a pitch 0-99) reads all of :data:`TTS_SENTENCES` once, in an order of its own;
its recording, resampled to the room's rate, normalised to unit RMS over its voiced
parts' time (pauses included), is cached per process (rendering all voices takes well
under a second). A second bank, :func:`children_bank`, holds children's voices (high
pitch, fast) calling out :data:`CHILD_SENTENCES` for the ``playroom``.
"""

from __future__ import annotations

import functools
import subprocess
import tempfile
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

TTS_SENTENCES = (
    "Good morning, did you sleep well last night?",
    "The train to the city leaves at a quarter past nine.",
    "Could you pass me the salt and the pepper, please?",
    "We should paint the kitchen a lighter colour this spring.",
    "I think the meeting was moved to Thursday afternoon.",
    "The children are playing football in the garden.",
    "Tomorrow it will rain in the north and clear up later in the day.",
    "Have you seen my keys? I left them on the table.",
    "The museum opens at ten and closes at six in the evening.",
    "She said the concert was the best one of the whole year.",
    "Let us take the long way home along the river.",
    "And now the news: the council voted on the new bridge today.",
)
"""What the voices say (one bank per voice; each reads every sentence)."""

TTS_VOICES = (
    ("en-us+m3", 165, 40),
    ("en-gb+f2", 150, 60),
    ("en-us+f4", 175, 70),
    ("en-gb-scotland+m1", 155, 35),
    ("en+m7", 170, 50),
    ("en-us+f1", 160, 55),
)
"""espeak-ng voices of the bank: (voice+variant, words per minute, pitch 0-99)."""

PAUSE_BETWEEN_SENTENCES_S = 0.35
"""Silence between two sentences of a voice's recording, seconds."""

CHILD_SENTENCES = (
    "Look at me! I can jump really high!",
    "My turn, my turn! Give it back!",
    "Mummy, come and see what I made!",
    "You're it! You can't catch me!",
    "That's mine, I had it first!",
    "Let's build a tower, a really big one!",
    "Again! Do it again!",
    "Where is the red car? I want the red car!",
    "Ready or not, here I come!",
    "Wow, look, the dinosaur is eating the train!",
)
"""What the children of :func:`children_bank` call out (each voice says every one)."""

CHILD_VOICES = (
    ("en-us+f5", 200, 95),
    ("en+f3", 210, 99),
    ("en-us+Alicia", 195, 90),
    ("en-us+f2", 215, 97),
)
"""espeak-ng voices of the children's bank: (voice+variant, words per minute, pitch 0-99);
their fundamental is about 300-400 Hz."""

CHILD_PAUSE_S = 0.2
"""Silence between two sentences of a child's recording, seconds."""


class TtsUnavailableError(RuntimeError):
    """espeak-ng is missing or failed (one line: what to install)."""


def _render(text: str, voice: str, speed_wpm: int, pitch: int) -> tuple[NDArray[np.float64], int]:
    """``text`` spoken by espeak-ng: mono samples in [-1, 1] and the rate, Hz.

    espeak-ng writes a wav file, which the package's one wav reader reads.
    """
    from infomax_contingency.audio.wav import read_wav

    with tempfile.TemporaryDirectory() as directory:
        path = Path(directory) / "speech.wav"
        command = ["espeak-ng", "-v", voice, "-s", str(speed_wpm), "-p", str(pitch),
                   "-w", str(path), text]
        try:
            subprocess.run(command, capture_output=True, check=True, timeout=60)
        except FileNotFoundError:
            raise TtsUnavailableError(
                "this room speaks with espeak-ng, which is not installed: apt-get install"
                " espeak-ng"
            ) from None
        except (subprocess.CalledProcessError, subprocess.TimeoutExpired) as error:
            raise TtsUnavailableError(f"espeak-ng failed on voice {voice!r}: {error}") from None
        samples, rate = read_wav(path)
    return samples[:, 0], rate


@functools.lru_cache(maxsize=4)
def tts_bank(rate: int) -> tuple[NDArray[np.float64], ...]:
    """Every voice of :data:`TTS_VOICES` reading :data:`TTS_SENTENCES`, at ``rate``, unit RMS.

    Read-only arrays; made once per process and rate. Raises
    :class:`TtsUnavailableError` without espeak-ng.
    """
    return _bank(rate, TTS_VOICES, TTS_SENTENCES, PAUSE_BETWEEN_SENTENCES_S)


@functools.lru_cache(maxsize=4)
def children_bank(rate: int) -> tuple[NDArray[np.float64], ...]:
    """Every voice of :data:`CHILD_VOICES` saying :data:`CHILD_SENTENCES`, at ``rate``, unit RMS.

    As :func:`tts_bank` (read-only, cached, deterministic), a bank of its own.
    """
    return _bank(rate, CHILD_VOICES, CHILD_SENTENCES, CHILD_PAUSE_S)


def _bank(
    rate: int,
    voices: tuple[tuple[str, int, int], ...],
    sentences: tuple[str, ...],
    pause_s: float,
) -> tuple[NDArray[np.float64], ...]:
    """Voice k reads ``sentences`` in the order ``default_rng(k).permutation``, with pauses."""
    from infomax_contingency.audio.resample import resample

    bank = []
    for k, (voice, speed, pitch) in enumerate(voices):
        order = np.random.default_rng(k).permutation(len(sentences))
        parts = []
        for index in order:
            samples, native = _render(sentences[index], voice, speed, pitch)
            parts.append(resample(samples, native, rate))
            parts.append(np.zeros(round(pause_s * rate)))
        x = np.concatenate(parts)
        x = x / np.sqrt(np.mean(x * x))
        x.setflags(write=False)
        bank.append(x)
    return tuple(bank)
