"""A scripted stand-in for a person in the follower seat: it plays games on a running play server through the play
protocol, as a page would, so that the human-follower analysis (``colorgrid replay rescore``, docs/STUDIES.md) can be
shown and tested on real recordings without human data. It is not a person, and its figures are not people's.

What it does, seeing only what a person sees (the goal is hidden from it): it walks toward the leader, and states as
its belief the color of the last block the leader collected that paid (the leader's score went up), which is what
the copy follower acts on; each probe it answers with that color and a confidence of 0.7 (chance when it has seen no
paying pickup yet).

    colorgrid play --replays-dir recordings/scripted --leaders astar --leaders person:slip=0.1,notice_delay=3
    python examples/scripted_assistant.py --games 6 --leader astar --probes steps:20,40,60
    colorgrid replay rescore recordings/scripted --follower bayes-people ippo

With ``--participants N`` it takes part in the study a ``colorgrid study run`` serves, as N participants
(``stand-in-1``, ...) one after another: it passes the study's screening as a desktop browser of 1280 by 800 pixels
would (its round trips measured over the play socket), consents, plays every game of the study in the follower seat,
answers each question (a Likert scale's middle point, a choice's first option, no text; each check's options in turn
until one is taken), so that the study's export, and what is
computed from it (``colorgrid study power``), can be shown on real files without human data:

    colorgrid study run studies/human_follower.toml --replays-dir recordings/stand_in
    python examples/scripted_assistant.py --participants 8
    colorgrid study export studies/human_follower.toml --replays-dir recordings/stand_in --out stand_in_data
"""

from __future__ import annotations

import argparse
import json
import time
import urllib.error
import urllib.request

from websockets.sync.client import connect

PACE_S = 0.04
"""Between two messages: within the server's --max-messages-per-s (40 by default), as a person's keys are."""
VIEWPORT = (1280, 800)
"""The window the stand-in says it has, for a study's screening."""
MOVES = {(-1, 0): "ArrowUp", (1, 0): "ArrowDown", (0, -1): "ArrowLeft", (0, 1): "ArrowRight"}


class StandIn:
    """The stand-in's memory of one game (it is not a person): the belief it states, and its next key number."""

    def __init__(self, welcome: dict):
        self.width, self.agent = welcome["width"], welcome["agent"]
        self.leader = next(name for name in welcome["leaders"])
        self.keys = {color: key for key, color in welcome["belief_keys"].items()}
        self.colors = len(welcome["colors"])
        self.stated, self.seq, self.score = None, 0, 0.0

    def key(self, key: str) -> dict:
        self.seq += 1
        return {"type": "key", "key": key, "seq": self.seq - 1, "t_client": time.time() * 1000}

    def react(self, state: dict) -> list[dict]:
        """The messages a state calls for: a new belief when the leader's pickup paid, a probe's answer, a move."""
        out = []
        paid = state["scores"][self.leader] > self.score  # the leader's score: what its pickup earned
        self.score = state["scores"][self.leader]
        for event in state["events"]:
            if event.get("agent") == self.leader and paid and event["color"] != self.stated:
                self.stated = event["color"]
                out.append(self.key(self.keys[self.stated]))
        if state["probe"] is not None:
            sure = self.stated is not None
            out.append({"type": "probe_answer", "probe": state["probe"]["id"], "color": self.stated or 0,
                        "confidence": 0.7 if sure else round(1 / self.colors + 1e-6, 6),
                        "t_client": time.time() * 1000})
        here, there = divmod(state[self.agent], self.width), divmod(state[self.leader], self.width)
        step = ((there[0] > here[0]) - (there[0] < here[0]), 0) if there[0] != here[0] else \
            (0, (there[1] > here[1]) - (there[1] < here[1]))
        out.append(self.key(MOVES.get(step, "ArrowUp")))
        return out


def play(url: str, leader: str, probes: str, horizon: int, mode: str = "turn", goal: str = "hidden") -> dict:
    """One turn-based game in the follower seat; returns its ``game_over``."""
    return play_game(url, {"type": "new_game", "seat": "follower", "leader": leader, "probes": probes, "goal": goal,
                           "mode": mode, "horizon": horizon})


