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

ATTENTIVE_ABOVE = 0.9
"""The default upper threshold: attentive once 90 % sure that someone answers."""
BORED_BELOW = 0.1
"""The default lower threshold: bored again once 90 % sure that nobody does (symmetric
to :data:`ATTENTIVE_ABOVE` in log odds). A belief that dips between the two, as it does
while a partner's replies are masked for a while, keeps the posture."""


class PostureHysteresis:
    """Two-threshold switch from belief to posture.

    Args:
        attentive_above: turn attentive when the belief is strictly above this.
        bored_below: turn bored when the belief is strictly below this
            (``0 <= bored_below < attentive_above <= 1``).
        initial: posture before any belief arrives.
    """

    def __init__(
        self, attentive_above: float = ATTENTIVE_ABOVE, bored_below: float = BORED_BELOW,
        initial: str = BORED,
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
