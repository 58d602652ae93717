"""A rollout step of several learners with the same network as one program, on any device.

``train.stacked.StackedActing`` is the CPU's way: hand-stacked layers over each learner's window
patches, cut by compiled kernels. On a GPU a pack's rollout step is bound by calls, not arithmetic
(a 16-env trial alone trains no faster on an H100 than on two CPU cores: docs/PERFORMANCE.md), so
here the learners' networks run as one ``torch.func.vmap`` of ``ActorCritic.forward`` over their
stacked weights (and stacked recurrent states, an LSTM run by ``train.nets.lstm_by_steps``): one call
per layer for the whole pack. Each learner keeps what ``Learner.act``
keeps (its view, inputs, action, log-probability and value) and draws its sample from its own
generator, so its update reads the same rollout it would alone (up to float rounding).
"""

from __future__ import annotations

import numpy as np
import torch
from torch.func import functional_call, vmap

from train.learner import _SIDE, Learner, sample_from
from train.nets import recurrence_by_steps
from train.packed_update import can_pack_update, stacked_weights


class PackedActing:
    """Acting for ``learners`` (``train.packed_update.can_pack_update``) in one ``vmap``; call ``refresh`` after their
    weights change (a pack does at each rollout's start)."""

    def __init__(self, learners: list[Learner]):
        if not can_pack_update(learners):
            raise ValueError("these learners cannot act as one: each must be a network of the same configuration and "
                             "shapes, on one device (train.packed_update.can_pack_update)")
        self.learners = learners
        self.template = learners[0].model
        self.params: dict[str, torch.Tensor] = {}
        self.recurrent = self.template.lstm is not None
        self._forward = vmap(self._one, in_dims=(0, 0, 0, 0 if self.recurrent else None))

    def _one(self, params: dict, view: dict, side: dict, state: tuple | None):
        logits, value, goal_logits, state = functional_call(self.template, params,
                                                            (view, *(side[k] for k in _SIDE), state))
        return logits, value, goal_logits, (() if state is None else state)

    @torch.no_grad()
    def refresh(self) -> None:
        """Stack the learners' current weights, ``[L, ...]`` each."""
        self.params = stacked_weights(self.learners)

    @torch.inference_mode()
    def act(self, inputs: list[dict[str, torch.Tensor]]) -> list[tuple[np.ndarray, np.ndarray]]:
        """One step for every learner (``inputs`` in the order of ``learners``, each as for ``Learner.act``): each
        one's sampled actions ``[rows]`` and goal probabilities ``[rows, C]``, kept in its buffers as ``act`` keeps
        them."""
        views = [lr.model.prepare(x["obs"], x["me"], lr.identity) for lr, x in zip(self.learners, inputs)]
        view = {k: torch.stack([v[k] for v in views]) for k in views[0]}
        side = {k: torch.stack([x[k] for x in inputs]) for k in _SIDE}
        state = (tuple(torch.stack([lr.state[n] for lr in self.learners]) for n in range(2)) if self.recurrent
                 else None)
        with recurrence_by_steps(self.template):
            logits, value, goal_logits, state = self._forward(self.params, view, side, state)
        if self.recurrent:
            for i, learner in enumerate(self.learners):
                learner.state = (state[0][i], state[1][i])
        probs = torch.softmax(logits[:, 0], dim=2)  # [L, rows, A]
        uniforms = torch.stack([torch.rand(probs.shape[1], 1, generator=lr.generator) for lr in self.learners])
        actions = sample_from(probs, uniforms.to(probs.device))
        logp = torch.log(probs.gather(2, actions[..., None])[..., 0])
        goal_probs = torch.softmax(goal_logits[:, 0], dim=2).cpu().numpy()
        for i, (learner, x, v) in enumerate(zip(self.learners, inputs, views)):
            learner.store_view(v)
            learner.keep(x, actions[i], logp[i], value[i, 0])
        actions = actions.cpu().numpy()
        return [(actions[i], goal_probs[i]) for i in range(len(self.learners))]
