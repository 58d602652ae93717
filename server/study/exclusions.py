"""Exclusions: the evidence of attention a game leaves, and the study's rules applied to it.

A trial's evidence is three figures, stored with the game's other figures when it ends (``server.study.figures``):
``away_s`` (seconds the page was hidden or out of focus, from the focus and visibility changes the page reported),
``idle_s`` (the longest stretch without a key, a stated belief or a probe's answer, by the server's clock) and
``round_trip_ms`` (the median round trip the page measured over its socket during play). ``exclusion_rows`` applies
the study's ``[exclusions]`` rules to them, and to the comprehension and attention checks each participant failed:
the rows of the export's ``exclusions`` table, which the admin page counts per arm. Practice games, and games lost and
played again, are never excluded.
"""

from __future__ import annotations

import statistics
from collections.abc import Iterable

from colorgrid.enums import Ending, GameKind
from colorgrid.replay import Replay
from server.study.config import Exclusions, Study

RULES = ("away", "idle", "round_trip", "failed_checks")
"""The rules, as the ``exclusions`` table's ``rule`` column names them (``Exclusions``'s fields, in order)."""
LOST = Ending.lost()


def away_seconds(page_events: list[dict], start_ms: float, end_ms: float) -> float:
    """Seconds between ``start_ms`` and ``end_ms`` (server clock) in which the page was out of focus (``blur`` until
    ``focus``) or hidden (``visibilitychange`` with ``visible`` false until one with true); still away at the end:
    counted to the end."""
    focused, visible, since, total = True, True, None, 0.0
    for event in sorted(page_events, key=lambda e: e["t_server"]):
        t = min(max(event["t_server"], start_ms), end_ms)
        if event["event"] == "blur":
            focused = False
        elif event["event"] == "focus":
            focused = True
        elif event.get("visible") is not None:
            visible = bool(event["visible"])
        away = not (focused and visible)
        if away and since is None:
            since = t
        elif not away and since is not None:
            total, since = total + t - since, None
    if since is not None:
        total += end_ms - since
    return total / 1000


def idle_seconds(times_ms: Iterable[float], start_ms: float, end_ms: float) -> float:
    """The longest stretch, in seconds, between ``start_ms`` and ``end_ms`` with none of ``times_ms`` in it."""
    inside = sorted(t for t in times_ms if start_ms <= t <= end_ms)
    marks = [start_ms, *inside, end_ms]
    return max(b - a for a, b in zip(marks, marks[1:])) / 1000


def attention_figures(replay: Replay) -> dict:
    """A game's ``away_s`` and ``idle_s`` from its replay: from the first state sent to the last (the server's clock,
    ``meta.state_sent_ms``); empty for a replay without those times."""
    sent = replay.meta.get("state_sent_ms") or []
    if len(sent) < 1:
        return {"away_s": None, "idle_s": None}
    start, end = sent[0], sent[-1]
    acts = [k["t_server"] for k in replay.key_events or [] if k.get("t_server") is not None]
    acts += [e["t_server"] for e in replay.belief_events or [] if e.get("t_server") is not None]
    return {"away_s": away_seconds(replay.meta.get("page_events") or [], start, end),
            "idle_s": idle_seconds(acts, start, end)}


def median_round_trip(round_trips_ms: list[float]) -> float | None:
    """The median of a game's measured round trips (None: none measured)."""
    return float(statistics.median(round_trips_ms)) if round_trips_ms else None


def counted(kind: str, ended: str | None) -> bool:
    """Whether a game of ``kind`` that ended as ``ended`` counts in a study's figures: a trial (not the practice) that
    ended, and not to no one's doing (``LOST``: the participant played it again); as the admin page counts."""
    return kind == GameKind.TRIAL and isinstance(ended, str) and bool(ended) and ended not in LOST


def exclusion_rows(study: Study, games: Iterable[dict], checks: Iterable[dict]) -> list[dict]:
    """The rows of the ``exclusions`` table: one per rule a trial or a participant breaks.

    ``games``: each game's ``participant``, ``game_id``, ``kind``, ``trial_index``, ``condition_index``, ``ended``
    and its figures ``away_s``, ``idle_s``, ``round_trip_ms`` (None: not measured, and the rule not applied);
    ``checks``: each check answered, ``participant``, ``page``, ``question``, ``answer`` (the one kept: the last).
    A row: ``participant``, ``game_id``, ``trial_index``, ``condition_index`` (None for a participant's rule),
    ``rule``, ``value``, ``threshold`` and ``evidence`` in words."""
    rules: Exclusions = study.exclusions
    per_game = (("away", "away_s", rules.away_s, "the page was hidden or out of focus for {v:.2f} s in all "
                                                 "(more than {t:g} s)"),
                ("idle", "idle_s", rules.idle_s, "{v:.2f} s without a key (more than {t:g} s)"),
                ("round_trip", "round_trip_ms", rules.round_trip_ms, "a median round trip of {v:.1f} ms during play "
                                                                     "(more than {t:g} ms)"))
    rows = []
    for game in games:
        if not counted(game["kind"], game["ended"]):
            continue
        where = {"participant": game["participant"], "game_id": game["game_id"],
                 "trial_index": game["trial_index"], "condition_index": game["condition_index"]}
        for rule, figure, threshold, words in per_game:
            value = game.get(figure)
            if threshold is not None and value is not None and value == value and value > threshold:
                rows.append({**where, "rule": rule, "value": float(value), "threshold": float(threshold),
                             "evidence": words.format(v=value, t=threshold)})
    if rules.failed_checks is not None:
        questions = {(page, q.id): q for page, q in check_questions(study)}
        failed: dict[str, list[str]] = {}
        for c in checks:
            q = questions.get((c["page"], c["question"]))
            if q is not None and c["answer"] != q.answer:
                failed.setdefault(c["participant"], []).append(
                    f"{c['page']}.{q.id}: {c['answer']!r} on the last of {q.tries} tries (right: {q.answer!r})")
        for pid, which in failed.items():
            if len(which) >= rules.failed_checks:
                rows.append({"participant": pid, "game_id": None, "trial_index": None, "condition_index": None,
                             "rule": "failed_checks", "value": float(len(which)),
                             "threshold": float(rules.failed_checks),
                             "evidence": f"{len(which)} check(s) failed: " + "; ".join(which)})
    return rows


def check_questions(study: Study) -> list[tuple[str, object]]:
    """Every check of the study with the page its answers carry (``after_trial`` for the trials page's)."""
    return [("after_trial" if p.kind == "trials" else p.name, q) for p in study.pages
            for q in (*p.questions, *p.after_each) if q.kind == "check"]
