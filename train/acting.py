"""How a trained network acts: its temperature, checked wherever one is given (a name, a file, the CLI)."""

from __future__ import annotations

import math


def check_temperature(value, what: str) -> float:
    """A finite number >= 0, as a float; anything else is refused in one line."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
        raise ValueError(f"{what}: temperature={value!r} is invalid: a finite number >= 0 (0 acts greedily, "
                         f"1 samples as trained)")
    return float(value)
