"""One game: people lead, AI followers assist; the server owns the state and records everything.

A game's team is its config's (``EnvConfig.num_leaders``, ``num_followers``). Each leader is a
``Seat`` played by a person, or an AI leader beside them (``Game.leader_kinds``: the last leader
seats); each follower and AI leader is an ``AIPlayer``: a slot in the pool built for its agent index.
A person may take the follower seat instead (``Game.seat``): then every leader is an AI leader, the
goal may be hidden from them, and what they state they believe is recorded (``server.stated``).
When a person leaves a game that other people still play, a scripted leader takes their seat (an
``AIPlayer`` at the seat's agent index) and the replay says from which step. Seats and AI players are
declared in ``server.seats``, the key log in ``server.keylog``.
"""

from __future__ import annotations

import secrets
import time
from dataclasses import dataclass, field

import numpy as np

from colorgrid.config import EnvConfig
from colorgrid.enums import Ending, KeyStatus, Role, SeatFit
from colorgrid.env import ACTION_DELTAS, BatchEnv
from colorgrid.policies.base import AgentInput
from colorgrid.render import look
from colorgrid.replay import Replay
from colorgrid.replay.blocks import encode_blocks
from colorgrid.roles import columns, scores
from colorgrid.step_inputs import StepInputs
from server.keylog import PENDING, CappedLog, KeyLog, now_ms
from server.messages import SeatView, State, Welcome
from server.protocol import KEY_ACTIONS, GoalView, Mode, belief_keys
from server.seats import STAND_IN, AIPlayer, Seat, lineup, pair_view
from server.stated import ProbePlan, StatedBeliefs, Via

MAX_PAGE_EVENTS = 1000
"""Focus and visibility changes recorded per game; later ones are counted in ``meta.page_events_dropped``."""


