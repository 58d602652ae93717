"""One game: a person leads, a follower assists; the server owns the state and records everything."""

from __future__ import annotations

import secrets
import time
from dataclasses import dataclass, field

import numpy as np

from colorgrid.config import AGENTS, FOLLOWER, LEADER, EnvConfig
from colorgrid.env import ACTION_NAMES, BatchEnv
from colorgrid.policies.base import AgentInput
from colorgrid.render import look
from colorgrid.replay import Replay
from colorgrid.roles import scores
from colorgrid.step_inputs import StepInputs
from server.protocol import KEY_ACTIONS, Mode

STAY = ACTION_NAMES.index("stay")


MAX_PAGE_EVENTS = 1000
"""Focus and visibility changes recorded per game; later ones are counted in ``meta.page_events_dropped``."""


def now_ms() -> float:
    return time.time() * 1000.0


@dataclass
class Game:
    """State of one live game."""

    config: EnvConfig
    mode: Mode  # a plain string is taken too ("turn", "realtime")
    follower: str
    preset: str
    seed: int
    show_belief: bool
    slot: int
    game_id: str = field(default_factory=lambda: secrets.token_hex(6))
    token: str = field(default_factory=lambda: secrets.token_urlsafe(18))
    created: float = field(default_factory=time.time)
    pool: object = field(default=None, repr=False)  # the FollowerPool serving this game
    max_key_log: int = 20_000  # key presses recorded; later ones still move the leader and are counted
    tick_hz: float = 5.0  # real time: steps a second
    study: dict | None = None  # a study's game: participant, condition, trial index... (recorded in the replay)
    client: dict = field(default_factory=dict)  # the page's user agent and viewport

    def __post_init__(self) -> None:
        self.mode = Mode(self.mode)
        self.env = BatchEnv(self.config, num_envs=1, seed=self.seed, autoreset=False)
        self.obs, _ = self.env.reset()
        self.last = StepInputs.begin(self.config, 1)
        self.pending: dict | None = None  # the latest key not yet applied (its key-log entry)
        self.key_log: list[dict] = []
        self.keys_dropped = 0  # key presses past ``max_key_log`` (not recorded)
        self.state_sent_ms: list[float] = [now_ms()]  # when each state t went out (reaction times)
        self.actions: list = []
        self.goals: list = []
        self.block_reward: list = []
        self.team_reward: list = []
        self.picked: list = []
        self.switched: list = []
        self.beliefs: list = []
        self.hashes = [self.env.state.state_hash(0)]
        self.deadline_misses: list[int] = []
        self.last_key_at = time.monotonic()
        self.disconnected_at: float | None = None
        self.finished = False
        self.replay_id: str | None = None
        self.last_events: list[dict] = []
        self.page_events: list[dict] = []  # the page's focus and visibility changes
        self.page_events_dropped = 0

    # ------------------------------------------------------------ keys
    def press(self, key: str, seq: int, t_client: float) -> str | None:
        """Register a key press; returns an error text for keys that are not moves.

        The latest key wins: one pressed before the previous one was applied marks
        that one ``superseded`` in the key log (nothing is dropped silently).
        """
        entry = {"seq": seq, "key": key, "t_client": t_client, "t_server": now_ms(), "applied_step": None}
        action = KEY_ACTIONS.get(key)
        if action is None:
            entry["status"] = "ignored"
            self._log(entry)
            return f"key {key!r} is not a move; use the arrow keys or WASD"
        entry["action"] = action
        if self.pending is not None:
            self.pending["status"] = "superseded"
        entry["status"] = "pending"
        self.pending = entry
        self._log(entry)
        self.last_key_at = time.monotonic()
        return None

    def page_event(self, event: str, visible: bool | None, t_client: float) -> None:
        """Record that the page lost or got focus, was hidden or shown (capped like the key log)."""
        if len(self.page_events) < MAX_PAGE_EVENTS:
            self.page_events.append({"event": event, "visible": visible, "t_client": t_client,
                                     "t_server": now_ms(), "step": int(self.env.state.t[0])})
        else:
            self.page_events_dropped += 1

    def _log(self, entry: dict) -> None:
        if len(self.key_log) < self.max_key_log:
            self.key_log.append(entry)
        else:
            self.keys_dropped += 1

    def ready(self) -> bool:
        """Whether the world should step now: always in real time, on a pending key when turn-based."""
        return not self.finished and (self.mode == Mode.REALTIME or self.pending is not None)

    def leader_action(self) -> int:
        if self.pending is None:
            return STAY  # real time with no key pending: the leader stays
        return self.pending["action"]

    # ------------------------------------------------------------ steps
    def follower_input(self) -> AgentInput:
        """The follower's input now (copied: a call that missed its deadline may still be reading it)."""
        obs = {k: v.copy() for k, v in self.obs.items()}
        return self.last.agent_input(obs, FOLLOWER, self.env.penalty_coef, self.env.state.goal.copy())

    def apply(self, follower_action: int, belief: np.ndarray | None, missed_deadline: bool) -> None:
        """Step the world with the pending key (or stay) and the follower's action."""
        t = int(self.env.state.t[0])
        leader = self.leader_action()
        if self.pending is not None:
            self.pending["status"], self.pending["applied_step"] = "applied", t
            self.pending = None
        self.goals.append(int(self.env.state.goal[0]))
        joint = np.empty((1, self.config.num_agents), dtype=np.int64)
        joint[0, LEADER], joint[0, FOLLOWER] = leader, follower_action
        self.obs, _, _, truncs, info = self.env.step(joint)
        self.actions.append(joint[0].tolist())
        self.block_reward.append([float(x) for x in info["block_reward"][0]])
        self.team_reward.append(float(info["team_reward"][0]))
        self.picked.append([int(x) for x in info["picked_color"][0]])
        self.switched.append(bool(info["goal_switched"][0]))
        if belief is not None:
            self.beliefs.append([round(float(p), 5) for p in belief])
        self.hashes.append(self.env.state.state_hash(0))
        self.state_sent_ms.append(now_ms())
        if missed_deadline:
            self.deadline_misses.append(t)
        self.last.record(joint, info)
        self.last_events = [
            {"agent": AGENTS[i], "color": int(c), "goal": bool(info["goal_pickup"][0, i])}
            for i, c in enumerate(info["picked_color"][0]) if c >= 0
        ]
        if info["goal_switched"][0]:
            self.last_events.append({"switch": int(info["goal_color"][0])})
        if truncs.all():
            self.finished = True

    # ------------------------------------------------------------ views
    def welcome(self) -> dict:
        cfg = self.config
        return {
            "type": "welcome", "game_id": self.game_id, "token": self.token, "mode": self.mode.value,
            "follower": self.follower, "preset": self.preset,
            "tick_hz": self.tick_hz if self.mode == Mode.REALTIME else None,
            "height": cfg.height, "width": cfg.width, "colors": list(cfg.color_names), "horizon": cfg.horizon,
            "show_belief": self.show_belief, "keys": sorted(KEY_ACTIONS), "look": look(cfg),
        }

    def state_message(self) -> dict:
        s, cfg = self.env.state, self.config
        colors = s.block_colors(cfg)[0].ravel()
        blocks = np.where(colors < 0, ord("."), colors + ord("0")).astype(np.uint8).tobytes().decode("ascii")
        last_seq = max((e["seq"] for e in self.key_log if e["status"] == "applied"), default=None)
        return {
            "type": "state", "step": int(s.t[0]), "horizon": cfg.horizon,
            **{name: int(s.agent_cell[0, i]) for i, name in enumerate(AGENTS)},
            "blocks": blocks,
            "goal": int(s.goal[0]),
            "scores": scores(s, cfg),
            "belief": self.beliefs[-1] if (self.show_belief and self.beliefs) else None,
            "events": self.last_events, "last_applied_seq": last_seq,
        }

    def to_replay(self, ended: str, follower_description: dict) -> Replay:
        for entry in self.key_log:
            if entry["status"] == "pending":
                entry["status"] = "unapplied"  # pressed after the last step the game made
        return Replay(
            config=self.config, seed=self.seed, source="play",
            agents={AGENTS[LEADER]: {"policy": "human"}, AGENTS[FOLLOWER]: follower_description},
            actions=self.actions, goal=self.goals, block_reward=self.block_reward, team_reward=self.team_reward,
            picked_color=self.picked, goal_switched=self.switched,
            goal_probs={AGENTS[FOLLOWER]: self.beliefs} if self.beliefs and len(self.beliefs) == len(self.actions)
            else {},
            state_hashes=self.hashes, ended=ended, key_events=self.key_log,
            meta={"game_id": self.game_id, "mode": self.mode.value, "preset": self.preset,
                  "deadline_misses": self.deadline_misses, "state_sent_ms": self.state_sent_ms,
                  "key_events_dropped": self.keys_dropped, "show_belief": self.show_belief,
                  "tick_hz": self.tick_hz if self.mode == Mode.REALTIME else None,
                  "client": self.client, "page_events": self.page_events,
                  "page_events_dropped": self.page_events_dropped,
                  **({"study": self.study} if self.study else {})},
        )
