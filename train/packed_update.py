"""The PPO update of several learners with the same network as one program (a pack's update).

Each learner is updated exactly as ``Learner.update`` updates it alone (the same advantages,
minibatch order from its own generator, loss, gradient clip, Adam step and early stop on KL), but
the network and the loss run once for all of them: their weights are stacked into ``[L, ...]``
tensors and each minibatch is one ``torch.func.vmap`` of ``ActorCritic.forward`` and ``ppo_loss``
over the learners, forward and backward; every layer is one batched product for all ``L``. Each
learner keeps its own optimizer, so its checkpoint is what it would be alone. A learner whose KL
stops its epochs early is left out of the later epochs; the others go on.

The results are each learner's own up to float rounding (a batched product may sum in another
order than a single one; ``tests/test_pack.py`` compares). A recurrent network's minibatches are whole
envs replayed from their state at the rollout's start, as alone; its LSTM runs step by step here
(``train.nets.lstm_by_steps``: ``vmap`` has no batching rule for ``aten::lstm``, and the segments
``nn.LSTM`` runs split where episodes start, which depends on the data).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch
from torch.func import functional_call, vmap

from train.learner import _SIDE, Learner, rows
from train.nets import recurrence_by_steps
from train.packing import PACK_SHAPED
from train.ppo import LossWeights, compute_gae, explained_variance, ppo_loss

_PER_LEARNER = ("clip_coef", "ent_coef", "vf_coef", "aux_coef")
"""The loss weights a packed learner may have of its own (``LossWeights``' other fields shape the loss)."""


def can_pack_update(learners: list[Learner]) -> bool:
    """Whether these learners can update as one ``PackedUpdate``: networks of one configuration (with or without
    an LSTM) and the same parameter shapes, on one device, with the same rows and the same PPO shape
    (``PACK_SHAPED``)."""
    first = learners[0]
    shapes = [p.shape for p in first.parameters]
    return (all(lr.device == first.device and lr.rows == first.rows for lr in learners)
            and all(lr.model.net == first.model.net and lr.model.agents.__len__() == len(first.model.agents)
                    for lr in learners)
            and all([p.shape for p in lr.parameters] == shapes for lr in learners)
            and all(getattr(lr.ppo, k) == getattr(first.ppo, k) for lr in learners for k in PACK_SHAPED)
            and all(lr.weights.clip_vloss == first.weights.clip_vloss and lr.weights.norm_adv == first.weights.norm_adv
                    for lr in learners))


def stacked_weights(learners: list[Learner]) -> dict[str, torch.Tensor]:
    """The learners' current weights by parameter name, each ``[L, ...]`` (detached copies, in learner order)."""
    names = [name for name, _ in learners[0].model.named_parameters()]
    return {name: torch.stack([p.detach() for p in group])
            for name, group in zip(names, zip(*(lr.parameters for lr in learners)))}


class PackedUpdate:
    """The PPO update of ``learners`` (``can_pack_update``) as one program; see the module docstring."""

    def __init__(self, learners: list[Learner]):
        if not can_pack_update(learners):
            raise ValueError("these learners cannot update as one: each must be a network of the same configuration "
                             "and shapes, on one device, with the same PPO shape (train.packed_update.can_pack_update)")
        self.learners = learners
        self.template = learners[0].model  # whose forward runs, on the stacked weights
        self.names = [name for name, _ in self.template.named_parameters()]
        self.ppo = learners[0].ppo
        self.shuffled: dict[str, torch.Tensor] = {}  # [L, N, ...] per view key: each learner's epoch order
        self.recurrent = self.template.lstm is not None
        self._step = vmap(self._loss, in_dims=(0, 0, 0, 0, 0 if self.recurrent else None))

    def _loss(self, params: dict, view: dict, mb: dict, w: dict, state: tuple | None):
        """One learner's PPO loss on its minibatch (``view`` and ``mb`` ``[T, n, ...]``: one step of ``n`` samples,
        or ``n`` whole envs from the recurrent ``state`` they had at the rollout's start), from its weights
        ``params`` and loss weights ``w`` (under ``vmap``: one of the pack)."""
        logits, value, goal_logits, _ = functional_call(self.template, params,
                                                        (view, *(mb[k] for k in _SIDE), state))
        flat = {k: t.reshape(-1, *t.shape[2:]) for k, t in mb.items()}
        first = self.learners[0].weights
        weights = LossWeights(w["clip_coef"], first.clip_vloss, w["ent_coef"], w["vf_coef"], w["aux_coef"],
                              first.norm_adv)
        return ppo_loss(logits.reshape(-1, logits.shape[-1]), value.reshape(-1),
                        goal_logits.reshape(-1, goal_logits.shape[-1]), flat["actions"], flat["logp"],
                        flat["values"], flat["advantages"], flat["returns"], flat["true_goal"], weights,
                        flat.get("aux_target"))

    def update(self, inputs: list[dict]) -> list[dict[str, float]]:
        """Every learner's PPO update on the rollout it just collected, bootstrapped from the values of its network
        ``inputs`` now (in the order of ``learners``); returns each one's statistics as ``Learner.update`` does."""
        learners, ppo = self.learners, self.ppo
        rollouts = [lr.stacked() for lr in learners]
        bootstrap = [lr.value(x) for lr, x in zip(learners, inputs)]
        samples = self._samples(rollouts, bootstrap)  # per learner: {key: [T, B, ...]}
        weights = [dataclasses.asdict(lr.weights) for lr in learners]
        active = list(range(len(learners)))
        last: list[dict] = [{} for _ in learners]
        epochs = [0] * len(learners)
        with recurrence_by_steps(self.template):
            for _ in range(ppo.update_epochs):
                w = {k: torch.tensor([weights[i][k] for i in active], device=learners[0].device)
                     for k in _PER_LEARNER}
                minibatches = (self._sequences(rollouts, samples, active) if self.recurrent
                               else self._shuffled_steps(rollouts, samples, active))
                stats = [self._minibatch([learners[i] for i in active], view, mb, w, state)
                         for view, mb, state in minibatches]
                still = []
                for j, i in enumerate(active):
                    epochs[i] += 1
                    last[i] = {k: torch.stack([s[k][j] for s in stats]).mean() for k in stats[0]}
                    target = learners[i].ppo.target_kl
                    if target is None or not last[i]["approx_kl"] > target:
                        still.append(i)
                active = still
                if not active:
                    break
        out = []
        for i, learner in enumerate(learners):
            result = {k: float(v) for k, v in last[i].items()}
            result["explained_variance"] = explained_variance(rollouts[i]["values"].flatten(),
                                                              samples[i]["returns"].flatten())
            result["epochs"] = epochs[i]
            result["lr"] = learner.optimizer.param_groups[0]["lr"]
            out.append(result)
        return out

    def _shuffled_steps(self, rollouts: list[dict], samples: list[dict], active: list[int]):
        """Feed-forward minibatches of one epoch, as ``Learner.shuffled_steps`` cuts them for each active learner
        (its own order, from its generator): ``(view, samples, None)``, every tensor ``[L, 1, n, ...]``."""
        learners = self.learners
        views = [{k: v.reshape(-1, *v.shape[2:]) for k, v in rollouts[i]["view"].items()} for i in active]
        N = len(samples[0]["values"].reshape(-1))
        orders = [torch.randperm(N, generator=learners[i].generator).to(learners[i].device) for i in active]
        shuffled = {k: self._storage(k, len(active), views[0][k]) for k in views[0]}
        for j, order in enumerate(orders):
            for k in shuffled:
                rows(views[j][k], 0, order, out=shuffled[k][j])
        picked = {k: torch.stack([samples[i][k].reshape(N, *samples[i][k].shape[2:]).index_select(0, order)
                                  for i, order in zip(active, orders)]) for k in samples[0]}
        n = N // self.ppo.num_minibatches
        for start in range(0, N, n):
            part = lambda t: t[:, None, start:start + n]  # noqa: E731
            yield {k: part(v) for k, v in shuffled.items()}, {k: part(t) for k, t in picked.items()}, None

    def _sequences(self, rollouts: list[dict], samples: list[dict], active: list[int]):
        """Recurrent minibatches of one epoch, as ``Learner.sequences`` makes them for each active learner: whole
        envs in its own order, replayed from the recurrent state they had at the rollout's start; ``(view, samples,
        state)``, every tensor ``[L, T, b, ...]`` (the state ``[L, 1, b, H]``)."""
        learners = self.learners
        B = samples[0]["values"].shape[1]
        orders = [torch.randperm(B, generator=learners[i].generator).to(learners[i].device)
                  .view(self.ppo.num_minibatches, -1) for i in active]
        for m in range(self.ppo.num_minibatches):
            parts = [(i, order[m]) for i, order in zip(active, orders)]
            view = {k: torch.stack([rows(rollouts[i]["view"][k], 1, idx) for i, idx in parts])
                    for k in rollouts[active[0]]["view"]}
            mb = {k: torch.stack([samples[i][k].index_select(1, idx) for i, idx in parts]) for k in samples[0]}
            state = tuple(torch.stack([learners[i].initial_state[n].index_select(1, idx) for i, idx in parts])
                          for n in range(2))
            yield view, mb, state

    def _minibatch(self, learners: list[Learner], view: dict, mb: dict, w: dict, state: tuple | None
                   ) -> dict[str, torch.Tensor]:
        """One minibatch of every learner in ``learners`` (the active ones, in the order of ``view``'s and ``mb``'s
        first axis): one batched loss, forward and backward, then each one's clip and Adam step."""
        stacked = {name: w.requires_grad_() for name, w in stacked_weights(learners).items()}
        loss, stats = self._step(stacked, view, mb, w, state)
        loss.sum().backward()  # the learners share nothing: each one's gradient is its own loss's
        for j, learner in enumerate(learners):
            for name, param in zip(self.names, learner.parameters):
                param.grad = stacked[name].grad[j]
            torch.nn.utils.clip_grad_norm_(learner.parameters, learner.ppo.max_grad_norm)
            learner.optimizer.step()
            learner.optimizer.zero_grad(set_to_none=True)
        return stats

    def _samples(self, rollouts: list[dict], bootstrap: list[torch.Tensor]) -> list[dict[str, torch.Tensor]]:
        """Each learner's samples ``{key: [T, B, ...]}``, its advantages and returns by GAE with its own gamma
        and lambda (one pass over the steps for all learners: GAE is column by column)."""
        values = torch.cat([b["values"] for b in rollouts], dim=1)  # [T, L * B]
        dones = torch.cat([b["dones"] for b in rollouts], dim=1)
        following = torch.cat([values[1:], torch.cat(bootstrap)[None]], dim=0)
        next_values = torch.where(dones, torch.cat([b["final_values"] for b in rollouts], dim=1), following)
        B = rollouts[0]["values"].shape[1]
        column = lambda key: torch.tensor(np.repeat([getattr(lr.ppo, key) for lr in self.learners], B),  # noqa: E731
                                          dtype=values.dtype, device=values.device)
        advantages, returns = compute_gae(torch.cat([b["rewards"] for b in rollouts], dim=1), values, next_values,
                                          dones, column("gamma"), column("gae_lambda"))
        out = []
        with_target = any("aux_target" in b for b in rollouts)
        for i, b in enumerate(rollouts):
            part = slice(i * B, (i + 1) * B)
            s = {k: b[k] for k in (*_SIDE, "actions", "logp", "true_goal")}
            s.update(values=b["values"], advantages=advantages[:, part], returns=returns[:, part])
            if with_target:  # every learner's goal head then learns from soft targets: the true goal as one-hot
                s["aux_target"] = (b["aux_target"] if "aux_target" in b else
                                   torch.nn.functional.one_hot(b["true_goal"], self.template.env.num_colors).float())
            out.append(s)
        return out

    def _storage(self, key: str, count: int, like: torch.Tensor) -> torch.Tensor:
        """``[count, *like.shape]`` storage for view ``key`` in each learner's epoch order, allocated once."""
        stored = self.shuffled.get(key)
        if stored is None or stored.shape[1:] != like.shape or stored.dtype != like.dtype:
            stored = self.shuffled[key] = torch.empty(len(self.learners), *like.shape, dtype=like.dtype,
                                                      device=like.device)
        return stored[:count]