@dataclass
class Game:
    """State of one live game."""

    config: EnvConfig
    mode: Mode  # a plain string is taken too ("turn", "realtime")
    follower: str  # the AI followers' name (``follower_label``)
    preset: str
    seed: int
    show_belief: bool
    game_id: str = field(default_factory=lambda: secrets.token_hex(6))
    created: float = field(default_factory=time.time)
    max_key_log: int = 20_000  # key presses recorded; later ones still move their leader and are counted
    tick_hz: float = 5.0  # real time: steps a second
    study: dict | None = None  # a study's game: participant, condition, trial index... (recorded in the replay)
    room: str | None = None  # the room's code, for a game of several people
    follower_kinds: tuple[str, ...] = ()  # each AI follower's kind, in agent order (all ``follower`` if empty)
    leader_kinds: tuple[str, ...] = ()  # each AI leader's kind: they play the last leader seats, people the first
    seat: Role = Role.LEADER  # the people's seat: leaders, or the first follower beside AI leaders
    goal_view: GoalView = GoalView.SHOWN  # the follower seat: whether its person sees the goal (a leader always does)
    probes: ProbePlan = field(default_factory=ProbePlan)  # the follower seat: when the game asks what they believe

    def __post_init__(self) -> None:
        self.mode, self.seat, self.goal_view = Mode(self.mode), Role(self.seat), GoalView(self.goal_view)
        cfg = self.config
        # AI leaders in ``leader_kinds`` order, AI followers in ``follower_kinds`` order
        people, self.ai_leaders, self.ai_followers = lineup(cfg, self.seat, len(self.leader_kinds))
        self.seats = [Seat(i, cfg.agent_names[i]) for i in people]
        self.stated = None if self.seat == Role.LEADER else StatedBeliefs(
            cfg, cfg.agent_names[people[0]], self.probes, self.seed, tagged=not cfg.one_to_one)
        self.ai: dict[int, AIPlayer] = {}  # agent index -> its policy's slot (followers, AI and stand-in leaders)
        self.env = BatchEnv(cfg, num_envs=1, seed=self.seed, autoreset=False)
        self.obs, _ = self.env.reset()
        self.last = StepInputs.begin(cfg, 1)
        self.keys = KeyLog(self.max_key_log)  # key presses; past ``max_key_log`` only counted
        self.state_sent_ms: list[float] = [now_ms()]  # when each state t went out (reaction times)
        self.actions: list = []
        self.goals: list = []
        self.block_reward: list = []
        self.team_reward: list = []
        self.picked: list = []
        self.switched: list = []
        self.hashes = [self.env.state.state_hash(0)]
        self.deadline_misses: list[int] = []
        self.finished = False
        self.replay_id: str | None = None
        self.stated_record: dict | None = None  # the follower seat, once saved: game_over's `stated`
        self.last_events: list[dict] = []
        self.page_events = CappedLog(MAX_PAGE_EVENTS)  # the pages' focus and visibility changes

    # ------------------------------------------------------------ who plays
    @property
    def solo(self) -> bool:
        """One person and one follower: messages and replays exactly as before teams."""
        return self.config.one_to_one

    @property
    def token(self) -> str:
        """The first seat's rejoin token (a game of one person has no other)."""
        return self.seats[0].token

    @property
    def people(self) -> list[Seat]:
        """The seats still played by a person (connected or within the rejoin grace)."""
        return [s for s in self.seats if s.left is None]

    def seat_of(self, client) -> Seat | None:
        """The seat ``client`` plays, or None (it never did, it was replaced, or the person left)."""
        return next((s for s in self.people if client is not None and s.client is client), None)

    @property
    def paused(self) -> bool:
        """A person is reconnecting: the game waits for them (at most the rejoin grace)."""
        return any(s.client is None for s in self.people)

    def controlled(self) -> bool:
        """Every agent has a player (false while a stand-in leader is being loaded)."""
        return len(self.people) + len(self.ai) == self.config.num_agents

    def leave(self, seat: Seat, reason: Ending) -> None:
        """The person in ``seat`` left; a stand-in must be attached (``attach``) before the next step."""
        seat.left, seat.left_at_step = reason, int(self.env.state.t[0])
        seat.client, seat.pending = None, None

    def attach(self, agent: int, pool, slot: int, view: tuple[int, int] | None = None) -> None:
        """``agent`` is played from now on by ``pool``'s ``slot`` (seeing the game through ``pair_view`` of
        ``view`` when given)."""
        self.ai[agent] = AIPlayer(agent, pool, slot, view=view)

    def describe_ai(self) -> dict[int, dict]:
        """Each AI player's ``agents`` entry for this game's replay (``PolicyPool.describe`` of its slot): asked
        before the slots are given back, while each still holds what this game had (a population's member)."""
        return {agent: player.pool.describe(player.slot) for agent, player in self.ai.items()}

    def release_slots(self) -> None:
        """Give back the pool slots of this game's AI players."""
        for player in self.ai.values():
            player.pool.release(player.slot)

    # ------------------------------------------------------------ keys
    def press(self, key: str, seq: int, t_client: float, seat: Seat | None = None) -> str | None:
        """Register a key press of ``seat`` (the first by default); returns an error text for keys that are
        not moves (nor, in the follower seat, belief keys: those state a belief and move nothing, logged ``stated``).
        A ``seq`` not after this person's last one raises ``BadSeq``, and nothing is logged.

        The latest key wins: one pressed before the previous one was applied marks
        that one ``superseded`` in the key log (nothing is dropped silently). A key that arrives after the
        game's last step is logged ``unapplied``.
        """
        seat = seat or self.seats[0]
        entry = self.keys.entry(seat, key, seq, t_client, tagged=not self.solo)
        action, color = KEY_ACTIONS.get(key), self.belief_keys.get(key)
        if color is not None:  # "I believe the goal is this color": no move (after the last step: recorded only)
            entry.update(status=KeyStatus.UNAPPLIED if self.finished else KeyStatus.STATED, color=color)
            if not self.finished:
                self.stated.state(color, Via.KEY, t_client, int(self.env.state.t[0]))
            self.keys.add(entry)
            return None
        if action is None:
            entry["status"] = KeyStatus.IGNORED
            self.keys.add(entry)
            if self.stated is None:
                return f"key {key!r} is not a move; use the arrow keys or WASD"
            return (f"key {key!r} is not a move or a color of this game: move with the arrow keys or WASD; say "
                    f"which color you believe is the goal with {'/'.join(self.belief_keys)}")
        entry["action"] = action
        if self.finished:  # on its way when the last step was made: recorded, never applied
            entry["status"] = KeyStatus.UNAPPLIED
            self.keys.add(entry)
            return None
        if seat.pending is not None:
            seat.pending["status"] = KeyStatus.SUPERSEDED
        entry["status"] = PENDING
        seat.pending = entry
        self.keys.add(entry)
        seat.last_key_at = time.monotonic()
        return None

    @property
    def belief_keys(self) -> dict[str, int]:
        """The keys that state a belief (``1`` is color 0) in the follower seat; none in a leader's."""
        return {} if self.stated is None else belief_keys(self.config.num_colors)

    def state_belief(self, color: int, t_client: float) -> None:
        """The person in the follower seat says the goal is ``color`` (a click on its swatch)."""
        if self.stated is None:
            raise ValueError("only a person in the follower seat states a belief: a leader knows the goal")
        if not self.finished:  # after the last step it would describe no step
            self.stated.state(color, Via.CLICK, t_client, int(self.env.state.t[0]))

    def answer_probe(self, probe: int, color: int, confidence: float, t_client: float) -> None:
        """The answer to the open probe (``server.stated.StatedBeliefs.answer``)."""
        if self.stated is None:
            raise ValueError("only a person in the follower seat is asked probes")
        self.stated.answer(probe, color, confidence, t_client, int(self.env.state.t[0]))

    def page_event(self, event: str, visible: bool | None, t_client: float, seat: Seat | None = None) -> None:
        """Record that a page lost or got focus, was hidden or shown (capped like the key log)."""
        entry = {"event": event, "visible": visible, "t_client": t_client, "t_server": now_ms(),
                 "step": int(self.env.state.t[0])}
        self.page_events.add(entry if self.solo else {"agent": (seat or self.seats[0]).name, **entry})

    def ready(self) -> bool:
        """Whether the world should step now. Real time: on the clock, unless a person is reconnecting.
        Turn-based: once every person has a key pending (people move together, see docs/SERVER_PROTOCOL.md) and no
        probe waits for its answer."""
        if self.finished or self.paused or not self.controlled() or not self.people:
            return False
        if self.mode == Mode.REALTIME:
            return True
        waiting = self.stated is not None and self.stated.open_probe is not None
        return not waiting and all(s.pending is not None for s in self.people)

    # ------------------------------------------------------------ steps
    def ai_input(self, player: AIPlayer) -> AgentInput:
        """A policy's input now (copied: a call that missed its deadline may still be reading it)."""
        obs = {k: v.copy() for k, v in self.obs.items()}
        start = np.ones(1, dtype=bool) if player.fresh else None
        inp = self.last.agent_input(obs, player.agent, self.env.penalty_coef, self.env.state.goal.copy(), start)
        return inp if player.view is None else pair_view(inp, self.config, player.view)

    def apply(self, moves: dict[int, tuple[int, np.ndarray | None, bool]]) -> None:
        """Step the world with each person's pending key (or stay) and the policies' ``moves``: agent index ->
        (action, belief or None, whether inference missed its deadline)."""
        t = int(self.env.state.t[0])
        self.goals.append(int(self.env.state.goal[0]))
        if self.stated is not None:
            self.stated.before_step()
        joint = np.empty((1, self.config.num_agents), dtype=np.int64)
        for seat in self.people:
            joint[0, seat.agent] = seat.action()
            if seat.pending is not None:
                seat.pending["status"], seat.pending["applied_step"] = KeyStatus.APPLIED, t
                seat.last_applied_seq = max(seat.pending["seq"], seat.last_applied_seq or 0)
                seat.pending = None
        missed = False
        for agent, (action, belief, miss) in moves.items():
            joint[0, agent] = action
            player = self.ai[agent]
            player.fresh = False
            if belief is None and miss and player.pool.has_belief:  # the deadline was missed: the belief repeats
                # the last one, or before the first, is the uniform one the follower starts from (no step seen),
                # so the belief track keeps a row a step (the replay's ``meta.deadline_misses`` says which)
                belief = player.beliefs[-1] if player.beliefs else [1.0 / self.config.num_colors] * self.config.num_colors
            if belief is not None:
                player.beliefs.append([round(float(p), 5) for p in belief])
            missed |= miss
        self.obs, _, _, truncs, info = self.env.step(joint)
        self.actions.append(joint[0].tolist())
        self.block_reward.append([float(x) for x in info["block_reward"][0]])
        self.team_reward.append(float(info["team_reward"][0]))
        self.picked.append([int(x) for x in info["picked_color"][0]])
        self.switched.append(bool(info["goal_switched"][0]))
        self.hashes.append(self.env.state.state_hash(0))
        self.state_sent_ms.append(now_ms())
        if missed:
            self.deadline_misses.append(t)
        self.last.record(joint, info)
        names = self.config.agent_names
        self.last_events = [
            {"agent": names[i], "color": int(c), "goal": bool(info["goal_pickup"][0, i])}
            for i, c in enumerate(info["picked_color"][0]) if c >= 0
        ]
        if info["goal_switched"][0]:
            self.last_events.append({"switch": int(info["goal_color"][0])})
        if truncs.all():
            self.finished = True
        if self.stated is not None:
            self.stated.after_step(t + 1, self.finished)

    def followers(self) -> list[AIPlayer]:
        """The AI followers, in agent order."""
        return [self.ai[i] for i in self.ai_followers if i in self.ai]

    @property
    def goal_hidden(self) -> bool:
        """Whether the goal is kept from the people: a person in the follower seat with the goal hidden."""
        return self.stated is not None and self.goal_view == GoalView.HIDDEN

    # ------------------------------------------------------------ views
    def seats_view(self) -> list[SeatView]:
        """Each person's seat for the pages: ``{agent, symbol, status}``."""
        symbols = self.config.symbols
        return [SeatView(agent=s.name, symbol=symbols[s.agent], status=s.status()) for s in self.seats]

    def welcome(self, seat: Seat | None = None) -> Welcome:
        """The ``welcome`` of ``seat`` (the first by default): its own token; in a team, its own agent."""
        cfg, seat = self.config, seat or self.seats[0]
        fields = {}  # the fields of some games only
        if not self.solo:
            fields.update(team=self.config.team, agent=seat.name, seats=self.seats_view(), room=self.room)
        if self.stated is not None:  # the follower seat: who they are, what they see, how they say what they believe
            fields.update(seat=self.seat, agent=seat.name, goal_view=self.goal_view, belief_keys=self.belief_keys,
                          probes=self.probes.text, confidence_min=round(1.0 / cfg.num_colors, 6))
        if len(self.ai_followers) > 1:  # each AI follower's kind, by agent name
            kinds = self.follower_kinds or (self.follower,) * len(self.ai_followers)
            fields["followers"] = dict(zip((cfg.agent_names[i] for i in self.ai_followers), kinds))
        if self.leader_kinds:  # each AI leader's kind, by agent name
            fields["leaders"] = dict(zip((cfg.agent_names[i] for i in self.ai_leaders), self.leader_kinds))
        return Welcome(
            type="welcome", game_id=self.game_id, token=seat.token, mode=self.mode, follower=self.follower,
            preset=self.preset, tick_hz=self.tick_hz if self.mode == Mode.REALTIME else None, height=cfg.height,
            width=cfg.width, colors=list(cfg.color_names), horizon=cfg.horizon, show_belief=self.show_belief,
            keys=sorted(KEY_ACTIONS), look=look(cfg), next_seq=seat.next_seq, prediction=self.prediction(seat),
            **fields)

    def prediction(self, seat: Seat) -> dict:
        """What a page needs to draw its person's own move before the server's state shows it (the state corrects
        it): each move key's ``[row, col]`` change and the columns ``[first, stop)`` the person's agent may stand
        on. A move off them, or onto another agent's cell, leaves the agent where it is (docs/ENV_CARD.md)."""
        return {"moves": {key: ACTION_DELTAS[action].tolist() for key, action in KEY_ACTIONS.items()},
                "columns": list(columns(self.config, seat.agent))}

    def state_message(self) -> State:
        """The ``state`` after the last step (or at the start), as every person of the game sees it."""
        s, cfg = self.env.state, self.config
        colors = s.block_colors(cfg)[0].ravel()
        blocks = encode_blocks(colors)
        fields = {name: int(s.agent_cell[0, i]) for i, name in enumerate(cfg.agent_names)}  # each agent's cell
        if self.solo:
            players = self.followers()
            beliefs = players[0].beliefs if players else []
            fields["belief"] = beliefs[-1] if (self.show_belief and beliefs) else None
        else:  # one belief per AI follower, by name
            fields["beliefs"] = {cfg.agent_names[p.agent]: p.beliefs[-1] if (self.show_belief and p.beliefs)
                                 else None for p in self.followers()}
        if self.stated is not None:
            fields.update(self.stated.view())
        return State(
            type="state", step=int(s.t[0]), horizon=cfg.horizon, blocks=blocks,
            goal=None if self.goal_hidden else int(s.goal[0]), scores=scores(s, cfg),
            events=[e for e in self.last_events if "switch" not in e] if self.goal_hidden else self.last_events,
            last_applied_seq=self.seats[0].last_applied_seq if self.solo else {
                seat.name: seat.last_applied_seq for seat in self.seats},
            **fields)

    def to_replay(self, ended: Ending, descriptions: dict[int, dict]) -> Replay:
        """The game as a replay; ``descriptions``: agent index -> its policy's ``agents`` entry (each AI follower
        and AI leader; one that saw the game through ``pair_view`` says so under ``view``)."""
        self.keys.close()
        if self.stated is not None:
            self.stated.close()
        names = self.config.agent_names
        agents = {}
        for i, name in enumerate(names):
            seat = next((s for s in self.seats if s.agent == i), None)
            if seat is None:
                view = self.ai[i].view if i in self.ai else None
                agents[name] = descriptions[i] if view is None else {
                    **descriptions[i], "view": {"team": SeatFit.PAIR_VIEW, "agents": [names[a] for a in view]}}
            elif seat.left is None:
                agents[name] = {"policy": "human"}
            else:  # a person who left: the stand-in leader's moves from that step on
                agents[name] = {"policy": "human", "replaced_by": STAND_IN, "from_step": seat.left_at_step}
        meta = {"game_id": self.game_id, "mode": self.mode.value, "preset": self.preset,
                "deadline_misses": self.deadline_misses, "state_sent_ms": self.state_sent_ms,
                "key_events_dropped": self.keys.dropped, "show_belief": self.show_belief,
                "tick_hz": self.tick_hz if self.mode == Mode.REALTIME else None}
        if self.solo:
            meta["client"] = self.seats[0].client_info
        else:
            meta.update(team=self.config.team, room=self.room,
                        clients={s.name: s.client_info for s in self.seats},
                        seats_left=[{"agent": s.name, "reason": s.left, "from_step": s.left_at_step,
                                     "replaced_by": STAND_IN} for s in self.seats if s.left])
        meta.update(page_events=self.page_events.entries, page_events_dropped=self.page_events.dropped,
                    **({"study": self.study} if self.study else {}))
        stated = {}
        if self.stated is not None:
            per_step, events, probes = self.stated.record()
            stated = {"stated_beliefs": {self.stated.agent: per_step}, "belief_events": events, "probes": probes}
            meta.update(seat=self.seat.value, goal_view=self.goal_view.value, probes=self.probes.text)
        return Replay(
            config=self.config, seed=self.seed, source="play", agents=agents,
            actions=self.actions, goal=self.goals, block_reward=self.block_reward, team_reward=self.team_reward,
            picked_color=self.picked, goal_switched=self.switched,
            goal_probs={names[p.agent]: p.beliefs for p in self.followers()
                        if p.beliefs and len(p.beliefs) == len(self.actions)},
            state_hashes=self.hashes, ended=ended, key_events=self.keys.entries, meta=meta, **stated,
        )
