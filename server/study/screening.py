"""Screening: who may take part (``[screening]`` of the study file), checked before consent from the device, the
window and round trips over the play socket; a participant who fails is refused with the study's return code, and the
refusal is logged with its reason. See docs/STUDIES.md.
"""

from __future__ import annotations

import statistics
from dataclasses import dataclass

from colorgrid.configkit import check_bool, check_int, check_number, fail
from server.study.errors import ScreenedOut

SCREENED = "screening:"
"""The prefix of the reason logged for a participant refused by ``[screening]`` (``screening:viewport``, ...)."""


@dataclass(frozen=True)
class Screening:
    """Who may take part (``[screening]``): checked by the study page before the consent page, from the device, the
    window and round trips over the play socket; a participant who fails is told why and given ``return_code``, and
    the refusal is logged with its reason (they take no place in the study)."""

    keyboard: bool = True
    """Refuse a device with a touch screen and no mouse or trackpad (a phone, a tablet): the games need keys."""
    min_width: int = 0
    """The narrowest window taken, in CSS pixels (0: any)."""
    min_height: int = 0
    """The lowest window taken, in CSS pixels (0: any)."""
    pings: int = 5
    """Round trips measured over the play socket (``ping`` and its ``pong``) before consent."""
    max_round_trip_ms: float | None = None
    """The highest median of those round trips taken, in ms (None: not checked)."""
    return_code: str = ""
    """Given to a participant who is refused (put into the study's ``redirect_url`` as ``{code}``): the platform's
    code for a participant screened out."""

    def __post_init__(self):
        check_bool(self, "keyboard")
        check_int(self, "min_width", 0, 10_000, allowed="a whole number of CSS pixels in 0..10000")
        check_int(self, "min_height", 0, 10_000, allowed="a whole number of CSS pixels in 0..10000")
        check_int(self, "pings", 1, 50, allowed="a whole number in 1..50")
        check_number(self, "max_round_trip_ms", "a number of milliseconds > 0, or leave it out", lambda v: v > 0,
                     optional=True)
        if not isinstance(self.return_code, str):
            fail(self, "return_code", "a string")

    def problem(self, touch_only: bool, viewport: tuple[int, int], round_trips_ms: list[float]) -> tuple[str, str]:
        """Why a device and connection cannot take part: ``(reason, words)``, the reason as logged and the words
        for the participant; ``("", "")`` when they can."""
        if self.keyboard and touch_only:
            return "touch_only", ("This study needs a keyboard: its games are played with the arrow keys. Please "
                                  "open it on a computer with a keyboard.")
        width, height = viewport
        if width < self.min_width or height < self.min_height:
            return "viewport", (f"This study needs a browser window of at least {self.min_width} by "
                                f"{self.min_height} pixels, and yours is {width} by {height}. Please open it on a "
                                f"larger screen, or make the window larger and reload the page.")
        if self.max_round_trip_ms is not None:
            if len(round_trips_ms) < self.pings:
                return "round_trip", ("Your connection to our server could not be measured. Please reload the page "
                                      "on a steady connection.")
            median = statistics.median(round_trips_ms)
            if median > self.max_round_trip_ms:
                return "round_trip", (f"Your connection to our server is too slow for this study's games (a round "
                                      f"trip of {median:.0f} ms; they need at most {self.max_round_trip_ms:g} ms).")
        return "", ""


def screened_out(rules: Screening | None, redirect_url: str, tx, pid: str, screen: dict | None) -> ScreenedOut | None:
    """The refusal of a new participant whose ``screen`` (the page's ``touch_only``, ``viewport``,
    ``round_trips_ms``) fails the study's ``rules`` (logged in ``tx`` with its reason and the measures), or None;
    ``redirect_url``: the study's, into which the return code goes."""
    if rules is None:
        return None
    if screen is None:
        reason, words = "not_screened", ("This study checks your browser before it starts, and this page did "
                                          "not. Please open the study from your link again.")
    else:
        reason, words = rules.problem(screen["touch_only"], tuple(screen["viewport"]), screen["round_trips_ms"])
        if not reason:
            return None
    tx.log(pid, "refused", reason=SCREENED + reason, screen=screen)
    url = redirect_url.replace("{code}", rules.return_code) if redirect_url else ""
    return ScreenedOut(words, rules.return_code, url)
