"""How well people read the goal: the measures of a person in the follower seat, beside AI followers on the same games.

A recorded game with a person in a follower seat (``agents[name].policy == "human"`` for a follower) holds what the
person said they believed (docs/REPLAY_FORMAT.md): the stated color at every step (``steps.stated_belief``) and each
probe's answer with its confidence (``probes``). The measures are those ``colorgrid eval`` gives an AI follower:

- **accuracy**: the share of steps whose stated color is the goal, over the steps where the person had stated one;
- **log-loss** and **Brier score** of the probe answers, each answer read as a distribution: its confidence on the
  stated color and the rest shared evenly by the other colors (log-loss clipped at 1e-6, as ``colorgrid eval``;
  Brier: the squared distance to the one-hot goal, summed over colors);
- **steps to catch a switch**: from each goal switch until the stated color is the new goal (``catch_lags``);
- **net and wrong pickups** of the person's agent.

The AI followers' side is paired: each follower **watches** the recorded history from the person's seat
(``branch.watch``: it gets every input that seat had, its actions ignored), so its belief at every step comes from the
very leader moves the person saw; its accuracy, log-loss and Brier are taken on the same steps and probes, its switch
lags on the same switches. Its pickups come from ``rescore`` (1:1 games: the follower plays the seat open-loop beside
the recorded leader), which is not paired that exactly: once it moves differently the board differs.

The person's figures are those of the games that measure reading a hidden goal. A study's practice game and a game that
showed the person the goal (``meta.goal_view == "shown"``, a control) measure something else; each kind is reported
apart (``colorgrid.replay.apart``), never pooled with them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from colorgrid.enums import Role
from colorgrid.replay import Replay, load
from colorgrid.replay.apart import SET_APART, set_apart, set_apart_words
from colorgrid.evaluate import catch_lags, format_mean_ci, mean_ci

LOG_LOSS_FLOOR = 1e-6
PERSON = "person"
"""The row of the person in the reports (the AI followers' rows are their names)."""
MEASURE_WORDS = {"accuracy": "belief accuracy (stated steps)", "accuracy_all_steps": "belief accuracy (every step)",
                 "probe_accuracy": "probe answers right", "log_loss": "probe log-loss", "brier": "probe Brier score",
                 "switch_lags": "steps to catch each switch", "median_switch_lag": "median steps to catch a switch",
                 "switches_caught": "switches caught", "net_pickups": "net pickups", "wrong_pickups": "wrong pickups"}
"""A person's measures in words, declared once: rescore's table and the replay page's panel (sent with ``/timeline``
as ``person_measure_words``) name them so."""
PAGE_MEASURES = ("accuracy", "accuracy_all_steps", "probe_accuracy", "log_loss", "brier", "switch_lags", "net_pickups")
"""The measures the replay page's panel shows, in its order (a game's own: its switches one by one, not a median)."""


def human_followers(replay: Replay) -> list[str]:
    """The followers a person played in ``replay`` (by agent name), those that stated beliefs."""
    cfg = replay.config
    return [name for name, role in zip(cfg.agent_names, cfg.roles)
            if role == Role.FOLLOWER and replay.agents.get(name, {}).get("policy") == "human"
            and name in replay.stated_beliefs]


def answer_distribution(color: int, confidence: float, num_colors: int) -> np.ndarray:
    """A probe's answer as a distribution ``[C]``: ``confidence`` on ``color``, the rest shared by the other colors."""
    probs = np.full(num_colors, (1.0 - confidence) / (num_colors - 1))
    probs[color] = confidence
    return probs


def log_loss(probs: np.ndarray, goal: int) -> float:
    return float(-np.log(max(float(probs[goal]), LOG_LOSS_FLOOR)))


def brier(probs: np.ndarray, goal: int) -> float:
    truth = np.zeros(len(probs))
    truth[goal] = 1.0
    return float(((np.asarray(probs, dtype=np.float64) - truth) ** 2).sum())


def scored_probes(replay: Replay, agent: str) -> list[dict]:
    """The answered probes of ``agent`` that can be scored: ``{step, color, confidence, goal, response_ms}``, the goal
    being the one on screen when the answer arrived (``answered_step``; real time goes on while a person answers). An
    answer that arrived after the last step has no goal recorded and is left out."""
    out = []
    for probe in replay.probes or []:
        if probe.get("agent", agent) != agent or probe.get("status") != "answered":
            continue
        step = probe.get("answered_step", probe["step"])
        if step < replay.num_steps:
            out.append({"step": step, "color": probe["color"], "confidence": probe["confidence"],
                        "goal": replay.goal[step], "response_ms": probe.get("response_ms")})
    return out


def person_measures(replay: Replay, agent: str) -> dict:
    """The measures of the person in ``agent``'s seat in one game (see the module's docstring)."""
    C, goal = replay.config.num_colors, np.asarray(replay.goal)
    stated = np.array([-1 if c is None else c for c in replay.stated_beliefs[agent]])
    said = stated >= 0
    probes = scored_probes(replay, agent)
    final = replay.final()
    asked = [p for p in replay.probes or [] if p.get("agent", agent) == agent]
    return {
        "steps": replay.num_steps, "stated_steps": int(said.sum()),
        "accuracy": float((stated[said] == goal[said]).mean()) if said.any() else None,
        "accuracy_all_steps": float((stated == goal).mean()),  # a step with no stated color is not right
        "switch_lags": catch_lags((stated == goal)[:, None], goal[:, None]).tolist(),
        "switches": int(np.sum(goal[1:] != goal[:-1])),
        "probes_asked": len(asked), "probes_answered": len(probes),
        "probe_accuracy": _mean([p["color"] == p["goal"] for p in probes]),
        "log_loss": _mean([log_loss(answer_distribution(p["color"], p["confidence"], C), p["goal"]) for p in probes]),
        "brier": _mean([brier(answer_distribution(p["color"], p["confidence"], C), p["goal"]) for p in probes]),
        "mean_confidence": _mean([p["confidence"] for p in probes]),
        "median_response_ms": float(np.median([p["response_ms"] for p in probes])) if probes else None,
        "goal_pickups": final[f"{agent}_goal_pickups"], "wrong_pickups": final[f"{agent}_wrong_pickups"],
        "net_pickups": final[f"{agent}_goal_pickups"] - final[f"{agent}_wrong_pickups"],
    }


def follower_measures(replay: Replay, agent: str, beliefs: list[list[float]]) -> dict:
    """The same measures for an AI follower's ``beliefs`` ``[T][C]`` formed watching ``agent``'s seat: accuracy on
    every step and on the steps the person had stated a belief, log-loss and Brier on the person's scored probes'
    steps (and log-loss on every step), switch lags on the same switches."""
    goal, probs = np.asarray(replay.goal), np.asarray(beliefs, dtype=np.float64)
    right = probs.argmax(axis=1) == goal
    said = np.array([c is not None for c in replay.stated_beliefs[agent]])
    probes = scored_probes(replay, agent)
    return {
        "steps": replay.num_steps, "stated_steps": int(said.sum()), "probes_answered": len(probes),
        "accuracy_all_steps": float(right.mean()),
        "accuracy": float(right[said].mean()) if said.any() else None,
        "log_loss_all_steps": float(np.mean([log_loss(p, g) for p, g in zip(probs, goal)])),
        "switch_lags": catch_lags(right[:, None], goal[:, None]).tolist(),
        "log_loss": _mean([log_loss(probs[p["step"]], p["goal"]) for p in probes]),
        "brier": _mean([brier(probs[p["step"]], p["goal"]) for p in probes]),
        "probe_accuracy": _mean([int(probs[p["step"]].argmax()) == p["goal"] for p in probes]),
    }


def watched(replay: Replay, agent: str, follower: str, seed: int | None = None) -> tuple[list | None, dict | None]:
    """The beliefs ``[T][C]`` ``follower`` forms watching ``agent``'s seat (``branch.watch``) and its
    ``follower_measures`` on them; (None, None) for a follower that forms no belief."""
    from colorgrid.replay.branch import watch

    beliefs = watch(replay, follower, replay.config.agent_names.index(agent), seed)
    return beliefs, None if beliefs is None else follower_measures(replay, agent, beliefs)


def person_and_follower(replay: Replay, follower: str, seed: int | None = None) -> dict:
    """One game's figures of each person in a follower seat beside ``follower`` (the replay page's "person and AI"
    panel; per game what ``human_follower_report`` pools), by the person's agent name: ``person`` (``person_measures``),
    ``follower`` (``follower_measures`` watching the seat, or None for a follower without beliefs), ``beliefs`` (its
    ``[T][C]``), in 1:1 games the follower's ``net_pickups`` and ``wrong_pickups`` in the seat
    (``branch.open_loop_pickups``, as rescore counts them; None in other teams), and the ``set_apart`` kind of the game
    with its ``set_apart_words`` (``apart.SET_APART``; None for a game rescore pools)."""
    from colorgrid.replay.branch import open_loop_pickups

    out, kind = {}, set_apart(replay)
    for agent in human_followers(replay):
        beliefs, measures = watched(replay, agent, follower, seed)
        pickups = open_loop_pickups(replay, follower, seed) if replay.config.one_to_one else (None, None)
        out[agent] = {"person": person_measures(replay, agent), "follower": measures, "beliefs": beliefs,
                      "net_pickups": pickups[0], "wrong_pickups": pickups[1], "set_apart": kind,
                      "set_apart_words": set_apart_words(kind)}
    return out


def _mean(values: list) -> float | None:
    return float(np.mean(values)) if values else None


def human_follower_report(files: list[Path], followers: list[str], seed: int | None = None,
                          pickups: dict | None = None) -> dict | None:
    """People in the follower seat in ``files`` beside each of ``followers`` watching their seats: per game and
    pooled, with paired differences (follower minus person) over games. Only games that measure reading a hidden goal
    are pooled; practice games and games that showed the goal are reported apart, each kind with its own figures, under
    ``set_apart`` (``SET_APART``'s keys; ``games`` may then be empty). ``pickups``: ``rescore``'s report, whose
    per-game net pickups of each follower (1:1 games) are set beside the person's, a kind set apart beside its own
    (rescore's ``set_apart``). None when no game had a person in a follower seat."""
    games, apart = [], {kind: [] for kind in SET_APART}
    for path in files:
        replay = load(path)
        if replay.kind != "actions" or "branch_of" in replay.meta:
            continue
        for agent in human_followers(replay):
            entry = {"game": str(path), "agent": agent, "leader": _leaders(replay),
                     "goal_view": replay.meta.get("goal_view"), "mode": replay.meta.get("mode"),
                     "set_apart": set_apart(replay), PERSON: person_measures(replay, agent), "followers": {}}
            for follower in followers:
                entry["followers"][follower] = watched(replay, agent, follower, seed)[1]
            (games if entry["set_apart"] is None else apart[entry["set_apart"]]).append(entry)
    if not games and not any(apart.values()):
        return None
    return {**_report(games, followers, pickups),
            "set_apart": {kind: _report(kept, followers, None if pickups is None else pickups["set_apart"].get(kind))
                          for kind, kept in apart.items() if kept}}


def _report(games: list[dict], followers: list[str], pickups: dict | None) -> dict:
    """The pooled rows and paired differences of ``games`` (``measures`` empty when there is none)."""
    if not games:
        return {"games": [], "followers": followers, "measures": {}, "paired_difference": {}}
    rows = {PERSON: _pooled([g[PERSON] for g in games])}
    paired = {}
    for follower in followers:
        mine = [(g[PERSON], g["followers"][follower]) for g in games if g["followers"][follower] is not None]
        if not mine:
            rows[follower] = None
            continue
        rows[follower] = _pooled([m for _, m in mine])
        paired[follower] = {name: _paired([(p[name], m[name]) for p, m in mine])
                            for name in ("accuracy", "log_loss", "brier")}
        paired[follower]["median_switch_lag"] = _paired([(_median(p["switch_lags"]), _median(m["switch_lags"]))
                                                         for p, m in mine])
    if pickups is not None:
        _add_pickups(rows, games, pickups, followers)
    return {"games": games, "followers": followers, "measures": rows, "paired_difference": paired}


def _leaders(replay: Replay) -> str:
    return " + ".join(replay.agents.get(replay.config.agent_names[i], {}).get("policy", "?")
                      for i in replay.config.leaders)


def _median(values: list) -> float | None:
    return float(np.median(values)) if values else None


def _paired(pairs: list[tuple]) -> dict | None:
    """Mean and 95% interval of (follower - person) over the games where both have the measure."""
    diffs = [m - p for p, m in pairs if p is not None and m is not None]
    return {**mean_ci(np.array(diffs)), "games": len(diffs)} if diffs else None


WEIGHTS = {"accuracy": "stated_steps", "accuracy_all_steps": "steps", "log_loss_all_steps": "steps",
           "probe_accuracy": "probes_answered", "log_loss": "probes_answered", "brier": "probes_answered",
           "mean_confidence": "probes_answered"}
"""Each pooled measure and what it is an average over (a game's weight): steps, stated steps or scored probes."""


def _pooled(measures: list[dict]) -> dict:
    """One row of the report: each measure pooled over games (averaged over all their steps, stated steps or probes,
    not a mean of games' shares; switch lags pooled), counts summed, pickups a mean with its 95% interval."""
    lags = [lag for m in measures for lag in m["switch_lags"]]
    out = {"games": len(measures), "switches_caught": len(lags), "median_switch_lag": _median(lags),
           "mean_switch_lag": float(np.mean(lags)) if lags else None}
    for name, weight in WEIGHTS.items():
        out[name] = _weighted([(m.get(name), m.get(weight)) for m in measures])
    for name in ("steps", "stated_steps", "switches", "probes_asked", "probes_answered"):
        if name in measures[0]:
            out[name] = sum(m[name] for m in measures)
    for name in ("net_pickups", "wrong_pickups"):
        if name in measures[0]:
            out[name] = mean_ci(np.array([m[name] for m in measures], dtype=np.float64))
    return out


def _weighted(pairs: list[tuple]) -> float | None:
    pairs = [(v, n) for v, n in pairs if v is not None and n]
    return float(sum(v * n for v, n in pairs) / sum(n for _, n in pairs)) if pairs else None


def _add_pickups(rows: dict, games: list[dict], pickups: dict, followers: list[str]) -> None:
    """Each follower's net and wrong pickups in the seat of the person's 1:1 games (``rescore``'s per-game figures)."""
    index = {game: i for i, game in enumerate(pickups["games"])}
    for follower in followers:
        mine = [index[g["game"]] for g in games if g["game"] in index]
        if mine and rows.get(follower) is not None:
            for name, per_game in (("net_pickups", "per_game"), ("wrong_pickups", "per_game_wrong")):
                values = [pickups[per_game][follower][i] for i in mine]
                rows[follower][name] = mean_ci(np.array(values, dtype=np.float64))
            rows[follower]["pickups_games"] = len(mine)


def format_human_report(report: dict) -> str:
    """The report as an eval-style table: one column for the people, one per AI follower watching their seats; then
    each kind of game set apart (practice, the goal shown), in a table of its own."""
    n = len(report["games"])
    if n:
        lines = [f"{n} recorded game(s) with a person in the follower seat, the goal hidden; each AI follower watches "
                 "the person's seat (the same leader moves)", *_table(report)]
    else:
        lines = ["no recorded game of a person in the follower seat with the goal hidden: nothing to measure the "
                 "person's reading of the goal on"]
    for kind, part in report.get("set_apart", {}).items():
        lines += ["", f"set apart, not in the person's figures above: {len(part['games'])} {SET_APART[kind].games}",
                  *_table(part)]
    return "\n".join(lines)


def _table(report: dict) -> list[str]:
    rows, names = report["measures"], [PERSON, *report["followers"]]
    lines = [f"{'':<34}" + "".join(f"{name:>22}" for name in names)]

    def cell(name, key, form):
        row = rows.get(name)
        value = None if row is None else row.get(key)
        if value is None:
            return f"{'-':>22}"
        if isinstance(value, dict):  # a mean with its 95% interval (none over one game)
            return f"{format_mean_ci(value, '{:+.2f}' if key == 'net_pickups' else '{:.2f}'):>22}"
        return f"{form(value):>22}"

    forms = {"accuracy": "{:.1%}", "accuracy_all_steps": "{:.1%}", "probe_accuracy": "{:.1%}", "log_loss": "{:.3f}",
             "brier": "{:.3f}", "median_switch_lag": "{:.1f}", "switches_caught": "{:d}", "net_pickups": "{}",
             "wrong_pickups": "{}"}
    for key, form in forms.items():
        lines.append(f"{MEASURE_WORDS[key]:<34}" + "".join(cell(name, key, form.format) for name in names))
    person = rows[PERSON]
    lines.append(f"the person stated a belief at {person['stated_steps']} of {person['steps']} steps; answered "
                 f"{person['probes_answered']} of {person['probes_asked']} probes; {person['switches']} goal switches")
    for follower, diffs in report["paired_difference"].items():
        words = []
        for key, label, form in (("accuracy", "accuracy", "{:+.1%}"), ("log_loss", "log-loss", "{:+.3f}"),
                                 ("median_switch_lag", "median switch lag", "{:+.1f} steps")):
            d = diffs.get(key)
            if d is not None:
                words.append(f"{label} {format_mean_ci(d, form)}")
        if words:
            lines.append(f"{follower} - person (paired over games): " + ", ".join(words))
    lines.append("net pickups: the person's own; a follower's when it plays the person's seat open-loop (1:1 games)")
    return lines
