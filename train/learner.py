"""One learning network: its optimizer, rollout buffer and PPO update (IPPO: learners share nothing).

A network plays one agent, or several agents of a role that share it: its rows are then the
envs of each of those agents in turn (agent-major, ``len(agents) * num_envs`` rows), acted on
in one batch and updated together as one larger batch.
"""

from __future__ import annotations

import numpy as np
import torch

from train.config import PPOConfig
from train.nets import ActorCritic
from train.ppo import LossWeights, compute_gae, explained_variance, ppo_loss

_SIDE = ("goal", "extras", "starts")


class Learner:
    """Acts during rollouts (keeping its recurrent state), then updates on the whole rollout.

    Recurrent networks are trained on whole sequences: minibatches are sets of rows (an
    agent in an env), each replayed over the full rollout from the recurrent state it had at
    the rollout's start, with the state zeroed at episode starts, exactly as during the rollout.
    ``name`` names the network in logs and checkpoints (its agent's name, or its role's when shared).
    """

    def __init__(self, model: ActorCritic, ppo: PPOConfig, weights: LossWeights, lr: float, seed: int,
                 device: torch.device, name: str = ""):
        self.model, self.ppo, self.weights, self.device = model.to(device), ppo, weights, device
        self.name, self.agents = name, model.agents
        self.parameters = list(self.model.parameters())  # (listed once: the module walk costs 0.1 ms a minibatch)
        self.optimizer = torch.optim.Adam(self.parameters, lr=lr, eps=1e-5, fused=True)
        self.generator = torch.Generator().manual_seed(seed)
        self.rows = len(self.agents) * ppo.num_envs
        self.state = self.model.initial_state(self.rows, device)
        self.identity = self.model.identity(self.agents, ppo.num_envs, device)  # None unless shared
        self.buffer: dict[str, list] = {}
        self.views: dict[str, torch.Tensor] = {}  # [num_steps, rows, ...] per view key, reused by every rollout
        self.shuffled: dict[str, torch.Tensor] = {}  # [num_steps * rows, ...] per view key, reused by every epoch
        self.steps = 0  # steps acted in this rollout

    # ------------------------------------------------------------ rollout
    def start_rollout(self) -> None:
        self.initial_state = None if self.state is None else tuple(s.clone() for s in self.state)
        self.steps = 0
        self.buffer = {k: [] for k in (*_SIDE, "actions", "logp", "values", "rewards", "dones", "final_values",
                                       "true_goal", "aux_target")}

    @torch.inference_mode()
    def act(self, x: dict[str, torch.Tensor]) -> tuple[np.ndarray, np.ndarray]:
        """One step for every row: sampled actions ``[rows]`` and goal probabilities ``[rows, C]``."""
        view = self.model.prepare(x["obs"], x["me"], self.identity)
        logits, value, goal_logits, self.state = self.model(view, *(x[k] for k in _SIDE), self.state)
        probs = torch.softmax(logits[0], dim=1)
        actions = sample(probs, self.generator)
        self.store_view(view)
        self.keep(x, actions, torch.log(probs.gather(1, actions[:, None])[:, 0]), value[0])
        return actions.cpu().numpy(), torch.softmax(goal_logits[0], dim=1).cpu().numpy()

    def keep(self, x: dict[str, torch.Tensor], actions: torch.Tensor, logp: torch.Tensor, value: torch.Tensor) -> None:
        """Keep one step's inputs ``x`` (as ``act`` takes them) and what was chosen, each ``[rows]``, in the rollout
        (its network view is stored apart: ``store_view``)."""
        for k in _SIDE:
            self.buffer[k].append(x[k][0])
        self.buffer["actions"].append(actions)
        self.buffer["logp"].append(logp)
        self.buffer["values"].append(value)
        self.steps += 1

    def store_view(self, view: dict[str, torch.Tensor]) -> None:
        """Keep this step's network view in the rollout's preallocated storage (no stacking at the update)."""
        for k, v in view.items():
            stored = self.views.get(k)
            if stored is None or stored.shape[1:] != v.shape[1:] or stored.dtype != v.dtype:
                with torch.inference_mode(False):  # a normal tensor: the update reads it with autograd on
                    stored = self.views[k] = torch.empty(self.ppo.num_steps, *v.shape[1:], dtype=v.dtype,
                                                         device=v.device)
            stored[self.steps].copy_(v[0])

    @torch.inference_mode()
    def value(self, x: dict[str, torch.Tensor]) -> torch.Tensor:
        """Values of observations ``x`` under the current recurrent state, without advancing it."""
        view = self.model.prepare(x["obs"], x["me"], self.identity)
        _, value, _, _ = self.model(view, *(x[k] for k in _SIDE), self.state)
        return value[0]

    def record(self, reward: np.ndarray, done: np.ndarray, true_goal: np.ndarray,
               final_value: torch.Tensor | None, aux_target: np.ndarray | None = None) -> None:
        """The outcome of the last action, per row (``[rows]``); ``final_value`` holds V(final observation)
        where ``done`` (None: no episode ended); ``aux_target [rows, C]`` the goal head's soft target (None:
        ``true_goal`` is its target). Kept as arrays, made tensors once for the whole rollout (``stacked``)."""
        self.buffer["rewards"].append(np.array(reward, dtype=np.float32))
        self.buffer["dones"].append(np.array(done, dtype=bool))
        self.buffer["true_goal"].append(np.array(true_goal, dtype=np.int64))
        self.buffer["final_values"].append(final_value)
        if aux_target is not None:
            self.buffer["aux_target"].append(np.array(aux_target, dtype=np.float32))

    # ------------------------------------------------------------- update
    def stacked(self) -> dict:
        """The rollout as ``[T, B, ...]`` tensors (``view`` is a dict of them)."""
        b = {}
        for key, steps in self.buffer.items():
            if not steps:
                continue
            if key == "final_values":
                zeros = torch.zeros(self.rows, device=self.device)
                b[key] = torch.stack([zeros if v is None else v for v in steps])
            elif isinstance(steps[0], np.ndarray):  # (``record``'s)
                b[key] = torch.from_numpy(np.stack(steps)).to(self.device)
            else:
                b[key] = torch.stack(steps)
        b["view"] = {k: v[:self.steps] for k, v in self.views.items()}
        return b

    def update(self, bootstrap_value: torch.Tensor) -> dict[str, float]:
        """PPO epochs over the rollout; returns the last epoch's mean statistics."""
        return self.update_on(self.stacked(), bootstrap_value)

    def update_on(self, b: dict, bootstrap_value: torch.Tensor) -> dict[str, float]:
        """``update`` on a rollout ``b`` as ``stacked`` gives it (``train.update_process`` runs it in a process of
        its own, on the rollout it is sent)."""
        values, dones = b["values"], b["dones"]
        following = torch.cat([values[1:], bootstrap_value[None]], dim=0)
        next_values = torch.where(dones, b["final_values"], following)
        advantages, returns = compute_gae(b["rewards"], values, next_values, dones, self.ppo.gamma,
                                          self.ppo.gae_lambda)
        T, B = values.shape
        recurrent = self.model.lstm is not None
        samples = {**{k: b[k] for k in (*_SIDE, "actions", "logp", "true_goal", "aux_target") if k in b},
                   "values": values, "advantages": advantages, "returns": returns}  # [T, B, ...] each
        epochs_done, stats = 0, []
        for _ in range(self.ppo.update_epochs):
            stats = []
            # recurrent minibatches are whole envs (sequences kept intact), others single steps
            order = torch.randperm(B if recurrent else T * B, generator=self.generator).to(self.device)
            batches = (self.sequences(b["view"], samples, order) if recurrent
                       else self.shuffled_steps(b["view"], samples, order))
            for view, mb, state in batches:
                logits, v, gl, _ = self.model(view, *(mb[k] for k in _SIDE), state)
                logits, v, gl = (pick_all(z) for z in (logits, v, gl))
                flat = {k: pick_all(t) for k, t in mb.items()}
                loss, s = ppo_loss(logits, v, gl, flat["actions"], flat["logp"], flat["values"], flat["advantages"],
                                   flat["returns"], flat["true_goal"], self.weights, flat.get("aux_target"))
                self.optimizer.zero_grad(set_to_none=True)
                loss.backward()
                torch.nn.utils.clip_grad_norm_(self.parameters, self.ppo.max_grad_norm)
                self.optimizer.step()
                stats.append(s)
            epochs_done += 1
            kl = torch.stack([s["approx_kl"] for s in stats]).mean()
            if self.ppo.target_kl is not None and kl > self.ppo.target_kl:
                break
        out = {k: float(torch.stack([s[k] for s in stats]).mean()) for k in stats[0]}
        out["explained_variance"] = explained_variance(values.flatten(), returns.flatten())
        out["epochs"] = epochs_done
        out["lr"] = self.optimizer.param_groups[0]["lr"]
        return out

    def sequences(self, view: dict, samples: dict, order: torch.Tensor):
        """Recurrent minibatches: ``(view, samples, initial state)`` of the envs in each part of ``order [B]``, every
        tensor ``[T, b, ...]`` (whole sequences, replayed from the rollout's initial recurrent state)."""
        for idx in order.view(self.ppo.num_minibatches, -1):
            envs = lambda t: t.index_select(1, idx)  # noqa: E731
            yield ({k: rows(v, 1, idx) for k, v in view.items()}, {k: envs(t) for k, t in samples.items()},
                   tuple(envs(s) for s in self.initial_state))

    def shuffled_steps(self, view: dict, samples: dict, order: torch.Tensor):
        """Feed-forward minibatches: ``(view, samples, None)`` of the steps in each part of ``order [T * B]``, every
        tensor ``[1, n, ...]``. Each tensor is put in ``order`` once per epoch, the views into storage kept between
        updates, and cut into contiguous parts: the same rows as one selection per minibatch, without allocating
        a fresh 5 MB patch tensor each time (its page faults cost more than the copy)."""
        shuffled = {k: self.shuffled_storage(k, v.reshape(-1, *v.shape[2:])) for k, v in view.items()}
        for k, v in view.items():
            rows(v.reshape(-1, *v.shape[2:]), 0, order, out=shuffled[k])
        picked = {k: t.reshape(-1, *t.shape[2:]).index_select(0, order) for k, t in samples.items()}
        n = len(order) // self.ppo.num_minibatches
        for start in range(0, len(order), n):
            part = lambda t: t[None, start:start + n]  # noqa: E731
            yield {k: part(v) for k, v in shuffled.items()}, {k: part(t) for k, t in picked.items()}, None

    def shuffled_storage(self, key: str, like: torch.Tensor) -> torch.Tensor:
        """A tensor shaped as ``like`` to hold view ``key``'s rows in an epoch's order, allocated once."""
        stored = self.shuffled.get(key)
        if stored is None or stored.shape != like.shape or stored.dtype != like.dtype:
            stored = self.shuffled[key] = torch.empty_like(like, memory_format=torch.contiguous_format)
        return stored


