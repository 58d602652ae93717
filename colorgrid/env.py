"""The batched ColorGrid environment: the one implementation of the rules.

Every other view (the PettingZoo env, replays, the play server) steps this class.
The rules it implements are in ``docs/ENV_CARD.md``; a summary:

* moves resolve leader first; off-grid (or out-of-half) moves and moves onto the
  other agent's current cell are blocked, so agents never overlap or swap;
* then each agent, leader first, collects the block on its cell: ``+goal_reward``
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
from colorgrid.config import AGENTS, EnvConfig
from colorgrid.generator import initial_layout
from colorgrid.state import EnvState

# Row and column change per action: up, down, left, right, stay.
ACTION_DELTAS = np.array([[-1, 0], [1, 0], [0, -1], [0, 1], [0, 0]], dtype=np.int64)
ACTION_NAMES = ("up", "down", "left", "right", "stay")
_MAX_RESPAWN_ATTEMPTS = 1_000_000
_PROPOSALS = 4  # respawn proposals drawn per pass; 4 make a second pass rare at 10% density


class BatchEnv:
    """``num_envs`` ColorGrid environments stepped together with array operations.

    Env ``i`` of a batch reset with ``seed=s`` runs exactly like a single env
    (``num_envs=1``) reset with ``seed=s + i``.

    Observations (returned by ``reset`` and ``step``) are a dict:
      ``"observation"``: uint8 ``[B, num_colors + 2, H, W]``, shared by both agents
      (one 0/1 plane per color, then leader, then follower). It is the env's own
      buffer, updated in place by the next step: copy it if you keep it.
      ``"goal_info"``: float32 ``[B, A, num_colors]``, one-hot goal per agent
      (zeros for the follower when ``asymmetric``).
    Rewards, terminations and truncations are ``[B, A]`` arrays, agents in the
    order of ``config.AGENTS`` (leader, follower).
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

        actions: int ``[B, A]`` (leader, follower), values in ``[0, num_actions)``.
        Returns ``(observations, rewards [B, A] float32, terminations [B, A],
        truncations [B, A], infos)``; see the module docstring for autoreset.
        """
        if self.state is None:
            raise RuntimeError("call reset() before step()")
        cfg, s = self.config, self.state
        actions = self._check_actions(actions)
        if self._needs_reset.any():
            raise RuntimeError("an episode has ended and autoreset is off: call reset() before step()")
        step_index = s.t + 1  # this step's number in its episode, 1..horizon

        self._move_agents(actions)
        block_reward, picked_color, goal_hit = self._collect_blocks(step_index)
        team_reward = block_reward.sum(axis=1)
        if cfg.reward_mode == "shared":
            rewards = np.repeat(team_reward[:, None], cfg.num_agents, axis=1)
        else:
            rewards = block_reward.copy()
        distance_term = self._distance_shaping()
        potential_term = self._potential_shaping()
        rewards = (rewards + distance_term + potential_term).astype(np.float32)

        s.t += 1
        switched = self._switch_goals(step_index)
        truncations = np.repeat((s.t >= cfg.horizon)[:, None], cfg.num_agents, axis=1)
        terminations = np.zeros_like(truncations)
        infos = {
            "block_reward": block_reward.astype(np.float32),  # [B, A], unshaped
            "team_reward": team_reward.astype(np.float32),  # [B], unshaped
            "picked_color": picked_color,  # [B, A] int64, -1 if nothing collected
            "goal_pickup": (picked_color >= 0) & goal_hit,  # [B, A] bool
            "wrong_pickup": (picked_color >= 0) & ~goal_hit,  # [B, A] bool
            "distance_shaping": distance_term.astype(np.float32),  # [B, A]
            "potential_shaping": potential_term.astype(np.float32),  # [B, A]
            "goal_color": s.goal.copy(),  # [B], after this step's switch
            "goal_switched": switched,  # [B] bool
            "penalty_coef": self._penalty_coef,
            "step": s.t.copy(),  # [B]
        }
        if switched.any():
            self._refresh_goal_info(self._envs[switched])
        done = truncations[:, 0]
        if done.any():
            self._end_episodes(done, infos)
        return self._observations(), rewards, terminations, truncations, infos

    # ------------------------------------------------------------- dynamics
    def _move_agents(self, actions: np.ndarray) -> None:
        """Resolve moves in agent order; each agent is blocked by the others' current cells."""
        s, cfg = self.state, self.config
        HW = self._cells_per_env
        # Sequential by rule (leader first, follower against the leader's new cell):
        # a loop over the (two) agents, vectorised over the batch.
        for a in range(cfg.num_agents):
            old = s.agent_cell[:, a]
            new = self._move_table[a, old, actions[:, a]]  # walls and halves already applied
            for b in range(cfg.num_agents):
                if b != a:
                    new = np.where(new == s.agent_cell[:, b], old, new)
            plane = self._obs_base + (cfg.num_colors + a) * HW
            self._obs_flat[plane + old] = 0  # clear the old cell, then mark the new one (may be the same)
            self._obs_flat[plane + new] = 1
            s.agent_cell[:, a] = new

    def _collect_blocks(self, step_index: np.ndarray):
        """Each agent, leader first, collects the block on its cell; it respawns at once."""
        s, cfg = self.state, self.config
        B, A, HW = self.num_envs, cfg.num_agents, self._cells_per_env
        block_reward = np.zeros((B, A), dtype=np.float64)
        picked_color = np.full((B, A), -1, dtype=np.int64)
        goal_hit = np.zeros((B, A), dtype=bool)
        block_at_flat = s.block_at.reshape(-1)
        if not (block_at_flat[self._env_base[:, None] + s.agent_cell] >= 0).any():
            return block_reward, picked_color, goal_hit
        for a in range(A):  # sequential by rule: the leader's block respawns before the follower collects
            where = self._env_base + s.agent_cell[:, a]
            block = block_at_flat[where]
            picked = block >= 0
            if not picked.any():
                continue
            e = self._envs[picked]
            j = block[picked].astype(np.int64)
            color = self._block_color[j]
            hit = color == s.goal[e]
            picked_color[e, a] = color
            goal_hit[e, a] = hit
            reward = np.where(hit, cfg.goal_reward, -cfg.wrong_penalty * self._penalty_coef)
            block_reward[e, a] = reward
            s.score[e, a] += reward
            s.goal_pickups[e, a] += hit
            s.wrong_pickups[e, a] += ~hit
            cell = s.agent_cell[e, a]
            block_at_flat[where[picked]] = -1
            self._obs_flat[self._obs_base[e] + color * HW + cell] = 0
            self._respawn(e, j, color, cell, step_index[e], a)
        return block_reward, picked_color, goal_hit

    def _respawn(self, envs, blocks, colors, collected_cell, step_index, agent: int) -> None:
        """Put blocks back on uniformly drawn free cells (rejection sampling, exact).

        Proposal ``k`` is a uniform cell (of the block's half in hemisphere mode);
        the first proposal that holds no block and no agent is taken. Proposals are
        drawn ``_PROPOSALS`` at a time, which gives the same result as drawing them
        one by one. Validation guarantees a free cell exists.
        """
        s, cfg = self.state, self.config
        H, W, HW = cfg.height, cfg.width, self._cells_per_env
        span = W // 2 if cfg.hemispheres else W
        lo = np.where(collected_cell % W >= span, span, 0) if cfg.hemispheres else 0
        block_at_flat = s.block_at.reshape(-1)
        todo = np.arange(envs.shape[0])
        attempts = np.arange(_PROPOSALS)
        for first in range(0, _MAX_RESPAWN_ATTEMPTS, _PROPOSALS):
            e = envs[todo]
            draw = rng.below(s.seed[e][:, None], H * span, step_index[todo][:, None], rng.STREAM_RESPAWN,
                             first + attempts[None, :], agent)  # [n, K]
            r, c = np.divmod(draw, span)
            cell = r * W + c + (lo[todo][:, None] if cfg.hemispheres else 0)
            free = block_at_flat[self._env_base[e][:, None] + cell] < 0
            for a in range(cfg.num_agents):
                free &= cell != s.agent_cell[e, a][:, None]
            found = free.any(axis=1)
            if found.any():
                k = free.argmax(axis=1)[found]
                ef, jf = e[found], blocks[todo[found]]
                cf = cell[found, k]
                block_at_flat[self._env_base[ef] + cf] = jf
                s.block_cell[ef, jf] = cf
                self._obs_flat[self._obs_base[ef] + colors[todo[found]] * HW + cf] = 1
                todo = todo[~found]
                if todo.size == 0:
                    return
        raise RuntimeError("respawn found no free cell; EnvConfig validation should prevent this")

    def _distance_shaping(self) -> np.ndarray:
        """[B, A]: ``-distance_penalty`` for listed agents within ``distance_threshold`` of the other."""
        cfg = self.config
        term = np.zeros((self.num_envs, cfg.num_agents), dtype=np.float64)
        if cfg.distance_penalty == 0 or not cfg.distance_penalty_agents:
            return term
        pos = self.state.agent_pos
        close = np.abs(pos[:, 0] - pos[:, 1]).sum(axis=-1) <= cfg.distance_threshold
        for name in cfg.distance_penalty_agents:
            term[:, AGENTS.index(name)] = np.where(close, -cfg.distance_penalty, 0.0)
        return term

    def _potential_shaping(self) -> np.ndarray:
        """[B, A]: ``scale * (sum 1/(d+1) over goal blocks - wrong_penalty * sum over others)``."""
        cfg, s = self.config, self.state
        if not cfg.potential_shaping:
            return np.zeros((self.num_envs, cfg.num_agents), dtype=np.float64)
        d = np.abs(s.block_pos[:, None, :, :] - s.agent_pos[:, :, None, :]).sum(axis=-1)  # [B, A, N] Manhattan
        closeness = 1.0 / (d + 1.0)
        is_goal = (self._block_color[None, :] == s.goal[:, None])[:, None, :]  # [B, 1, N]
        weight = np.where(is_goal, 1.0, -cfg.wrong_penalty)
        return cfg.potential_scale * (closeness * weight).sum(axis=-1)

    def _switch_goals(self, step_index: np.ndarray) -> np.ndarray:
        """[B] bool: envs whose goal switched, uniformly to one of the other colors."""
        cfg, s = self.config, self.state
        if cfg.switch_prob == 0:
            return np.zeros(self.num_envs, dtype=bool)
        switched = rng.uniform(s.seed, step_index, rng.STREAM_SWITCH) < cfg.switch_prob
        if switched.any():
            e = self._envs[switched]
            offset = 1 + rng.below(s.seed[e], cfg.num_colors - 1, step_index[e], rng.STREAM_SWITCH_COLOR)
            s.goal[e] = (s.goal[e] + offset) % cfg.num_colors
        return switched

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
        gi = self._goal_info
        gi[envs] = 0
        goal = self.state.goal[envs]
        gi[envs, 0, goal] = 1.0
        if not self.config.asymmetric:
            gi[envs, 1, goal] = 1.0

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
        actions = np.asarray(actions)
        expected = (self.num_envs, self.config.num_agents)
        if actions.shape != expected:
            raise ValueError(f"actions must have shape {expected} (envs, agents), got {actions.shape}")
        if actions.dtype.kind not in "iu":
            raise ValueError(f"actions must be integers, got dtype {actions.dtype}")
        n = self.config.num_actions
        if actions.size and (actions.min() < 0 or actions.max() >= n):
            raise ValueError(
                f"actions must be in [0, {n}) ({', '.join(ACTION_NAMES[:n])}); got values from "
                f"{actions.min()} to {actions.max()}" + ("" if n == 5 else "; set allow_stay=True for 4 (stay)")
            )
        return actions.astype(np.int64, copy=False)


def move_table(config: EnvConfig) -> np.ndarray:
    """[A, H*W, num_actions] int64: the cell each action leads to, per agent.

    Walls (and the agent's half in hemisphere mode) are applied here: a move that
    would leave the allowed area maps to the same cell. Blocking by the other
    agent depends on the state and is applied in ``step``.
    """
    H, W = config.height, config.width
    rows, cols = np.divmod(np.arange(H * W), W)
    table = np.empty((config.num_agents, H * W, config.num_actions), dtype=np.int64)
    for a in range(config.num_agents):
        lo, hi = (0, W) if not config.hemispheres else ((0, W // 2) if a == 0 else (W // 2, W))
        for k in range(config.num_actions):
            r, c = rows + ACTION_DELTAS[k, 0], cols + ACTION_DELTAS[k, 1]
            inside = (r >= 0) & (r < H) & (c >= lo) & (c < hi)
            table[a, :, k] = np.where(inside, r * W + c, rows * W + cols)
    return table
