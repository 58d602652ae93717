"""The PPO update of several learners with the same feed-forward network as one program (a pack's update).

Each learner is updated exactly as ``Learner.update`` updates it alone (the same advantages,
minibatch order from its own generator, loss, gradient clip, Adam step and early stop on KL), but
the network and the loss run once for all of them: their weights are stacked into ``[L, ...]``
tensors and each minibatch is one ``torch.func.vmap`` of ``ActorCritic.forward`` and ``ppo_loss``
over the learners, forward and backward; every layer is one batched product for all ``L``. Each
learner keeps its own optimizer, so its checkpoint is what it would be alone. A learner whose KL
stops its epochs early is left out of the later epochs; the others go on.

The results are each learner's own up to float rounding (a batched product may sum in another
order than a single one; ``tests/test_pack.py`` compares). Recurrent networks are not packed here
(their sequences split where episodes start, which ``vmap`` cannot batch): they update on their own.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch
from torch.func import functional_call, vmap

from train.learner import _SIDE, Learner, rows
from train.packing import PACK_SHAPED
from train.ppo import LossWeights, compute_gae, explained_variance, ppo_loss

_PER_LEARNER = ("clip_coef", "ent_coef", "vf_coef", "aux_coef")
"""The loss weights a packed learner may have of its own (``LossWeights``' other fields shape the loss)."""


def can_pack_update(learners: list[Learner]) -> bool:
    """Whether these learners can update as one ``PackedUpdate``: feed-forward networks of one configuration and
    the same parameter shapes, on one device, with the same rows and the same PPO shape (``PACK_SHAPED``)."""
    first = learners[0]
    shapes = [p.shape for p in first.parameters]
    return (all(lr.model.lstm is None for lr in learners)
            and all(lr.device == first.device and lr.rows == first.rows for lr in learners)
            and all(lr.model.net == first.model.net and lr.model.agents.__len__() == len(first.model.agents)
                    for lr in learners)
            and all([p.shape for p in lr.parameters] == shapes for lr in learners)
            and all(getattr(lr.ppo, k) == getattr(first.ppo, k) for lr in learners for k in PACK_SHAPED)
            and all(lr.weights.clip_vloss == first.weights.clip_vloss and lr.weights.norm_adv == first.weights.norm_adv
                    for lr in learners))


class PackedUpdate:
    """The PPO update of ``learners`` (``can_pack_update``) as one program; see the module docstring."""

    def __init__(self, learners: list[Learner]):
        if not can_pack_update(learners):
            raise ValueError("these learners cannot update as one: each must be a feed-forward network of the same "
                             "configuration and shapes, on one device, with the same PPO shape "
                             "(train.packed_update.can_pack_update)")
        self.learners = learners
        self.template = learners[0].model  # whose forward runs, on the stacked weights
        self.names = [name for name, _ in self.template.named_parameters()]
        self.ppo = learners[0].ppo
        self.shuffled: dict[str, torch.Tensor] = {}  # [L, N, ...] per view key: each learner's epoch order
        self._step = vmap(self._loss, in_dims=(0, 0, 0, 0))

    def _loss(self, params: dict, view: dict, mb: dict, w: dict):
        """One learner's PPO loss on its minibatch (``view`` and ``mb`` ``[1, n, ...]``), from its weights ``params``
        and loss weights ``w`` (under ``vmap``: one of the pack)."""
        logits, value, goal_logits, _ = functional_call(self.template, params,
                                                        (view, *(mb[k] for k in _SIDE), None))
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
        samples = self._samples(rollouts, bootstrap)  # per learner: {key: [N, ...]}
        views = [{k: v.reshape(-1, *v.shape[2:]) for k, v in b["view"].items()} for b in rollouts]
        N = len(samples[0]["values"])
        n = N // ppo.num_minibatches
        weights = [dataclasses.asdict(lr.weights) for lr in learners]
        active = list(range(len(learners)))
        last: list[dict] = [{} for _ in learners]
        epochs = [0] * len(learners)
        for _ in range(ppo.update_epochs):
            orders = [torch.randperm(N, generator=learners[i].generator).to(learners[i].device) for i in active]
            shuffled = {k: self._storage(k, len(active), views[0][k]) for k in views[0]}
            for j, (i, order) in enumerate(zip(active, orders)):
                for k in shuffled:
                    rows(views[i][k], 0, order, out=shuffled[k][j])
            picked = {k: torch.stack([samples[i][k].index_select(0, order) for i, order in zip(active, orders)])
                      for k in samples[0]}
            w = {k: torch.tensor([weights[i][k] for i in active], device=learners[0].device) for k in _PER_LEARNER}
            stats = []
            for start in range(0, N, n):
                part = lambda t: t[:, None, start:start + n]  # noqa: E731  [L, 1, n, ...]
                stats.append(self._minibatch([learners[i] for i in active], {k: part(v) for k, v in shuffled.items()},
                                             {k: part(t) for k, t in picked.items()}, w))
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
                                                              samples[i]["returns"])
            result["epochs"] = epochs[i]
            result["lr"] = learner.optimizer.param_groups[0]["lr"]
            out.append(result)
        return out

    def _minibatch(self, learners: list[Learner], view: dict, mb: dict, w: dict) -> dict[str, torch.Tensor]:
        """One minibatch of every learner in ``learners`` (the active ones, in the order of ``view``'s and ``mb``'s
        first axis): one batched loss, forward and backward, then each one's clip and Adam step."""
        stacked = {name: torch.stack([p.detach() for p in group]).requires_grad_()
                   for name, group in zip(self.names, zip(*(lr.parameters for lr in learners)))}
        loss, stats = self._step(stacked, view, mb, w)
        loss.sum().backward()  # the learners share nothing: each one's gradient is its own loss's
        for j, learner in enumerate(learners):
            for name, param in zip(self.names, learner.parameters):
                param.grad = stacked[name].grad[j]
            torch.nn.utils.clip_grad_norm_(learner.parameters, learner.ppo.max_grad_norm)
            learner.optimizer.step()
            learner.optimizer.zero_grad(set_to_none=True)
        return stats

    def _samples(self, rollouts: list[dict], bootstrap: list[torch.Tensor]) -> list[dict[str, torch.Tensor]]:
        """Each learner's flat samples ``{key: [T * B, ...]}``, its advantages and returns by GAE with its own gamma
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
            out.append({k: t.reshape(-1, *t.shape[2:]) for k, t in s.items()})
        return out

    def _storage(self, key: str, count: int, like: torch.Tensor) -> torch.Tensor:
        """``[count, *like.shape]`` storage for view ``key`` in each learner's epoch order, allocated once."""
        stored = self.shuffled.get(key)
        if stored is None or stored.shape[1:] != like.shape or stored.dtype != like.dtype:
            stored = self.shuffled[key] = torch.empty(len(self.learners), *like.shape, dtype=like.dtype,
                                                      device=like.device)
        return stored[:count]
