"""A replay as a player draws it: verified first, then one board per step plus the episode's events.

The web replay player (``/api/replays/{id}/timeline``) and the 3D viewer both read this (with
``look``, the colors and agents to draw them in: ``colorgrid.render.look``);
a replay that fails verification comes back with ``verified: false`` and its problem,
and no boards, so that nothing plays a trajectory the rules would not produce.

A game with a person in a follower seat adds what the person said (``stated_beliefs``: each step's stated color,
``belief_events``, ``probes``) and their measures (``person_measures``: ``colorgrid.replay.human_follower``'s, per
agent); a timeline without one has none of these fields.
"""

from __future__ import annotations

import bisect

from colorgrid.config import COLOR_NAMES
from colorgrid.render import look
from colorgrid.replay.format import Replay
from colorgrid.replay.human_follower import MEASURE_WORDS, PAGE_MEASURES, human_followers, person_measures
from colorgrid.replay.blocks import encode_blocks
from colorgrid.replay.simulate import replay_states, verify


def timeline(replay: Replay, path=None) -> dict:
    states = replay_states(replay, path)  # simulated once: verified, then drawn
    check = verify(replay, path, states)
    cfg = replay.config
    out = {
        "verified": check.ok, "problem": None if check.ok else check.message,
        "kind": replay.kind, "source": replay.source, "agents": replay.agents, "created": replay.created,
        "ended": replay.ended, "seed": replay.seed, "final": replay.final(), "meta": replay.meta,
        "config": cfg.to_dict(), "agent_names": list(cfg.agent_names), "roles": list(cfg.roles),
        "colors": list(COLOR_NAMES[: cfg.num_colors]), "look": look(cfg),
        "height": cfg.height, "width": cfg.width, "steps": replay.num_steps,
    }
    if not check.ok:
        return out
    boards = []
    for t, state in enumerate(states):
        boards.append({
            "t": t, "blocks": encode_blocks(state.block_colors(cfg).reshape(-1)),
            **{name: int(state.agent_cell[0, i]) for i, name in enumerate(cfg.agent_names)},
            "goal": int(replay.goal[t]) if t < replay.num_steps else int(state.goal[0]),
            "scores": [float(x) for x in state.score[0]] if replay.kind == "actions" else None,
        })
    events = []  # pickups and goal switches, for timeline markers
    for t in range(replay.num_steps):
        for i, name in enumerate(cfg.agent_names):
            color = replay.picked_color[t][i] if replay.picked_color else -1
            if color >= 0:
                events.append({"t": t, "type": "pickup", "agent": name, "color": color,
                               "correct": color == replay.goal[t]})
        if replay.goal_switched and replay.goal_switched[t]:
            events.append({"t": t, "type": "switch", "to": boards[t + 1]["goal"]})
    out.update({"boards": boards, "goal": replay.goal, "actions": replay.actions, "goal_probs": replay.goal_probs,
                "events": events, "key_events": reaction_times(replay.key_events or [],
                                                               replay.meta.get("state_sent_ms"))})
    if replay.stated_beliefs:  # a person in a follower seat: what they said, and how well it read the goal
        out.update({"stated_beliefs": replay.stated_beliefs, "belief_events": replay.belief_events or [],
                    "probes": replay.probes or [],
                    "person_measures": {name: person_measures(replay, name) for name in human_followers(replay)},
                    "person_measure_words": [[key, MEASURE_WORDS[key]] for key in PAGE_MEASURES]})
    return out


def reaction_times(keys: list[dict], state_sent_ms: list | None) -> list[dict]:
    """Key events with ``shown_step`` (the state on screen when the key reached the server) and
    ``reaction_ms`` (from that state being sent to the key arriving; it includes the network both ways)."""
    if not state_sent_ms:
        return keys
    out = []
    for key in keys:
        k = bisect.bisect_right(state_sent_ms, key.get("t_server", float("-inf"))) - 1
        extra = {"shown_step": k, "reaction_ms": round(key["t_server"] - state_sent_ms[k], 1)} if k >= 0 else {}
        out.append({**key, **extra})
    return out