def play_game(url: str, new_game: dict) -> dict:
    """The game ``new_game`` starts, played in the follower seat to its end; returns its ``game_over``."""
    with connect(url, open_timeout=20) as ws:
        ws.send(json.dumps(new_game))
        me = None
        while True:
            msg = json.loads(ws.recv(timeout=60))
            if msg["type"] == "welcome":
                me = StandIn(msg)
            elif msg["type"] == "state" and me is not None and msg["step"] < msg["horizon"]:
                for reply in me.react(msg):
                    time.sleep(PACE_S)
                    ws.send(json.dumps(reply))
            elif msg["type"] == "game_over":
                return msg
            elif msg["type"] in ("error", "full"):
                raise RuntimeError(f"the server refused: {msg}")


def post(base: str, path: str, body: dict) -> dict:
    request = urllib.request.Request(base + path, data=json.dumps(body).encode(), method="POST",
                                     headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(request, timeout=60) as response:
        return json.loads(response.read())


def round_trips(url: str, pings: int) -> list[float]:
    """The round trips (ms) of ``pings`` pings over a play socket, as the study page measures them before consent."""
    times = []
    with connect(url, open_timeout=20) as ws:
        for _ in range(pings):
            sent = time.perf_counter()
            ws.send(json.dumps({"type": "ping"}))
            while json.loads(ws.recv(timeout=60))["type"] != "pong":
                pass
            times.append((time.perf_counter() - sent) * 1000)
    return times


def answer(question: dict):
    """The stand-in's answer to a study's question: a Likert scale's middle point, a choice's first option, no text."""
    return {"likert": (question["scale"] + 1) // 2, "choice": (question["options"] or [None])[0]}.get(question["kind"])


def take_part(url: str, pid: str) -> int:
    """Go through the study served at ``url`` (the play socket's URL) as participant ``pid``, from consent to its
    last page; returns the games played."""
    base = url.replace("ws://", "http://", 1).replace("wss://", "https://", 1).removesuffix("/ws/play")
    with urllib.request.urlopen(base + "/api/study/info", timeout=60) as response:
        screening = json.loads(response.read())["screening"]
    join = {"params": {"PROLIFIC_PID": pid, "STUDY_ID": "stand-in", "SESSION_ID": pid}}
    if screening is not None:
        join["screen"] = {"touch_only": False, "viewport": list(VIEWPORT),
                          "round_trips_ms": round_trips(url, screening["pings"])}
    joined = post(base, "/api/study/join", join)
    who, view, games = {"pid": pid, "session": joined["session"]}, joined["view"], 0
    while not view.get("finished") and view["kind"] != "debrief":
        body = {**who, "step": view["step"]}
        if view["kind"] == "consent":
            body["agree"] = True
        if view.get("game") and not view.get("done"):
            play_game(url, {"type": "new_game", "study": {"participant": pid, "session": joined["session"]}})
            games += 1
        tried = {q["id"]: 0 for q in view.get("questions") or []}  # a check: the option tried
        while True:
            if view.get("questions"):
                body["answers"] = {q["id"]: q["options"][tried[q["id"]]] if q["kind"] == "check" else answer(q)
                                   for q in view["questions"]}
            try:
                view = post(base, "/api/study/advance", body)
                break
            except urllib.error.HTTPError as err:  # a check answered wrong, with tries left: the next option
                detail = json.loads(err.read())["detail"]
                if err.code != 422 or not isinstance(detail, dict) or not detail.get("again"):
                    raise
                for problem in detail["problems"]:
                    tried[problem["question"]] += 1
    return games


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--url", default="ws://127.0.0.1:8000/ws/play")
    parser.add_argument("--games", type=int, default=4)
    parser.add_argument("--leader", action="append", help="AI leader(s), played in turn (default: astar)")
    parser.add_argument("--probes", default="steps:20,40,60")
    parser.add_argument("--horizon", type=int, default=80)
    parser.add_argument("--participants", type=int, help="take part in the study the server runs as this many "
                                                          "participants instead (its games' settings are the study's)")
    args = parser.parse_args()
    for i in range(args.participants or 0):
        pid = f"stand-in-{i + 1}"
        print(f"{pid}: {take_part(args.url, pid)} games")
    if args.participants:
        return
    leaders = args.leader or ["astar"]
    for i in range(args.games):
        over = play(args.url, leaders[i % len(leaders)], args.probes, args.horizon)
        print(f"game {i + 1}: {over['replay_id']} ({over['steps']} steps, team {over['scores']['team']:+g})")


if __name__ == "__main__":
    main()