def sample(probs: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
    """One action per row of ``probs [B, A]`` by inverting the CDF (uniforms from ``generator``, on the CPU)."""
    return sample_from(probs, torch.rand(probs.shape[0], 1, generator=generator).to(probs.device))


def sample_from(probs: torch.Tensor, uniforms: torch.Tensor) -> torch.Tensor:
    """The action of each row of ``probs [..., A]`` that ``uniforms [..., 1]`` picks by inverting the CDF."""
    return (probs.cumsum(dim=-1) <= uniforms).sum(dim=-1).clamp_(max=probs.shape[-1] - 1)


def rows(t: torch.Tensor, dim: int, idx: torch.Tensor, out: torch.Tensor | None = None) -> torch.Tensor:
    """``t.index_select(dim, idx)`` for a contiguous ``t``, through its 2-D or 3-D form: the same tensor (one
    selection over flat rows instead of one along the view's full shape); written into ``out`` if given."""
    flat = t.reshape(*t.shape[:dim + 1], -1)
    if out is None:
        picked = flat.index_select(dim, idx)
    else:
        picked = torch.index_select(flat, dim, idx, out=out.view(*flat.shape[:dim], len(idx), -1))
    return picked.reshape(*picked.shape[:dim + 1], *t.shape[dim + 1:])


def pick_all(t: torch.Tensor) -> torch.Tensor:
    """``[T, b, ...]`` network outputs flattened to ``[T * b, ...]`` (the order ``pick`` uses)."""
    return t.reshape(t.shape[0] * t.shape[1], *t.shape[2:])
