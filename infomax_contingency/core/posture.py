"""From the belief to the robot's posture, with hysteresis.

The robot turns ``attentive`` when P(S=1) rises above an upper threshold and turns
``bored`` again only when it falls below a lower one, so a belief hovering around a
single threshold cannot make the head twitch back and forth.
"""

from __future__ import annotations

import math

ATTENTIVE = "attentive"
BORED = "bored"
POSTURES = (ATTENTIVE, BORED)


class PostureHysteresis:
    """Two-threshold switch from belief to posture.

    Args:
        attentive_above: turn attentive when the belief is strictly above this.
        bored_below: turn bored when the belief is strictly below this
            (``0 <= bored_below < attentive_above <= 1``).
        initial: posture before any belief arrives.
    """

    def __init__(
        self, attentive_above: float = 0.9, bored_below: float = 0.2, initial: str = BORED
    ) -> None:
        if not 0.0 <= bored_below < attentive_above <= 1.0:
            raise ValueError(
                "posture thresholds must satisfy 0 <= bored_below < attentive_above <= 1;"
                f" got bored_below={bored_below}, attentive_above={attentive_above}"
            )
        if initial not in POSTURES:
            raise ValueError(f"initial posture must be one of {POSTURES}, got {initial!r}")
        self.attentive_above = float(attentive_above)
        self.bored_below = float(bored_below)
        self.posture = initial

    def update(self, belief: float) -> str | None:
        """Feed one belief; return the new posture if it changed, else None."""
        if not math.isfinite(belief) or not 0.0 <= belief <= 1.0:
            raise ValueError(f"belief must be a probability in [0, 1], got {belief!r}")
        if self.posture == BORED and belief > self.attentive_above:
            self.posture = ATTENTIVE
            return ATTENTIVE
        if self.posture == ATTENTIVE and belief < self.bored_below:
            self.posture = BORED
            return BORED
        return None
