"""Recorded games that measure something else: kept out of what ``colorgrid replay rescore`` pools.

A study's practice game and a game that showed the person in the follower seat the goal (``meta.goal_view ==
"shown"``, a control) do not measure reading a hidden goal. Rescore reports each kind apart, in figures of its own,
never pooled with the others: the followers' open-loop pickups (``branch.rescore``) and the person's measures
(``human_follower.human_follower_report``) alike. The words for each kind are declared here once, for rescore's tables
and for the replay page (sent with ``/api/replays/{id}/people``: the page keeps none of its own).
"""

from __future__ import annotations

from dataclasses import dataclass

from colorgrid.enums import GameKind, GoalView, SetApart
from colorgrid.replay.format import Replay


@dataclass(frozen=True)
class ApartWords:
    """What a kind of game set apart is, in words: of a count of them, and of one."""

    games: str
    """After a count, in rescore's tables: ``2 practice game(s) of a study``."""
    game: str
    """Of one game, on the replay page (``/api/replays/{id}/people``): ``This is a practice game of a study``."""


SET_APART = {SetApart.PRACTICE: ApartWords("practice game(s) of a study", "a practice game of a study"),
             SetApart.GOAL_SHOWN: ApartWords("game(s) that showed the person the goal (a control)",
                                      "a game that showed the person the goal (a control)")}
"""The kinds of game reported apart, each with what it is, in words."""


def set_apart(replay: Replay) -> SetApart | None:
    """The ``SET_APART`` kind of ``replay``, or None for a game that is pooled: a study's practice game
    (``meta.study.kind``) whatever it showed, else a game that showed the goal (``meta.goal_view``)."""
    if (replay.meta.get("study") or {}).get("kind") == GameKind.PRACTICE:
        return SetApart.PRACTICE
    return SetApart.GOAL_SHOWN if replay.meta.get("goal_view") == GoalView.SHOWN else None


def set_apart_words(kind: str | None) -> str | None:
    """One game of the ``SET_APART`` kind ``kind`` in words (None for a game that is pooled)."""
    return None if kind is None else SET_APART[kind].game
