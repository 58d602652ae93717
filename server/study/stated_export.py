"""The export's view of the follower seat: what a participant stated they believed, from a game's replay.

``server.study.export`` calls these for every game whose replay is found: the ``trials`` columns of the person's
measures (``colorgrid.replay.human_follower``, the same computation as ``colorgrid replay rescore``), each step's stated
color, and the rows of the ``probes`` and ``statements`` tables (their columns are declared in
``server.study.schema``). A leader's game has none of them.
"""

from __future__ import annotations

from colorgrid.config import AGENTS, FOLLOWER
from colorgrid.replay import Replay
from colorgrid.replay.human_follower import answer_distribution, brier, human_followers, log_loss, person_measures

SEAT = AGENTS[FOLLOWER]
"""A study's games are 1:1: the follower seat is the agent ``follower``."""


def seated(replay: Replay) -> bool:
    """Whether a person played the follower seat of ``replay``."""
    return SEAT in human_followers(replay)


def stated_figures(replay: Replay | None) -> dict:
    """The ``trials`` columns of ``schema.stated_figures`` (all missing for a leader's game or a missing replay)."""
    if replay is None or not seated(replay):
        return {}
    m = person_measures(replay, SEAT)
    lags = sorted(m["switch_lags"])
    median = (lags[(len(lags) - 1) // 2] + lags[len(lags) // 2]) / 2 if lags else None
    return {"stated_steps": m["stated_steps"], "stated_accuracy": m["accuracy"], "switches": m["switches"],
            "switch_lag_median": median, "probes_asked": m["probes_asked"], "probes_answered": m["probes_answered"],
            "probe_log_loss": m["log_loss"], "probe_brier": m["brier"]}


def stated_by_step(replay: Replay) -> list:
    """The stated color at each step ``[T]`` (None: none yet), or all None for a leader's game."""
    return replay.stated_beliefs.get(SEAT) if seated(replay) else [None] * replay.num_steps


def probe_rows(replay: Replay, base: dict, game_id: str) -> list[dict]:
    """One row per probe (``probes`` table), scored against the goal on screen when it was answered."""
    if not seated(replay):
        return []
    C, T = replay.config.num_colors, replay.num_steps
    rows = []
    for p in replay.probes or []:
        answered = p.get("status") == "answered"
        step = p.get("answered_step")
        goal = replay.goal[step] if answered and step is not None and step < T else None
        scored = goal is not None
        probs = answer_distribution(p["color"], p["confidence"], C) if scored else None
        rows.append({**base, "game_id": game_id, "probe": p["id"], "step": p["step"], "trigger": p["trigger"],
                     "status": p["status"], "color": p.get("color"), "confidence": p.get("confidence"),
                     "answered_step": step, "goal": goal, "correct": (p["color"] == goal) if scored else None,
                     "log_loss": log_loss(probs, goal) if scored else None,
                     "brier": brier(probs, goal) if scored else None, "response_ms": p.get("response_ms"),
                     "refused": p.get("refused", 0), "asked_ms": p.get("asked_ms"),
                     "answered_ms": p.get("answered_ms"), "t_client_ms": p.get("t_client")})
    return rows


def statement_rows(replay: Replay, base: dict, game_id: str) -> list[dict]:
    """One row per statement (``statements`` table)."""
    if not seated(replay):
        return []
    T = replay.num_steps
    return [{**base, "game_id": game_id, "color": e["color"], "via": e["via"], "step": e["step"],
             "goal": replay.goal[e["step"]] if e["step"] < T else None, "t_client_ms": e.get("t_client"),
             "t_server_ms": e.get("t_server")} for e in replay.belief_events or []]
