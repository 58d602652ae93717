"""Gymnasium views: one seat of a team as a single-agent env, its partners played by policies.

Single-agent libraries (Stable-Baselines3, CleanRL-style loops, most of Gymnasium's tools) train one
agent. ``SeatVectorEnv`` is ``BatchEnv`` seen from one seat (``"follower"``, ``"leader"``, or
``follower_0``... in larger teams): the other agents act by policies (scripted, a population, a frozen
checkpoint), so the seat's agent meets the same partners every library sees. ``SeatEnv`` is the same view
of a batch of one. Both are thin views: the rules are ``BatchEnv``'s, partners see what they see in
rollouts (``StepInputs``).

Observations: the PettingZoo view's ``Dict`` (``observation`` uint8 ``[P, H, W]``, ``goal_info``
float32 ``[C]``: zeros for a follower in the asymmetric setting), or with ``flatten=True`` one float32
``Box`` of ``P * H * W + C`` values (planes first), which every library's MLP policy takes. Rewards are
the seat's own reward from the env (the team's in ``shared`` mode). Infos carry the seat's unshaped block
reward, pickups and the true goal (for evaluation; not an observation).

Registered with Gymnasium as ``colorgrid/ColorGrid-v0`` (``gymnasium.make`` and ``gymnasium.make_vec``
after ``import colorgrid``); the version follows ``ENV_ID``.
"""

from __future__ import annotations

from typing import Mapping

import gymnasium
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv

from colorgrid import rng
from colorgrid.config import ENV_ID, EnvConfig
from colorgrid.env import BatchEnv
from colorgrid.policies import make_policy
from colorgrid.render import render_ansi, render_rgb
from colorgrid.seat_view import seat_view
from colorgrid.step_inputs import StepInputs

GYM_ID = f"colorgrid/ColorGrid-v{ENV_ID.rsplit('_v', 1)[1]}"
"""Gymnasium's id for the seat view; its version is the environment's (``ENV_ID``)."""
RENDER_MODES = ("rgb_array", "ansi")
DEFAULT_PARTNERS = {"leader": "astar", "follower": "bayes"}
"""Who plays the other seats unless told: A* leaders and Bayesian followers (by role)."""


def partner_specs(config: EnvConfig, seat: int, partners: str | Mapping[str, str] | None) -> dict[int, str]:
    """The policy spec of every agent but ``seat``: one spec for all of them, a ``{agent name: spec}`` map (the
    rest by role from ``DEFAULT_PARTNERS``), or None (all by role)."""
    names = config.agent_names
    if isinstance(partners, Mapping):
        unknown = sorted(set(partners) - set(names)) + ([names[seat]] if names[seat] in partners else [])
        if unknown:
            raise ValueError(f"partners: {unknown} are not other agents of this team; name some of "
                             f"{[n for i, n in enumerate(names) if i != seat]}")
    specs = {}
    for i, name in enumerate(names):
        if i == seat:
            continue
        role = config.roles[i]
        if isinstance(partners, str):
            specs[i] = partners
        elif partners is not None and name in partners:
            specs[i] = partners[name]
        else:
            specs[i] = DEFAULT_PARTNERS[role]
    return specs


def seat_index(config: EnvConfig, seat: str) -> int:
    if seat not in config.agent_names:
        raise ValueError(f"seat {seat!r} is not an agent of this team; choose one of {list(config.agent_names)}")
    return config.agent_names.index(seat)


