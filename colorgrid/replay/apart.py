"""Recorded games that measure something else: kept out of what ``colorgrid replay rescore`` pools.

A study's practice game and a game that showed the person in the follower seat the goal (``meta.goal_view ==
"shown"``, a control) do not measure reading a hidden goal. Rescore reports each kind apart, in figures of its own,
never pooled with the others: the followers' open-loop pickups (``branch.rescore``) and the person's measures
(``human_follower.human_follower_report``) alike.
"""

from __future__ import annotations

from colorgrid.enums import GameKind
from colorgrid.replay.format import Replay

SET_APART = {GameKind.PRACTICE.value: "practice game(s) of a study",
             "goal_shown": "game(s) that showed the person the goal (a control)"}
"""The kinds of game reported apart, each with what it is, in words."""


def set_apart(replay: Replay) -> str | None:
    """The ``SET_APART`` kind of ``replay``, or None for a game that is pooled: a study's practice game
    (``meta.study.kind``) whatever it showed, else a game that showed the goal (``meta.goal_view``)."""
    if (replay.meta.get("study") or {}).get("kind") == GameKind.PRACTICE:
        return GameKind.PRACTICE.value
    return "goal_shown" if replay.meta.get("goal_view") == "shown" else None
