"""What every part of the sweep file's checking shares: its error, the one-line message, how two parameter values
compare, and which training-log columns a sweep's trials table summarises."""

from __future__ import annotations

from typing import Any

from colorgrid.configkit import ConfigError

SUMMARY_SUFFIXES = ("team_reward", "_goal_pickups", "_wrong_pickups", "_net_pickups", "_goal_accuracy")
"""Columns the ``trials`` table summarises besides the sweep's metric (their finals are what claims compare)."""


class SweepError(ConfigError):
    """A sweep cannot run as asked: its file is wrong (the message names the place and what is allowed), or the
    cluster or resources it asks for are not there (the message names the cause and the fix)."""


def bad(where: str, value: Any, allowed: str) -> SweepError:
    return SweepError(f"{where}={value!r} is invalid: {allowed}")


def same_value(a, b) -> bool:
    """Whether two parameter values are the same (``0`` and ``0.0`` are; ``'0'`` and ``0`` are not)."""
    import numbers

    def number(v) -> bool:
        return isinstance(v, numbers.Real) and not isinstance(v, bool)

    if number(a) and number(b):
        return float(a) == float(b)
    return not (number(a) or number(b)) and str(a) == str(b)  # labels, booleans