class SeatVectorEnv(VectorEnv):
    """``num_envs`` ColorGrid envs from one seat, the other agents played by ``partners``, stepped as one batch.

    Autoreset is Gymnasium's ``SAME_STEP`` (declared in ``metadata``): the step that ends an episode returns
    the next episode's first observation, with the ended one's last in ``infos["final_obs"]`` (an object
    array, ``None`` where no episode ended; mask ``infos["_final_obs"]``) and its seat's totals in
    ``infos["final_info"]``. Env ``i`` of a batch reset with ``seed=s`` runs as ``SeatEnv`` reset with
    ``seed=s + i``, partners included where they draw no random numbers (A*, the oracle): a scripted policy
    that wanders at random draws for its whole batch at once, so its draws depend on the batch.
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": list(RENDER_MODES), "render_fps": 5}

    def __init__(self, num_envs: int = 1, seat: str = "follower", partners: str | Mapping[str, str] | None = None,
                 config: EnvConfig | None = None, flatten: bool = False, render_mode: str | None = None,
                 autoreset: bool = True, **overrides):
        if render_mode is not None and render_mode not in RENDER_MODES:
            raise ValueError(f"render_mode must be one of {list(RENDER_MODES)} or None, got {render_mode!r}")
        config = config if config is not None else EnvConfig()
        self.config = config.replace(**overrides) if overrides else config
        self.seat = seat_index(self.config, seat)
        self.seat_name = seat
        self.flatten, self.render_mode = bool(flatten), render_mode
        self.num_envs = num_envs
        self.batch = BatchEnv(self.config, num_envs=num_envs, autoreset=autoreset)
        self.partners = {i: make_policy(spec, role=self.config.roles[i])
                         for i, spec in partner_specs(self.config, self.seat, partners).items()}
        cfg = self.config
        self._self_plane = not cfg.one_to_one  # as the PettingZoo view: the observer's own cell, again, last
        planes = cfg.num_planes + self._self_plane
        if self.flatten:
            size = planes * cfg.height * cfg.width + cfg.num_colors
            self.single_observation_space = spaces.Box(0.0, 1.0, (size,), dtype=np.float32)
        else:
            self.single_observation_space = spaces.Dict({
                "observation": spaces.Box(0, 1, (planes, cfg.height, cfg.width), dtype=np.uint8),
                "goal_info": spaces.Box(0.0, 1.0, (cfg.num_colors,), dtype=np.float32),
            })
        self.single_action_space = spaces.Discrete(cfg.num_actions)
        self.observation_space = gymnasium.vector.utils.batch_space(self.single_observation_space, num_envs)
        self.action_space = spaces.MultiDiscrete(np.full(num_envs, cfg.num_actions))
        self.metadata = {**self.metadata, "name": cfg.env_id}
        self._obs: dict | None = None
        self._last: StepInputs | None = None

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode in every env (env ``i`` seeded ``seed + i``); a seed also reseeds the partners.

        Without a seed each env's next episode is the one its autoreset would start (its seed derived from
        the current episode's, as ``BatchEnv`` does), so an unseeded reset after a seeded one is reproducible;
        the very first unseeded reset draws from ``np_random``."""
        super().reset(seed=seed)
        first = self.batch.state is None
        if seed is not None:
            seeds = int(seed)
        elif first:
            seeds = int(self.np_random.integers(0, 2**32))
        else:
            seeds = rng.next_episode_seed(self.batch.state.seed)
        self._obs, info = self.batch.reset(seed=seeds)
        if seed is not None or first:
            for i, policy in self.partners.items():
                policy.reset(self.config, self.num_envs, i, seed=int(info["seed"][0]))
        self._last = StepInputs.begin(self.config, self.num_envs)
        return self._observation(self._obs), {"seed": info["seed"], "goal_color": info["goal_color"]}

    def step(self, actions):
        """The seat's actions ``[num_envs]``; the partners act on the same observations."""
        if self._last is None:
            raise RuntimeError("call reset() before step()")
        mine = np.asarray(actions, dtype=np.int64).reshape(-1)
        if mine.shape != (self.num_envs,):
            raise ValueError(f"expected {self.num_envs} actions (one per env), got shape {np.shape(actions)}")
        joint = np.zeros((self.num_envs, self.config.num_agents), dtype=np.int64)
        joint[:, self.seat] = mine
        goal = self.batch.state.goal.copy()
        for i, policy in self.partners.items():
            joint[:, i] = policy.act(self._last.agent_input(self._obs, i, self.batch.penalty_coef, goal)).actions
        self._obs, rewards, terms, truncs, info = self.batch.step(joint)
        done = terms.any(axis=1) | truncs.any(axis=1)
        self._last.record(joint, info, done if done.any() else None)
        s = self.seat
        infos = {"block_reward": info["block_reward"][:, s].copy(), "team_reward": info["team_reward"].copy(),
                 "goal_pickup": info["goal_pickup"][:, s].copy(), "wrong_pickup": info["wrong_pickup"][:, s].copy(),
                 "goal_color": info["goal_color"].copy()}
        if done.any() and self.batch.autoreset:
            final = self._observation(info["final_obs"])
            infos["final_obs"] = np.full(self.num_envs, None, dtype=object)
            for e in np.flatnonzero(done):
                infos["final_obs"][e] = ({k: v[e] for k, v in final.items()} if isinstance(final, dict)
                                         else final[e])
            infos["_final_obs"] = done.copy()
        if done.any():
            totals = info["final_info"]
            infos["final_info"] = {
                "episode_block_reward": np.where(done, totals["episode_block_reward"][:, s], 0.0),
                "episode_goal_pickups": np.where(done, totals["episode_goal_pickups"][:, s], 0),
                "episode_wrong_pickups": np.where(done, totals["episode_wrong_pickups"][:, s], 0),
            }
            infos["final_info"].update({f"_{k}": done.copy() for k in list(infos["final_info"])})
            infos["_final_info"] = done.copy()
        return (self._observation(self._obs), rewards[:, s].astype(np.float32), terms[:, s].copy(),
                truncs[:, s].copy(), infos)

    def render(self):
        """Env 0 as an RGB frame or ANSI text (``render_mode``)."""
        if self.render_mode is None or self.batch.state is None:
            return None
        if self.render_mode == "rgb_array":
            return render_rgb(self.batch.state, self.config)
        return render_ansi(self.batch.state, self.config, color=False)

    def _observation(self, obs: dict):
        """The seat's view of batched observations: the Dict, or the flattened Box."""
        return seat_view(obs["observation"], obs["goal_info"], self.seat, self.config.num_colors, self._self_plane,
                         self.flatten)


