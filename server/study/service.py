"""A running study: who is where, what they see next, and what each of their games is.

Pages are expanded per participant into **steps**: the trials page becomes one step per trial
(and one per ``after_each`` questionnaire). A participant's ``step`` only moves forward, and only
when the current step is done (consent agreed, answers valid, the game over); a lost game
(disconnected past the grace, server stopped) is played again as a new attempt. Everything a
participant did is in the database before the page is told it worked.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import random
import re
import secrets
import statistics
import time
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass

from markdown_it import MarkdownIt

from colorgrid.enums import Ending, GameKind, Role
from colorgrid.presets import env_config
from colorgrid.render import look
from server.study.assign import arm_labels, arms, choose_arm, trial_order
from server.followers import follower_info
from server.study.config import ID_PATTERN, GameSettings, Page, Question, Study
from server.study.errors import Finished, Invalid, Refused
from server.study.exclusions import exclusion_rows, median_round_trip
from server.study.figures import game_figures, score_figures
from server.study.questions import count_checks, taken_answers
from server.study.screening import screened_out
from server.study.store import StudyStore

LOST = Ending.lost()
"""Game endings that do not count: the participant plays that game again. ``Ending.SERVER_LOST`` is written when the
participant starts a game again whose process stopped without saving it (killed, crashed), on whichever process they
reach."""
ADMIN_ENDING_WORDS: dict[Ending, str] = {ending: ending.value for ending in Ending} | {
    Ending.SERVER_LOST: "lost with a process that stopped (server_lost)",
    Ending.SERVER_SHUTDOWN: "stopped with the server (server_shutdown)"}
"""Each ending as the admin page counts games by it (``summary``' ``ending_words``): its name, or what happened."""
FULL = "full"
"""The reason logged for a participant refused because the study is full (every place or every arm's quota taken)."""
SESSION_PATTERN = re.compile(r"^[A-Za-z0-9_-]{32,128}$")
"""A session key a browser may propose at its first join: random URL-safe text, 32 to 128 characters."""
MAX_ROUND_TRIPS = 10_000
"""Round trips kept per game (a page pings every few seconds)."""
END_RETRIES = 1
"""How many more times the end of a game is written when its write fails (a database that blinked)."""
END_RETRY_WAIT_S = 0.5
log = logging.getLogger("colorgrid.server")
_markdown = MarkdownIt("commonmark", {"html": False})  # raw HTML in a study file is shown as text, never run


def own_session(proposed: str | None) -> str | None:
    """The key a browser proposed for its first join, when it is one (``SESSION_PATTERN``): the page makes it and
    keeps it before it sends the join, so that the same join sent again resumes instead of being refused."""
    return proposed if isinstance(proposed, str) and SESSION_PATTERN.match(proposed) else None


@dataclass(frozen=True)
class Step:
    """One screen of one participant's study."""

    kind: str  # consent, instructions, practice, trial, questions (after a trial), questionnaire, debrief
    page: Page
    trial_index: int | None = None
    condition: int | None = None

    @property
    def questions(self) -> tuple[Question, ...]:
        return self.page.after_each if self.kind == "questions" else self.page.questions

    @property
    def answers_page(self) -> str:
        return "after_trial" if self.kind == "questions" else self.page.name

    @property
    def has_game(self) -> bool:
        return self.kind in (GameKind.PRACTICE, GameKind.TRIAL)


def study_hash(study: Study) -> str:
    return hashlib.sha256(json.dumps(dataclasses.asdict(study), sort_keys=True, default=str).encode()).hexdigest()


class StudyService:
    def __init__(self, study: Study, store: StudyStore):
        self.study, self.store = study, store
        self.rng = random.Random(study.design.seed)
        self.arms = arms(study)
        self.live: dict[str, object] = {}  # pid -> its live Game (for a page that reloads)
        self.round_trips: dict[str, list[float]] = defaultdict(list)  # game id -> the round trips measured in play
        # pid -> where another process of the deployment runs its game, {game_id, token, backend} to rejoin it there,
        # or None: set by server.cluster.siblings.join_cluster, which asks the siblings
        self.elsewhere: Callable[[str], dict | None] = lambda pid: None

    # ---------------------------------------------------------------- steps
    def steps(self, conditions: list[int]) -> list[Step]:
        out = []
        for page in self.study.pages:
            if page.kind != "trials":
                out.append(Step(page.kind, page))
                continue
            for i, c in enumerate(conditions):
                out.append(Step(GameKind.TRIAL, page, i, c))
                if page.after_each:
                    out.append(Step("questions", page, i, c))
        return out

    def game_settings(self, step: Step) -> GameSettings:
        if step.kind == GameKind.PRACTICE:
            return self.study.practice_game(step.page)
        return self.study.conditions[step.condition]

    # ---------------------------------------------------------------- joining
    def participant_id(self, params: dict) -> str:
        for name in self.study.id_params:
            value = params.get(name)
            if value:
                if not ID_PATTERN.match(value):
                    raise Refused("The participant id in this link is not one this study can take. Please open the "
                                  "study from the link you were given, without changing it.")
                return value
        if self.study.anonymous:
            return "anon-" + secrets.token_hex(6)
        raise Refused("This link has no participant id in it. Please open the study from the link you were given "
                      "(on the study platform), without changing it.")

    def join(self, params: dict, session: str | None, user_agent: str, screen: dict | None = None) -> dict:
        """Start or resume a participant; the answer carries their session key and the step to show. A new
        participant of a study with ``[screening]`` brings the page's ``screen`` (``touch_only``, ``viewport``,
        ``round_trips_ms``); one who fails it, or who finds the study full, is refused, and the refusal logged with
        its reason (they take no place)."""
        pid = params.get("_pid")  # an anonymous participant coming back: only with its session
        if not (self.study.anonymous and pid and session and self.store.participant(pid) is not None):
            pid = self.participant_id(params)
        with self.store.transaction(assign=True) as tx:  # counts read and row written as one, across processes
            row = tx.participant(pid)
            refusal = (screened_out(self.study.screening, self.study.redirect_url, tx, pid, screen)
                       if row is None else None)
            if row is None and refusal is None:
                arm = None
                if tx.count_participants() < self.study.max_participants:
                    arm = choose_arm(tx.arm_counts(len(self.arms)), self.study.design.quota,
                                     self.study.design.balance, self.rng)
                if arm is None:
                    tx.log(pid, "refused", reason=FULL)
                    refusal = Refused("the study is full: thank you for your interest")
            if refusal is not None:
                answer = refusal  # raised once the transaction is committed: the refusal stays in the log
            elif row is None:
                conditions = trial_order(self.study, arm, self.rng)
                kept = {k: str(params[k])[:200] for k in (*self.study.id_params, *self.study.keep_params)
                        if params.get(k)}
                new, now = own_session(session) or secrets.token_urlsafe(24), time.time()
                row = tx.add_participant({"pid": pid, "session": new, "arm": arm,
                                          "conditions": json.dumps(conditions), "status": "active", "step": 0,
                                          "url_params": json.dumps(kept), "user_agent": user_agent[:500],
                                          "started": now, "updated": now})
                if row["session"] == new:
                    tx.log(pid, "joined", arm=arm, **({"screen": screen} if screen else {}))
                    return {"pid": pid, "session": new}
                answer = self.returning(tx, row, session, user_agent)  # another process joined them just now
            else:
                answer = self.returning(tx, row, session, user_agent)  # joined before
        if isinstance(answer, Refused):
            raise answer  # once the transaction is committed: the refusal stays in the audit log
        return answer

    def returning(self, tx, row: dict, session: str | None, user_agent: str) -> dict | Refused:
        """A participant who joined before: their own browser (or any, when the study resumes) gets their session.
        Their own browser includes a join whose answer was lost and is sent again (by the page, or by the proxy
        when the process that stored it was killed before answering): it carries the key the browser proposed.
        A refusal is returned, not raised: raised inside ``tx`` it would roll back its own event."""
        pid = row["pid"]
        if session and secrets.compare_digest(session, row["session"]):
            tx.log(pid, "resumed")
        elif self.study.returning == "resume":
            tx.log(pid, "resumed", new_browser=True, user_agent=user_agent[:300])
        elif row["status"] == "completed":
            tx.log(pid, "refused", reason="already completed")
            return Finished(self.study.completion_code, self.completion_url())
        else:
            tx.log(pid, "refused", reason="already started")
            return Refused("You have already started this study in another browser or on another device, and it "
                           "cannot start again here. Please go on in that browser; if you cannot, contact the "
                           "researchers through the study platform.")
        return {"pid": pid, "session": row["session"]}

    def completion_url(self) -> str:
        """The study's ``redirect_url`` with its completion code in it ("" when it has none)."""
        url = self.study.redirect_url
        return url.replace("{code}", self.study.completion_code) if url else ""

    def check(self, pid: str, session: str):
        row = self.store.participant(pid) if isinstance(pid, str) else None
        if row is None or not isinstance(session, str) or not secrets.compare_digest(session, row["session"]):
            raise Refused("unknown participant or session: open the study from your link again")
        return row

    # ---------------------------------------------------------------- what the page shows
    def view(self, pid: str, session: str) -> dict:
        row = self.check(pid, session)
        steps = self.steps(json.loads(row["conditions"]))
        step = steps[row["step"]]
        trials = sum(s.kind == GameKind.TRIAL for s in steps)
        out = {"pid": pid, "step": row["step"], "steps": len(steps), "kind": step.kind,
               "title": f"About game {step.trial_index + 1}" if step.kind == "questions" else step.page.title,
               "study": self.study.title, "html": _markdown.render(step.page.text) if step.kind != "questions" else "",
               "trial_index": step.trial_index, "trials": trials}
        if step.questions:
            # a check's right answer stays on the server
            out["questions"] = [{k: v for k, v in dataclasses.asdict(q).items() if k != "answer"}
                                for q in step.questions]
        settings = self.game_settings(step) if step.has_game else self.study.defaults
        config = env_config(settings.preset)
        out["look"] = look(config)  # who is who: the page's legend draws each disc as the board will
        assisting = settings.seat == Role.FOLLOWER  # the participant plays the follower, beside an AI leader
        out["agent"] = config.agent_names[config.followers[0] if assisting else config.leaders[0]]  # a study game: 1:1
        if step.has_game:  # has_belief: the follower forms a belief the page may show (copy has none)
            out["game"] = {"mode": settings.mode, "show_belief": settings.show_belief, "horizon": settings.horizon,
                           "tick_hz": settings.tick_hz, "seat": settings.seat,
                           "has_belief": not assisting and follower_info(settings.follower)["has_belief"]}
            last = self.store.last_game(pid, row["step"])
            live = self.live.get(pid)
            if live is not None and not live.finished:
                out["live"] = {"game_id": live.game_id, "token": live.token}
            elif last is not None and last["ended"] and last["ended"] not in LOST:
                out["done"] = {"ended": last["ended"], "scores": json.loads(last["scores"] or "null")}
            elif self.away(pid, last):
                there = self.elsewhere(pid)
                if there is not None:
                    out["live"] = there  # another process runs it: the page rejoins it there
                else:
                    out["interrupted"] = True  # its process stopped: the page offers to play it again
        if step.kind == "debrief":
            out["completion_code"] = self.study.completion_code
            out["redirect_url"] = self.completion_url()
        return out

    # ---------------------------------------------------------------- moving on
    def advance(self, pid: str, session: str, step_index: int, answers: dict | None, agree: bool) -> dict:
        row = self.check(pid, session)
        steps = self.steps(json.loads(row["conditions"]))
        if step_index != row["step"]:
            raise Invalid(f"this page is not the participant's current one (step {row['step']} of {len(steps)});"
                          " reload to continue")
        step = steps[step_index]
        if step.kind == "debrief":
            raise Invalid("the study is complete: there is no page after the debrief")
        if step.kind == "consent" and agree is not True:
            raise Invalid("consent: agree to take part (or close the page to leave the study)")
        clean = {}
        if step.questions:
            clean = taken_answers(step.questions, answers)
            count_checks(self.store, pid, step_index, step.kind, step.questions, clean)
        if step.has_game:
            last = self.store.last_game(pid, step_index)
            if last is None or not last["ended"] or last["ended"] in LOST:
                raise Invalid("the game on this page is not over yet")
        now = time.time()
        nxt = step_index + 1
        done = nxt == len(steps) or steps[nxt].kind == "debrief"
        with self.store.transaction() as tx:
            if not tx.move_on(pid, step_index, min(nxt, len(steps) - 1), done, now):  # a second tab moved on meanwhile
                raise Invalid("this page was already completed; reload to continue")
            for qid, value in clean.items():
                tx.answer(pid, step_index, step.answers_page, step.trial_index, qid, value, now)
            tx.log(pid, "consented" if step.kind == "consent" else "advanced", step=step_index)
            if done:
                tx.log(pid, "completed")
        if nxt == len(steps):  # no debrief page: the study ends on the last page
            return {**self.view(pid, session), "finished": True}
        return self.view(pid, session)

    # ---------------------------------------------------------------- games
    def game_for(self, pid: str, session: str) -> tuple[GameSettings, dict]:
        """The settings of the game the participant's current step plays, and what its replay records."""
        row = self.check(pid, session)
        steps = self.steps(json.loads(row["conditions"]))
        step = steps[row["step"]]
        if not step.has_game:
            raise Invalid("the participant's current page has no game")
        live = self.live.get(pid)
        if live is not None and not live.finished:
            raise Invalid("this participant's game is still running: rejoin it")
        last = self.store.last_game(pid, row["step"])
        if self.away(pid, last):  # played again as a new attempt, unless another process still runs it
            if self.elsewhere(pid) is not None:
                raise Invalid("this participant's game is still running in another server process: reload the page "
                              "to rejoin it")
        elif last is not None and (not last["ended"] or last["ended"] not in LOST):
            raise Invalid("the game on this page was already played")
        settings = self.game_settings(step)
        meta = {"study": self.study.id, "participant": pid, "step": row["step"], "kind": step.kind,
                "trial_index": step.trial_index, "condition_index": step.condition,
                "condition": dataclasses.asdict(settings), "show_belief": settings.show_belief,
                "attempt": 0 if last is None else last["attempt"] + 1, "arm": row["arm"]}
        return settings, meta

    def away(self, pid: str, last: dict | None) -> bool:
        """Whether the participant's latest game never ended and is not running here: another process of the
        deployment runs it (``elsewhere`` says), or the process that ran it stopped without saving it."""
        return last is not None and not last["ended"] and pid not in self.live

    def interrupted(self, pid: str, last: dict | None) -> bool:
        """Whether the participant's latest game never ended and runs nowhere: the process that ran it stopped
        without saving it (killed, crashed), this one or another behind the same proxy. A participant's requests
        reach the process running their game, but not always: one started again after it died takes its
        participants back, whose games may still run where they went meanwhile; so the others are asked."""
        return self.away(pid, last) and self.elsewhere(pid) is None

    def game_started(self, game) -> None:
        m = game.study
        self.live[m["participant"]] = game
        with self.store.transaction() as tx:
            if m["attempt"] > 0:  # an interrupted attempt before it gets its ending now (a lost one keeps its own)
                tx.end_game(m["participant"], m["step"], m["attempt"] - 1, {"ended": Ending.SERVER_LOST,
                                                                            "finished": time.time()}, running=True)
            tx.add_game({"pid": m["participant"], "step": m["step"], "attempt": m["attempt"], "kind": m["kind"],
                         "trial_index": m["trial_index"], "condition": m["condition_index"],
                         "settings": json.dumps(m["condition"]), "game_id": game.game_id, "started": time.time()})

    def game_over(self, game, reason: Ending, scores: dict) -> None:
        """Record the end of a game with its figures (``server.study.figures``), read from the game's own record
        (descriptions of the AI agents do not enter them)."""
        m = game.study
        try:
            for attempt in range(1 + END_RETRIES):
                try:
                    figures = game_figures(game.to_replay(reason, defaultdict(dict)))
                    figures["round_trip_ms"] = median_round_trip(self.round_trips.get(game.game_id, []))
                    with self.store.transaction() as tx:
                        tx.end_game(m["participant"], m["step"], m["attempt"],
                                    {"replay_id": game.replay_id, "ended": reason, "scores": json.dumps(scores),
                                     "finished": time.time(), **score_figures(scores), **figures})
                    return
                except Exception as error:
                    if attempt == END_RETRIES:
                        raise  # the hub logs it; the participant plays the game again (it reads "interrupted")
                    log.warning("could not record the end of game %s of %s (%s: %s); trying once more",
                                game.game_id, m["participant"], type(error).__name__, error)
                    time.sleep(END_RETRY_WAIT_S)
        finally:  # stored or not, it is not running: once stored never "interrupted" meanwhile, else it is
            self.round_trips.pop(game.game_id, None)
            if self.live.get(m["participant"]) is game:
                del self.live[m["participant"]]

    def round_trip(self, game, ms: float) -> None:
        """A round trip the page of a study game measured during play (``ping.round_trip_ms``; the hub's hook)."""
        if game.study is not None and len(self.round_trips[game.game_id]) < MAX_ROUND_TRIPS:
            self.round_trips[game.game_id].append(float(ms))

    # ---------------------------------------------------------------- the admin's view
    def summary(self, live_games: int) -> dict:
        rows = self.store.participants()
        labels = arm_labels(self.study)
        figures = self.store.figures_by_arm(LOST)
        by_arm = [{"arm": a, "label": labels[a], "active": 0, "completed": 0,
                   "trials": figures.get(a, {"games": 0}),
                   "excluded": {"trials": 0, "participants": 0, "rules": {}}} for a in range(len(self.arms))]
        for r in rows:
            if 0 <= r["arm"] < len(by_arm):
                by_arm[r["arm"]][r["status"]] += 1
        minutes = [(r["completed"] - r["started"]) / 60 for r in rows if r["completed"]]
        endings = self.store.endings()  # games by how they ended; a lost one (LOST) was played again
        for a, counts in self.excluded_by_arm().items():
            if 0 <= a < len(by_arm):
                by_arm[a]["excluded"] = counts
        return {
            "study": self.study.id, "title": self.study.title,
            "conditions": [{"label": f"C{i + 1}", **dataclasses.asdict(c)}
                           for i, c in enumerate(self.study.conditions)],
            "arms": by_arm, "quota": self.study.design.quota, "max_participants": self.study.max_participants,
            "participants": {"total": len(rows), "active": sum(r["status"] == "active" for r in rows),
                             "completed": sum(r["status"] == "completed" for r in rows)},
            "completion_minutes": {"median": statistics.median(minutes) if minutes else None,
                                   "values": sorted(round(m, 2) for m in minutes)},
            "live_games": live_games,
            "refused": self.store.refusals(),
            "endings": {"counted": {k: n for k, n in endings.items() if k not in LOST},
                        "played_again": {k: n for k, n in endings.items() if k in LOST}},
            "ending_words": {ending.value: words for ending, words in ADMIN_ENDING_WORDS.items()},
            "recent": [{"pid": r["pid"], "arm": r["arm"], "status": r["status"], "step": r["step"],
                        "started": r["started"], "updated": r["updated"], "completed": r["completed"]}
                       for r in sorted(rows, key=lambda r: -r["updated"])[:200]],
        }

    def excluded_by_arm(self) -> dict[int, dict]:
        """Per arm, the trials and the participants the study's ``[exclusions]`` rules exclude so far, from the
        figures stored when each game ended (``server.study.exclusions``, as the export applies them)."""
        rows = self.store.participants()
        arm_of = {r["pid"]: r["arm"] for r in rows}
        games = [{**g, "participant": g["pid"], "condition_index": g["condition"]} for g in self.store.games()]
        checks = [{"participant": a["pid"], "page": a["page"], "question": a["question"],
                   "answer": json.loads(a["value"]) if a["value"] is not None else None}
                  for a in self.store.answers()]
        out: dict[int, dict] = {}
        for row in exclusion_rows(self.study, games, checks):
            arm = arm_of.get(row["participant"])
            if arm is None:
                continue
            counts = out.setdefault(arm, {"trials": set(), "participants": set(), "rules": {}})
            counts["trials" if row["game_id"] else "participants"].add(row["game_id"] or row["participant"])
            counts["rules"][row["rule"]] = counts["rules"].get(row["rule"], 0) + 1
        return {a: {"trials": len(c["trials"]), "participants": len(c["participants"]), "rules": c["rules"]}
                for a, c in out.items()}
