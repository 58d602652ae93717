"""Turning replays back into states: re-simulation, verification, frames; recording a batch as replays."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from colorgrid.env import BatchEnv
from colorgrid.replay.blocks import decode_blocks
from colorgrid.replay.format import Replay, ReplayError
from colorgrid.rollout import EpisodeBatch
from colorgrid.state import EnvState


def replay_states(replay: Replay, path=None) -> list[EnvState]:
    """The ``T + 1`` states of the episode (batch-of-one ``EnvState`` each)."""
    if replay.kind == "frames":
        return [frame_state(replay, t) for t in range(replay.num_steps + 1)]
    env = BatchEnv(replay.config, num_envs=1, seed=replay.seed, autoreset=False)
    env.reset()
    env.penalty_coef = replay.penalty_coef
    states = [env.state.copy()]
    for t, action in enumerate(replay.actions):
        try:
            env.step(np.array([action], dtype=np.int64))
        except (ValueError, RuntimeError) as err:
            raise ReplayError(path, f"step {t} cannot be simulated: {err}") from None
        states.append(env.state.copy())
    return states


@dataclass
class Verification:
    ok: bool
    message: str
    first_bad_step: int | None = None


def verify(replay: Replay, path=None, states: list[EnvState] | None = None) -> Verification:
    """Re-simulate and compare every state hash; reports the first step that differs.

    ``states``: the replay's states if the caller already simulated them (``replay_states``).
    """
    if replay.kind == "frames":
        return Verification(True, "ok (frames replay: states are stored, nothing to re-simulate)")
    if replay.state_hashes is None:
        return Verification(False, "no state hashes stored: cannot verify")
    states = states if states is not None else replay_states(replay, path)
    for t, (state, expected) in enumerate(zip(states, replay.state_hashes)):
        got = state.state_hash(0)
        if got != expected:
            what = "the initial state" if t == 0 else f"the state after step {t - 1}"
            return Verification(False, f"state hash mismatch at step {t} ({what}): file has {expected}, "
                                       f"re-simulation gives {got}", t)
    final = replay.final()
    for i, name in enumerate(replay.config.agent_names):
        if f"{name}_score" in final and abs(float(states[-1].score[0, i]) - final[f"{name}_score"]) > 1e-6:
            return Verification(False, f"{name} score differs from re-simulation", len(states) - 1)
    return Verification(True, "ok")


def frame_state(replay: Replay, t: int) -> EnvState:
    """State ``t`` of a frames replay, rebuilt from the stored cells."""
    cfg, frames = replay.config, replay.frames
    colors = decode_blocks(frames["blocks"][t])
    block_cells = np.concatenate([np.flatnonzero(colors == k) for k in range(cfg.num_colors)])
    block_at = np.full(cfg.height * cfg.width, -1, dtype=np.int32)
    # Blocks are numbered color by color, so block j has color j // blocks_per_color when counts match.
    block_at[block_cells] = np.arange(block_cells.size)
    goal = frames["goal"][t]
    return EnvState(
        seed=np.zeros(1, dtype=np.uint64), t=np.array([t]), goal=np.array([goal]),
        agent_cell=np.array([frames["agent_cell"][t]], dtype=np.int64),
        block_cell=block_cells[None, :], block_at=block_at.reshape(1, cfg.height, cfg.width),
        score=np.zeros((1, cfg.num_agents)), goal_pickups=np.zeros((1, cfg.num_agents), dtype=np.int64),
        wrong_pickups=np.zeros((1, cfg.num_agents), dtype=np.int64),
    )


def from_batch(batch: EpisodeBatch, agents: dict, source: str, penalty_coef: float = 1.0,
               meta: dict | None = None) -> list[Replay]:
    """One replay per episode of a recorded batch (``run_episodes(..., record_hashes=True)``)."""
    replays = []
    for e in range(batch.num_episodes):
        probs = {name: batch.goal_probs[i][:, e].round(5).tolist()
                 for i, name in enumerate(batch.config.agent_names) if batch.goal_probs[i] is not None}
        replays.append(Replay(
            config=batch.config, seed=int(batch.seeds[e]), source=source, agents=agents,
            actions=batch.actions[:, e].tolist(), goal=batch.goal[:, e].tolist(),
            block_reward=batch.block_reward[:, e].tolist(), team_reward=batch.team_reward[:, e].tolist(),
            picked_color=batch.picked_color[:, e].tolist(), goal_switched=batch.goal_switched[:, e].tolist(),
            goal_probs=probs,
            state_hashes=list(batch.state_hashes[:, e]) if batch.state_hashes is not None else None,
            penalty_coef=penalty_coef, meta=dict(meta or {}),
        ))
    return replays