class SeatEnv(gymnasium.Env):
    """One ColorGrid env from one seat (``SeatVectorEnv`` of one env, without autoreset): a ``gymnasium.Env``."""

    metadata = {"render_modes": list(RENDER_MODES), "render_fps": 5}

    def __init__(self, seat: str = "follower", partners: str | Mapping[str, str] | None = None,
                 config: EnvConfig | None = None, flatten: bool = False, render_mode: str | None = None,
                 **overrides):
        self.vector = SeatVectorEnv(1, seat, partners, config, flatten, render_mode, autoreset=False, **overrides)
        self.config, self.render_mode = self.vector.config, render_mode
        self.observation_space = self.vector.single_observation_space
        self.action_space = self.vector.single_action_space
        self.metadata = {**self.metadata, "name": self.config.env_id}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        obs, info = self.vector.reset(seed=seed)
        return _first(obs), {"seed": int(info["seed"][0]), "goal_color": int(info["goal_color"][0])}

    def step(self, action):
        """One step; the step that ends the episode also reports the seat's episode totals (``episode_*``)."""
        obs, reward, term, trunc, info = self.vector.step(np.array([action]))
        # the vector env's masks ("_final_info", "_episode_*") are its own: Gymnasium reserves "_"-prefixed keys
        # for vector envs, which add them when they batch a single env's infos
        out = {k: v[0].item() for k, v in info.items() if k != "final_info" and not k.startswith("_")}
        out.update({k: v[0].item() for k, v in info.get("final_info", {}).items() if not k.startswith("_")})
        return _first(obs), float(reward[0]), bool(term[0]), bool(trunc[0]), out

    def render(self):
        return self.vector.render()


def _first(obs):
    return {k: v[0] for k, v in obs.items()} if isinstance(obs, dict) else obs[0]


def gym_env(seat: str = "follower", partners: str | Mapping[str, str] | None = None,
            config: EnvConfig | None = None, flatten: bool = False, render_mode: str | None = None,
            **overrides) -> SeatEnv:
    """A ``gymnasium.Env`` of one seat, e.g. ``gym_env(seat="follower", partners="population:people#training")``;
    ``overrides`` are EnvConfig fields applied on top of ``config``."""
    return SeatEnv(seat, partners, config, flatten, render_mode, **overrides)


def gym_vector_env(num_envs: int, seat: str = "follower", partners: str | Mapping[str, str] | None = None,
                   config: EnvConfig | None = None, flatten: bool = False, render_mode: str | None = None,
                   **overrides) -> SeatVectorEnv:
    """A ``gymnasium.vector.VectorEnv`` of ``num_envs`` envs of one seat, stepped as one ``BatchEnv``."""
    return SeatVectorEnv(num_envs, seat, partners, config, flatten, render_mode, **overrides)


def register() -> None:
    """``gymnasium.make(GYM_ID, seat=..., partners=...)`` and ``gymnasium.make_vec(GYM_ID, num_envs=...)``."""
    if GYM_ID not in gymnasium.registry:
        gymnasium.register(GYM_ID, entry_point="colorgrid.gym_env:SeatEnv",
                           vector_entry_point="colorgrid.gym_env:SeatVectorEnv",
                           max_episode_steps=None, disable_env_checker=False)
