"""A study game's figures: its scores and what its replay says of the follower, computed once per game.

The study service writes them into the ``games`` table when a game ends (``game_over``), so the
export's ``trials`` table and the admin page read them from the database. ``game_figures`` is the
one computation: the export calls it too, on the replay file, for games recorded before the
figures were stored (schema version 1).
"""

from __future__ import annotations

import json

import numpy as np

from colorgrid.config import AGENTS, FOLLOWER, LEADER
from colorgrid.replay import Replay
from server.study.exclusions import attention_figures

SCORES = {"team_score": "team", "leader_score": AGENTS[LEADER], "follower_score": AGENTS[FOLLOWER]}
"""Each score column and its key in the game's scores (``colorgrid.roles.scores``: ``team`` and an agent's name)."""
FIGURES: dict[str, type] = {
    "steps": int,
    "follower_goal_pickups": int,
    "follower_wrong_pickups": int,
    "follower_net_pickups": int,
    "leader_goal_pickups": int,
    "leader_wrong_pickups": int,
    "belief_accuracy": float,  # None: the follower keeps no belief
    "deadline_misses": int,
    "viewport": str,  # JSON: the page's [width, height]
    "user_agent": str,
    "away_s": float,  # server.study.exclusions: seconds hidden or out of focus
    "idle_s": float,  # the longest stretch without a key
    "round_trip_ms": float,  # the median round trip during play (None: none measured; not in a replay)
}
"""Each figure ``game_figures`` reads from a game's replay, and its Python type (the exported ``trials`` columns)."""


def score_figures(scores: dict | None) -> dict:
    """The score columns of a game's scores (``{"team": ..., "leader": ..., "follower": ...}``; None: all None)."""
    return {column: (scores or {}).get(key) for column, key in SCORES.items()}


def game_figures(replay: Replay) -> dict:
    """The ``FIGURES`` of one study game (a 1:1 team) from its replay."""
    final = replay.final()
    leader, follower = AGENTS[LEADER], AGENTS[FOLLOWER]
    beliefs = replay.goal_probs.get(follower) or []
    correct = [int(np.argmax(b)) == replay.goal[t] for t, b in enumerate(beliefs)]
    client = replay.meta.get("client") or {}
    return {
        "steps": replay.num_steps,
        "follower_goal_pickups": final[f"{follower}_goal_pickups"],
        "follower_wrong_pickups": final[f"{follower}_wrong_pickups"],
        "follower_net_pickups": final[f"{follower}_goal_pickups"] - final[f"{follower}_wrong_pickups"],
        "leader_goal_pickups": final[f"{leader}_goal_pickups"],
        "leader_wrong_pickups": final[f"{leader}_wrong_pickups"],
        "belief_accuracy": float(np.mean(correct)) if correct else None,
        "deadline_misses": len(replay.meta.get("deadline_misses", [])),
        "viewport": json.dumps(client.get("viewport")),
        "user_agent": client.get("user_agent"),
        **attention_figures(replay),
        "round_trip_ms": None,  # measured by the page during play, kept by the study service (not in the replay)
    }
