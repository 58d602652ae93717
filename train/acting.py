"""How a trained network acts: its temperature and the least belief it steps onto a block with, each checked
wherever one is given (a name, a file, the CLI)."""

from __future__ import annotations

import math

MIN_TEMPERATURE = 0.01


def check_temperature(value, what: str) -> float:
    """0, or a finite number >= 0.01 (below that, ``logits / temperature`` overflows float32), as a float;
    anything else is refused in one line."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or \
            not (value == 0 or value >= MIN_TEMPERATURE):
        raise ValueError(f"{what}: temperature={value!r} is invalid: 0 (greedy) or a finite number >= "
                         f"{MIN_TEMPERATURE} (1 samples as trained)")
    return float(value)


def check_min_belief(value, what: str) -> float:
    """A number in [0, 1], as a float; anything else is refused in one line."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value <= 1:
        raise ValueError(f"{what}: min_belief={value!r} is invalid: a number in [0, 1] (0 leaves the network's "
                         f"moves as they are)")
    return float(value)


ACTING = {"temperature": (check_temperature, 1.0), "min_belief": (check_min_belief, 0.0)}
"""The acting settings a checkpoint may store and a policy name may set: each one's check and default."""
