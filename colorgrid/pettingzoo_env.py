"""PettingZoo views of the batched environment: a thin wrapper over a batch of one."""

from __future__ import annotations

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv
from pettingzoo.utils.conversions import parallel_to_aec

from colorgrid.config import ENV_ID, EnvConfig
from colorgrid.env import BatchEnv
from colorgrid.render import render_ansi, render_rgb
from colorgrid.seat_view import seat_view

RENDER_MODES = ("rgb_array", "ansi", "human")


class ColorGridParallelEnv(ParallelEnv):
    """ColorGrid as a PettingZoo ``ParallelEnv``.

    Agents: ``"leader"`` and ``"follower"`` in the 1:1 team; otherwise ``leader_0, leader_1, ...,
    follower_0, ...`` (``EnvConfig.agent_names``). Each agent observes ``{"observation": uint8
    [P, H, W], "goal_info": float32 [num_colors]}``. In the 1:1 team ``P = num_colors + 2`` (one plane
    per color, then leader, then follower), the same for both agents. In other teams there is one plane
    per agent in index order and a last plane marking the observing agent's own cell, so that an agent
    can tell which one it is: ``P = num_colors + A + 1``. With ``flatten=True`` the observation is instead
    one float32 ``Box`` of ``P * H * W + num_colors`` values: those planes flattened in C order (plane,
    row, column), then ``goal_info``, the layout of the Gymnasium view's ``flatten=True``.

    Infos carry the unshaped block rewards, pickups, shaping terms, the true goal color (for evaluation:
    it is not an observation) and the episode's seed. Reset and every step give the same keys, with the
    same types (reset's are neutral: zero rewards, no pickups, no switch), so that libraries that build
    their info spec from the reset (TorchRL) see every step's infos.
    ``render_mode="human"`` prints the ANSI view to the terminal.
    """

    metadata = {"name": ENV_ID, "render_modes": list(RENDER_MODES), "is_parallelizable": True, "render_fps": 5}

    def __init__(self, config: EnvConfig | None = None, render_mode: str | None = None, flatten: bool = False):
        if render_mode is not None and render_mode not in RENDER_MODES:
            raise ValueError(f"render_mode must be one of {list(RENDER_MODES)} or None, got {render_mode!r}")
        if not isinstance(flatten, (bool, np.bool_)):
            raise ValueError(f"flatten must be True (one float32 Box) or False (the Dict), got {flatten!r}")
        self.config = config if config is not None else EnvConfig()
        self.render_mode = render_mode
        self.flatten = bool(flatten)
        self.batch = BatchEnv(self.config, num_envs=1, autoreset=False)
        cfg = self.config
        self.names = cfg.agent_names
        self.possible_agents = list(self.names)
        self.agents: list[str] = []
        self.metadata = {**self.metadata, "name": cfg.env_id}
        self._self_plane = not cfg.one_to_one
        planes = cfg.num_planes + self._self_plane
        if self.flatten:
            obs_space = spaces.Box(0.0, 1.0, (planes * cfg.height * cfg.width + cfg.num_colors,), dtype=np.float32)
        else:
            obs_space = spaces.Dict({
                "observation": spaces.Box(0, 1, (planes, cfg.height, cfg.width), dtype=np.uint8),
                "goal_info": spaces.Box(0.0, 1.0, (cfg.num_colors,), dtype=np.float32),
            })
        self._observation_spaces = {a: obs_space for a in self.names}
        self._action_spaces = {a: spaces.Discrete(cfg.num_actions) for a in self.names}

    def observation_space(self, agent: str) -> spaces.Space:
        return self._observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Space:
        return self._action_spaces[agent]

    def reset(self, seed: int | None = None, options: dict | None = None):
        obs, info = self.batch.reset(seed=seed)
        self.agents = list(self.names)
        A = self.config.num_agents
        zeros, nothing = np.zeros((1, A), dtype=np.float32), np.zeros((1, A), dtype=np.bool_)
        neutral = {"block_reward": zeros, "team_reward": zeros[:, 0], "goal_pickup": nothing, "wrong_pickup": nothing,
                   "distance_shaping": zeros, "potential_shaping": zeros, "goal_color": info["goal_color"],
                   "goal_switched": nothing[:, 0]}
        return self._split(obs), self._infos(neutral)

    def step(self, actions: dict):
        if not self.agents:
            raise RuntimeError("the episode has ended: call reset() before step()")
        missing = [a for a in self.agents if a not in actions]
        if missing:
            raise ValueError(f"actions missing for agent(s) {missing}; expected one per agent in {self.agents}")
        joint = np.array([[actions[a] for a in self.names]], dtype=np.int64)
        obs, rewards, terms, truncs, info = self.batch.step(joint)
        reward_list, term_list, trunc_list = rewards[0].tolist(), terms[0].tolist(), truncs[0].tolist()
        out = (
            self._split(obs),
            dict(zip(self.names, reward_list)),
            dict(zip(self.names, term_list)),
            dict(zip(self.names, trunc_list)),
            self._infos(info),
        )
        if all(trunc_list) or all(term_list):
            self.agents = []
        if self.render_mode == "human":
            self.render()
        return out

    def render(self):
        if self.render_mode is None or self.batch.state is None:
            return None
        if self.render_mode == "rgb_array":
            return render_rgb(self.batch.state, self.config)
        text = render_ansi(self.batch.state, self.config, color=self.render_mode == "human")
        if self.render_mode == "ansi":
            return text
        print(text, flush=True)
        return None

    def state(self) -> np.ndarray:
        """The global state as the shared observation planes (every agent sees the whole grid)."""
        return self.batch._obs[0].copy()

    def close(self) -> None:
        pass

    def _infos(self, info: dict) -> dict:
        """Each agent's infos from the batch's (a batch of one), as Python scalars: the same keys at reset and
        every step."""
        # one .tolist() per array: Python scalars without per-element numpy conversions
        block, shaping_d, shaping_p = (info[k][0].tolist() for k in ("block_reward", "distance_shaping",
                                                                       "potential_shaping"))
        hit, wrong = info["goal_pickup"][0].tolist(), info["wrong_pickup"][0].tolist()
        team, goal, switched = float(info["team_reward"][0]), int(info["goal_color"][0]), bool(info["goal_switched"][0])
        seed = int(self.batch.state.seed[0])
        return {
            a: {"block_reward": block[i], "team_reward": team, "goal_pickup": hit[i], "wrong_pickup": wrong[i],
                "distance_shaping": shaping_d[i], "potential_shaping": shaping_p[i], "goal_color": goal,
                "goal_switched": switched, "seed": seed}
            for i, a in enumerate(self.names)
        }

    def _split(self, obs: dict) -> dict:
        """Each agent's view of env 0's observations (``seat_view`` of a batch of one)."""
        out = {}
        for i, a in enumerate(self.names):
            view = seat_view(obs["observation"][:1], obs["goal_info"][:1], i, self.config.num_colors,
                             self._self_plane, self.flatten)
            out[a] = view[0] if self.flatten else {key: value[0] for key, value in view.items()}
        return out


