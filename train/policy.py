"""Trained networks behind the common ``Policy`` interface (evaluation, the play server, replays, frozen partners)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from colorgrid.config import EnvConfig
from colorgrid.env import move_table
from colorgrid.policies.base import AgentInput, Policy, PolicyOutput
from colorgrid.policies.grid import kept_off, unsure_moves
from train.acting import ACTING, check_min_belief, check_temperature
from train.inputs import step_tensors
from train.nets import ActorCritic


class NetPolicy(Policy):
    """Acts with an ``ActorCritic``; its goal probabilities are the auxiliary head's softmax.

    ``temperature`` is the acting temperature: actions are sampled from ``softmax(logits / temperature)``;
    1 (the default) samples as the network was trained, 0 takes the most likely action (greedy), values
    between sharpen the sampling. ``min_belief`` (0: off) keeps the agent off any block whose color its own
    belief (the goal head) gives less than that: such moves are taken out before sampling, unless every
    move is one. Keeps one recurrent state per env row, cleared at episode starts. A network shared by
    several agents plays any one of them (the one ``reset`` names).
    """

    avoids_moves = True

    def __init__(self, model: ActorCritic, name: str = "net", temperature: float = 1.0, source: str | None = None,
                 min_belief: float = 0.0):
        self.model = model
        self.name = name
        self.temperature = check_temperature(temperature, source or name)
        self.min_belief = check_min_belief(min_belief, source or name)
        self.source = source
        self.device = next(model.parameters()).device

    def reset(self, config: EnvConfig, num_envs: int, agent_index: int, seed: int = 0) -> None:
        super().reset(config, num_envs, agent_index, seed)
        check_compatible(self.model.env, config, self.source or self.name)
        if agent_index not in self.model.agents:
            trained = " or ".join(f"the {self.model.env.agent_names[a]}" for a in self.model.agents)
            raise ValueError(f"{self.source or self.name} was trained as {trained}, not the "
                             f"{config.agent_names[agent_index]}")
        self.state = self.model.initial_state(num_envs, self.device)
        self.generator = torch.Generator().manual_seed(int(seed) * 2 + agent_index)
        self.moves = move_table(config)[agent_index] if self.min_belief else None  # [H*W, actions]: where each leads

    def state_dict(self) -> dict:
        """The recurrent state and the sampling generator (the weights come from the checkpoint)."""
        return {"recurrent": None if self.state is None else [s.clone() for s in self.state],
                "generator": self.generator.get_state()}

    def load_state_dict(self, state: dict) -> None:
        if state["recurrent"] is not None:
            self.state = tuple(torch.as_tensor(s, device=self.device).clone() for s in state["recurrent"])
        self.generator.set_state(torch.as_tensor(state["generator"], dtype=torch.uint8))

    def act(self, inp: AgentInput, rows: np.ndarray | None = None) -> PolicyOutput:
        return self.act_avoiding(inp, rows, None)

    @torch.inference_mode()
    def act_avoiding(self, inp: AgentInput, rows: np.ndarray | None, avoid: np.ndarray | None) -> PolicyOutput:
        """``act``, with the moves ``avoid`` marks (``[B, actions]`` bool, or None) taken out before sampling beside
        those ``min_belief`` takes out, unless that would leave a row no move."""
        rows_idx = self._rows(rows)
        x = step_tensors(inp, self.model.env, self.agent_index, self.device,  # sized as the network was trained
                         progress=self.model.net.leader_progress)
        state = None
        if self.state is not None:
            state = (self.state[0][:, rows_idx], self.state[1][:, rows_idx])
        view = self.model.prepare(x["obs"], x["me"], self.model.identity((self.agent_index,), len(rows_idx),
                                                                          self.device))
        logits, _, goal_logits, new_state = self.model(view, x["goal"], x["extras"], x["starts"], state)
        if self.state is not None:
            self.state[0][:, rows_idx], self.state[1][:, rows_idx] = new_state
        logits = logits[0].cpu()
        probs = torch.softmax(goal_logits[0], dim=1).cpu().numpy().astype(np.float32)
        risky = None
        if self.min_belief:
            moves = self.moves[:, :logits.shape[1]]  # a network trained without ``stay`` never chooses it
            risky = unsure_moves(inp.observation, probs, moves, self.config, self.agent_index, self.min_belief)
        banned = kept_off(None if avoid is None else avoid[:, :logits.shape[1]], risky)  # the caller's first
        if banned is not None:
            logits = logits.masked_fill(torch.from_numpy(banned), -torch.inf)
        if self.temperature == 0:
            actions = logits.argmax(dim=1)
        else:
            chances = torch.softmax(logits if self.temperature == 1 else logits / self.temperature, dim=1)
            actions = torch.multinomial(chances, 1, generator=self.generator)[:, 0]
        return PolicyOutput(actions.numpy().astype(np.int64), probs)

    def describe(self) -> dict:
        d = {"policy": self.name, "arch": self.model.net.arch, "lstm": self.model.net.lstm}
        if self.temperature != 1:  # as trained is the default, and what replays without the field played
            d["temperature"] = self.temperature
        if self.min_belief:
            d["min_belief"] = self.min_belief
        if self.source:
            d["checkpoint"] = self.source
        return d


def check_compatible(trained: EnvConfig, wanted: EnvConfig, what: str) -> None:
    """A network fits an env with the same grid, colors and team, and the same actions or more.

    A network trained without ``stay`` may act where ``stay`` exists (the play server's
    real-time mode gives the leader one): it never chooses it, and a partner's ``stay`` shows
    in its last-action inputs as no move. The team's shape sets the number of agent planes
    and last-step inputs.
    """
    keys = ("height", "width", "num_colors", "num_leaders", "num_followers")
    diff = {k: (getattr(trained, k), getattr(wanted, k)) for k in keys if getattr(trained, k) != getattr(wanted, k)}
    if trained.allow_stay and not wanted.allow_stay:
        diff["allow_stay"] = (True, False)
    if diff:
        detail = ", ".join(f"{k}: trained {a!r}, requested {b!r}" for k, (a, b) in diff.items())
        raise ValueError(f"{what} does not fit this environment ({detail}); the network's input and output "
                         f"shapes depend on these fields")


def load_policy(path: str | Path, role: str | None = None, cache: "ModelCache | None" = None,
                **acting: float | None) -> NetPolicy:
    """A ``NetPolicy`` from a checkpoint: the network of ``role`` (see ``find_network``; default: the only
    trained one), acting with the settings ``acting`` (``train.acting.ACTING``: ``temperature``, ``min_belief``,
    see ``NetPolicy``); one not given, or None, is what the file stores, else its default (sampling as
    trained, every move allowed).

    With a ``cache`` the network comes from it (shared with other policies of the same file);
    each policy keeps its own recurrent state and random generator.
    """
    model = cache.get(path, role) if cache is not None else load_model(path, role)
    unknown = sorted(set(acting) - set(ACTING))
    if unknown:
        raise ValueError(f"{path}: unknown acting setting(s) {unknown}; allowed: {list(ACTING)}")
    stored = getattr(model, "acting", {})
    settings = {k: stored.get(k, default) if acting.get(k) is None else acting[k] for k, (_, default) in ACTING.items()}
    return NetPolicy(model, name=f"{Path(path).stem}", source=str(path), **settings)


def load_model(path: str | Path, role: str | None) -> ActorCritic:
    from train.checkpoint import build_model, find_network, load_checkpoint

    ckpt = load_checkpoint(path)
    env = EnvConfig.from_dict(ckpt["env_config"])
    _, entry = find_network(ckpt, env, role, str(path))
    return build_model(entry, env, str(path))
