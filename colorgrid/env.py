"""The batched ColorGrid environment: the one implementation of the rules.

Every other view (the PettingZoo env, replays, the play server) steps this class.
The dynamics of a step run in one compiled function (``colorgrid/kernel.py``); this
class holds the state, checks inputs, builds infos and handles episodes. The rules are
in ``docs/ENV_CARD.md``; a summary:

* moves resolve in agent order (the leaders, then the followers; 1:1: leader first);
  off-grid (or out-of-half) moves and moves onto another agent's cell (its new cell if it
  has moved, else its current one) are blocked, so agents never overlap or swap;
* then each agent, in the same order, collects the block on its cell: ``+goal_reward``
  for the goal color, ``-wrong_penalty * penalty_coef`` otherwise; the block
  respawns at once, same color, on a uniformly drawn cell with no block and no
  agent (in hemisphere mode, in the half it was collected in);
* after rewards the goal switches with probability ``switch_prob`` to one of the
  other colors, uniformly;
* after ``horizon`` steps every agent is truncated.

Autoreset: **same-step** (Gymnasium 1.x ``AutoresetMode.SAME_STEP``). When an
episode ends, ``step`` returns the first observation of the next episode, the
last observation of the ended one in ``infos["final_obs"]`` (with the mask
``infos["_final_obs"]``) and its totals in ``infos["final_info"]``. The next
episode's seed is derived from the ended one's (``rng.next_episode_seed``), so
every episode is reproducible from its own seed. Pass ``autoreset=False`` to
stop instead: stepping an ended env then raises.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from colorgrid import rng
from colorgrid.config import EnvConfig
from colorgrid.generator import initial_layout
from colorgrid import kernel
from colorgrid.kernel import step_kernel
from colorgrid.roles import columns
from colorgrid.state import EnvState

# Row and column change per action: up, down, left, right, stay.
ACTION_DELTAS = np.array([[-1, 0], [1, 0], [0, -1], [0, 1], [0, 0]], dtype=np.int64)
ACTION_NAMES = ("up", "down", "left", "right", "stay")


class BatchEnv:
    """``num_envs`` ColorGrid environments stepped together with array operations.

    Env ``i`` of a batch reset with ``seed=s`` runs exactly like a single env
    (``num_envs=1``) reset with ``seed=s + i``.

    Observations (returned by ``reset`` and ``step``) are a dict:
      ``"observation"``: uint8 ``[B, num_colors + A, H, W]``, shared by every agent
      (one 0/1 plane per color, then one per agent in index order: 1:1 leader, follower).
      It is the env's own buffer, updated in place by the next step: copy it if you keep it.
      ``"goal_info"``: float32 ``[B, A, num_colors]``, one-hot goal per agent
      (zeros for the followers when ``asymmetric``).
    Rewards, terminations and truncations are ``[B, A]`` arrays, agents in index
    order (``config.agent_names``: the leaders, then the followers).
    """

    def __init__(self, config: EnvConfig | None = None, num_envs: int = 1, seed: int | None = None,
                 autoreset: bool = True):
        if isinstance(num_envs, bool) or not isinstance(num_envs, int) or num_envs < 1:
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        self.config = config if config is not None else EnvConfig()
        if not isinstance(self.config, EnvConfig):
            raise TypeError(f"config must be an EnvConfig, got {type(self.config).__name__}")
        self.num_envs = num_envs
        self.autoreset = autoreset
        self._penalty_coef = float(self.config.penalty_coef)
        cfg = self.config
        B, A, H, W = num_envs, cfg.num_agents, cfg.height, cfg.width
        self._obs = np.zeros((B, cfg.num_planes, H, W), dtype=np.uint8)
        self._obs_flat = self._obs.reshape(-1)  # a view, for flat-index updates on the hot path
        self._goal_info = np.zeros((B, A, cfg.num_colors), dtype=np.float32)
        self._envs = np.arange(B)
        self._cells_per_env = H * W
        self._env_base = self._envs * (H * W)  # offset of each env in flat [B, H, W] arrays
        self._obs_base = self._envs * (cfg.num_planes * H * W)  # same for [B, P, H, W]
        self._move_table = move_table(cfg)
        self._block_color = np.arange(cfg.num_blocks) // cfg.blocks_per_color
        self._obs_cells = self._obs.reshape(B, cfg.num_planes, H * W)  # a view, for the compiled step
        self._params = kernel.pack(cfg, self._penalty_coef)
        self._needs_reset = np.ones(B, dtype=bool)
        self.state: EnvState | None = None
        self._pending_seed = seed

    # ------------------------------------------------------------------ API
    @property
    def penalty_coef(self) -> float:
        """Current wrong-block penalty coefficient (settable between steps, for annealing)."""
        return self._penalty_coef

    @penalty_coef.setter
    def penalty_coef(self, value: float) -> None:
        value = float(value)
        if not np.isfinite(value) or value < 0:
            raise ValueError(f"penalty_coef must be a finite number >= 0, got {value!r}")
        self._penalty_coef = value
        self._params["penalty_coef"] = value

    def reset(self, seed: int | Sequence[int] | None = None):
        """Start a new episode in every env; returns ``(observations, infos)``.

        ``seed``: an int ``s`` seeds env ``i`` with ``s + i``; a sequence gives one
        seed per env; ``None`` uses the seed given to the constructor the first
        time and fresh operating-system entropy afterwards.
        """
        if seed is None:
            seed, self._pending_seed = self._pending_seed, None
        if seed is None:
            seed = rng.fresh_seed()
        seeds = self._seed_array(seed)
        B, A = self.num_envs, self.config.num_agents
        N, H, W = self.config.num_blocks, self.config.height, self.config.width
        self.state = EnvState(
            seed=seeds,
            t=np.zeros(B, dtype=np.int64),
            goal=np.zeros(B, dtype=np.int64),
            agent_cell=np.zeros((B, A), dtype=np.int64),
            block_cell=np.zeros((B, N), dtype=np.int64),
            block_at=np.full((B, H, W), -1, dtype=np.int32),
            score=np.zeros((B, A), dtype=np.float64),
            goal_pickups=np.zeros((B, A), dtype=np.int64),
            wrong_pickups=np.zeros((B, A), dtype=np.int64),
        )
        self._reset_envs(self._envs, seeds)
        return self._observations(), {"seed": seeds.copy(), "goal_color": self.state.goal.copy()}

    def load_state(self, state: EnvState) -> dict:
        """Replace the whole batch's state (e.g. a hand-built or replayed one); returns observations.

        ``state`` must have this env's batch size and shapes; it is copied.
        """
        if self.state is None:
            self.reset(seed=0)
        for name in ("agent_cell", "block_cell", "block_at"):
            want, got = getattr(self.state, name).shape, getattr(state, name).shape
            if want != got:
                raise ValueError(f"state.{name} has shape {got}, this env needs {want}")
        self.state = state.copy()
        HW = self._cells_per_env
        self._obs[:] = 0
        block_colors = self.state.block_colors(self.config).reshape(self.num_envs, -1)
        envs, cells = np.nonzero(block_colors >= 0)
        self._obs_flat[self._obs_base[envs] + block_colors[envs, cells] * HW + cells] = 1
        for a in range(self.config.num_agents):
            self._obs_flat[self._obs_base + (self.config.num_colors + a) * HW + self.state.agent_cell[:, a]] = 1
        self._refresh_goal_info(self._envs)
        self._needs_reset[:] = self.state.t >= self.config.horizon
        return self._observations()

    def step(self, actions):
        """Advance every env one step.

        actions: int ``[B, A]`` (agents in index order), values in ``[0, num_actions)``.
        Returns ``(observations, rewards [B, A] float32, terminations [B, A],
        truncations [B, A], infos)``; see the module docstring for autoreset.
        """
        if self.state is None:
            raise RuntimeError("call reset() before step()")
        cfg, s = self.config, self.state
        actions = self._check_actions(actions)
        if not self.autoreset and self._needs_reset.any():
            raise RuntimeError("an episode has ended and autoreset is off: call reset() before step()")
        B, A = self.num_envs, cfg.num_agents
        fout = np.empty((5, B, A), dtype=np.float32)
        picked_color = np.empty((B, A), dtype=np.int64)
        bout = np.empty((4, B, A), dtype=np.bool_)
        switched = np.empty(B, dtype=np.bool_)
        code = step_kernel(actions, s.agent_cell, s.block_at.reshape(B, -1), s.block_cell, self._block_color, s.goal,
                           s.t, s.seed, s.score, s.goal_pickups, s.wrong_pickups, self._obs_cells, self._goal_info,
                           self._move_table, self._params, fout, picked_color, bout, switched)
        if code == kernel.BAD_ACTION:
            self._check_action_values(actions)
        if code == kernel.NO_FREE_CELL:
            raise RuntimeError("respawn found no free cell; EnvConfig validation should prevent this")
        rewards, truncations, terminations = fout[kernel.O_REWARD], bout[kernel.O_TRUNCATED], bout[kernel.O_TERMINATED]
        infos = {
            "block_reward": fout[kernel.O_BLOCK],  # [B, A] float32, unshaped
            "team_reward": fout[kernel.O_TEAM, :, 0],  # [B], unshaped (the same in every agent's column)
            "picked_color": picked_color,  # [B, A] int64, -1 if nothing collected
            "goal_pickup": bout[kernel.O_GOAL_PICKUP],  # [B, A] bool
            "wrong_pickup": bout[kernel.O_WRONG_PICKUP],  # [B, A] bool
            "distance_shaping": fout[kernel.O_DISTANCE],  # [B, A] float32
            "potential_shaping": fout[kernel.O_POTENTIAL],  # [B, A] float32
            "goal_color": s.goal.copy(),  # [B], after this step's switch
            "goal_switched": switched,  # [B] bool
            "penalty_coef": self._penalty_coef,
            "step": s.t.copy(),  # [B]
        }
        done = truncations[:, 0]  # every agent's episode ends at once: any agent's column tells
        if done[0] if B == 1 else done.any():
            self._end_episodes(done, infos)
        return self._observations(), rewards, terminations, truncations, infos

    # ------------------------------------------------------ episodes, obs
    def _reset_envs(self, envs: np.ndarray, seeds: np.ndarray) -> None:
        """Lay out new episodes with ``seeds`` in ``envs`` and rebuild their observations."""
        s, cfg = self.state, self.config
        HW = self._cells_per_env
        agent_cell, block_cell, goal = initial_layout(cfg, seeds)
        s.seed[envs] = seeds
        s.t[envs] = 0
        s.goal[envs] = goal
        s.agent_cell[envs] = agent_cell
        s.block_cell[envs] = block_cell
        s.score[envs] = 0
        s.goal_pickups[envs] = 0
        s.wrong_pickups[envs] = 0
        s.block_at[envs] = -1
        s.block_at.reshape(-1)[(self._env_base[envs][:, None] + block_cell).ravel()] = np.tile(
            np.arange(cfg.num_blocks), envs.shape[0])
        self._obs[envs] = 0
        obs_base = self._obs_base[envs][:, None]
        self._obs_flat[(obs_base + self._block_color[None, :] * HW + block_cell).ravel()] = 1
        agent_planes = (cfg.num_colors + np.arange(cfg.num_agents))[None, :] * HW
        self._obs_flat[(obs_base + agent_planes + agent_cell).ravel()] = 1
        self._refresh_goal_info(envs)
        self._needs_reset[envs] = False

    def _end_episodes(self, done: np.ndarray, infos: dict) -> None:
        s = self.state
        infos["_final_obs"] = done.copy()
        infos["final_obs"] = {"observation": self._obs.copy(), "goal_info": self._goal_info.copy()}
        infos["final_info"] = {
            "seed": s.seed.copy(),
            "episode_block_reward": s.score.copy(),  # [B, A]
            "episode_goal_pickups": s.goal_pickups.copy(),  # [B, A]
            "episode_wrong_pickups": s.wrong_pickups.copy(),  # [B, A]
            "episode_length": s.t.copy(),  # [B]
        }
        envs = self._envs[done]
        if self.autoreset:
            self._reset_envs(envs, rng.next_episode_seed(s.seed[envs]))
        else:
            self._needs_reset[envs] = True

    def _refresh_goal_info(self, envs: np.ndarray) -> None:
        kernel.write_goal_infos(self._goal_info, envs, self.state.goal, self._params[0]["sees_goal"])

    def _observations(self) -> dict:
        return {"observation": self._obs, "goal_info": self._goal_info}

    # -------------------------------------------------------------- checks
    def _seed_array(self, seed) -> np.ndarray:
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            seeds = int(seed) + np.arange(self.num_envs, dtype=object)
        else:
            seeds = np.asarray(list(seed), dtype=object)
            if seeds.shape != (self.num_envs,):
                raise ValueError(f"seed must be an int or a sequence of {self.num_envs} ints, got shape {seeds.shape}")
        if any(isinstance(x, bool) or not isinstance(x, (int, np.integer)) or not 0 <= int(x) <= rng.MAX_SEED
               for x in seeds):
            raise ValueError(f"seeds must be integers in [0, 2**63 - 1], got {seed!r}")
        return np.array([int(x) for x in seeds], dtype=np.uint64)

    def _check_actions(self, actions) -> np.ndarray:
        """Shape and dtype here; the compiled step checks the range before it changes anything."""
        if type(actions) is not np.ndarray or actions.dtype != np.int64:
            actions = np.asarray(actions)
            if actions.dtype.kind not in "iu":
                raise ValueError(f"actions must be integers, got dtype {actions.dtype}")
            actions = actions.astype(np.int64)
        if actions.shape != (self.num_envs, self.config.num_agents):
            raise ValueError(f"actions must have shape {(self.num_envs, self.config.num_agents)} (envs, agents), "
                             f"got {actions.shape}")
        return actions

    def _check_action_values(self, actions: np.ndarray) -> None:
        n = self.config.num_actions
        raise ValueError(
            f"actions must be in [0, {n}) ({', '.join(ACTION_NAMES[:n])}); got values from "
            f"{actions.min()} to {actions.max()}" + ("" if n == 5 else "; set allow_stay=True for 4 (stay)"))


def move_table(config: EnvConfig) -> np.ndarray:
    """[A, H*W, num_actions] int64: the cell each action leads to, per agent.

    Walls (and the agent's half in hemisphere mode) are applied here: a move that
    would leave the allowed area maps to the same cell. Blocking by other agents
    depends on the state and is applied in ``step``.
    """
    H, W = config.height, config.width
    rows, cols = np.divmod(np.arange(H * W), W)
    table = np.empty((config.num_agents, H * W, config.num_actions), dtype=np.int64)
    for a in range(config.num_agents):
        lo, hi = columns(config, a)
        for k in range(config.num_actions):
            r, c = rows + ACTION_DELTAS[k, 0], cols + ACTION_DELTAS[k, 1]
            inside = (r >= 0) & (r < H) & (c >= lo) & (c < hi)
            table[a, :, k] = np.where(inside, r * W + c, rows * W + cols)
    return table
