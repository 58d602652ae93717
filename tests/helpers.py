"""Shared test helpers."""

import asyncio
import math
import time
from decimal import ROUND_HALF_UP, Decimal

import numpy as np

from colorgrid import BatchEnv, EnvConfig
from colorgrid.scenario import state_from_text

UP, DOWN, LEFT, RIGHT, STAY = range(5)


def js_round(x: float) -> int:
    """JavaScript's ``Math.round``, as a page rounds: halves go up (Python's ``round`` sends 12.5 to 12), and
    0.49999999999999994 down (adding 0.5 first would round it up)."""
    whole = math.floor(x)
    return whole + 1 if x - whole >= 0.5 else whole


def js_fixed(x: float, digits: int) -> str:
    """JavaScript's ``x.toFixed(digits)``, as a page writes a number: the float's exact value rounded, a tie to the
    larger magnitude (Python's format sends the exact tie 6.25 to "6.2", the page writes "6.3"); a negative number
    keeps its sign when it rounds to zero (-0.001: "-0.00"), negative zero has none ("0.00")."""
    rounded = Decimal(abs(x)).quantize(Decimal(1).scaleb(-digits), rounding=ROUND_HALF_UP)
    return ("-" if x < 0 else "") + f"{rounded:.{digits}f}"


def env_from_text(config: EnvConfig, text: str, goal=0, seed=0) -> BatchEnv:
    env = BatchEnv(config, num_envs=1, seed=seed)
    env.load_state(state_from_text(config, text, goal=goal, seed=seed))
    return env


def step1(env: BatchEnv, *actions: int):
    """One step of a batch of one: an action per agent, in index order (1:1: leader, follower)."""
    return env.step(np.array([actions]))


def check_consistent(env: BatchEnv) -> None:
    """The state's redundant views and the observation planes agree with each other."""
    s, cfg = env.state, env.config
    B, HW = env.num_envs, cfg.height * cfg.width
    flat = s.block_at.reshape(B, HW)
    assert ((flat >= 0).sum(axis=1) == cfg.num_blocks).all()
    assert (np.take_along_axis(flat, s.block_cell, axis=1) == np.arange(cfg.num_blocks)).all()
    assert (np.take_along_axis(flat, s.agent_cell, axis=1) < 0).all(), "a block lies under an agent"
    ordered = np.sort(s.agent_cell, axis=1)
    assert (ordered[:, 1:] != ordered[:, :-1]).all(), "agents overlap"
    obs = env._obs.reshape(B, cfg.num_planes, HW)
    colors = s.block_colors(cfg).reshape(B, HW)
    for k in range(cfg.num_colors):
        assert (obs[:, k] == (colors == k)).all()
    for a in range(cfg.num_agents):
        expected = np.zeros((B, HW), dtype=np.uint8)
        expected[np.arange(B), s.agent_cell[:, a]] = 1
        assert (obs[:, cfg.num_colors + a] == expected).all()


class Inbox:
    """A player's connection as the game hub sees it (``server.play.live.Client``): it keeps the messages sent to it and
    the game it plays."""

    def __init__(self):
        self.messages, self.game = [], None

    async def send(self, message: dict) -> None:
        self.messages.append(message)

    def detach(self) -> None:
        self.game = None

    def attach(self, game) -> None:
        self.game = game

    def last(self, kind: str) -> dict:
        return [m for m in self.messages if m["type"] == kind][-1]


def dies_at_start(conn) -> None:
    """An inference process that cannot start (as with a broken install): it exits before answering."""
    raise SystemExit(3)


WAIT_S = 60.0
"""How long ``wait_until`` waits at most: a bound for a loaded CI machine, not a duration any test expects."""


def wait_until(condition, what: str, timeout_s: float = WAIT_S, every_s: float = 0.1):
    """Ask ``condition()`` again until it holds; its value. Fails, naming ``what``, after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not (value := condition()):
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(every_s)
    return value


async def until(condition, timeout_s: float = WAIT_S) -> None:
    """In an event loop: let its tasks run until ``condition()`` holds; fails after ``timeout_s`` (a bound for a loaded
    machine, not a time any test expects)."""
    async def poll():
        while not condition():
            await asyncio.sleep(0.001)

    await asyncio.wait_for(poll(), timeout_s)