def parallel_env(config: EnvConfig | None = None, render_mode: str | None = None, flatten: bool = False,
                 max_cycles: int | None = None, **overrides) -> ColorGridParallelEnv:
    """A ``ParallelEnv``; ``overrides`` are EnvConfig fields applied on top of ``config``. ``flatten=True``: each
    observation one float32 vector (the planes, then the goal one-hot), for libraries whose default networks
    take no ``Dict`` (RLlib's stops with ``No default encoder config for obs space=Dict``). ``max_cycles``:
    PettingZoo's name for the ``horizon`` (steps per episode), as its environments and ``max_cycles_test`` take
    it; giving both is refused unless they agree."""
    config = config if config is not None else EnvConfig()
    overrides = horizon_from_max_cycles(max_cycles, overrides)
    if overrides:
        config = config.replace(**overrides)
    return ColorGridParallelEnv(config, render_mode=render_mode, flatten=flatten)


def env(config: EnvConfig | None = None, render_mode: str | None = None, flatten: bool = False,
        max_cycles: int | None = None, **overrides):
    """The AEC version, through PettingZoo's ``parallel_to_aec`` conversion; arguments as ``parallel_env``'s."""
    return parallel_to_aec(parallel_env(config, render_mode=render_mode, flatten=flatten, max_cycles=max_cycles,
                                        **overrides))


def horizon_from_max_cycles(max_cycles: int | None, overrides: dict) -> dict:
    """``overrides`` with PettingZoo's ``max_cycles`` given as EnvConfig's ``horizon`` (the one setting, two names)."""
    if max_cycles is None:
        return overrides
    if "horizon" in overrides and overrides["horizon"] != max_cycles:
        raise ValueError(f"max_cycles={max_cycles!r} and horizon={overrides['horizon']!r} disagree: they are one "
                         f"setting (PettingZoo's name and ColorGrid's for the steps per episode); give one of them")
    return {**overrides, "horizon": max_cycles}
