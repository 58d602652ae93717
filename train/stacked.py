"""Every learner's rollout step in one set of batched operations (CPU, the fast feed-forward network).

At the paper's batch (16 envs) a layer's arithmetic takes a few microseconds and its call as
long again, so a rollout step of two learners, each running its own network layer by layer,
pays mostly for calls. Learners whose networks have the same shape (the fast feed-forward
network, as leader and follower use by default) act here through one stacked copy of their
weights instead: each layer is one batched matrix product over all learners, the policy,
value and goal heads are joined into block-diagonal layers, and each learner's window patches
are cut by one compiled pass straight into its rollout storage, which the update reads.

This is ``ActorCritic.forward`` on the same inputs with the same weights (a test checks the
outputs agree to float rounding); samples are drawn from each learner's own generator as
``Learner.act`` draws them. Only acting changes: the update still runs each learner's own
network.
"""

from __future__ import annotations

import numpy as np
import torch

from train import views
from train.learner import Learner, sample_from
from train.nets import FastEncoder


def can_stack(learners: list[Learner]) -> bool:
    """Whether these learners can act through one ``StackedActing``: all on the CPU, each a fast feed-forward
    network without goal planes or belief input, with the same parameter shapes and the same number of rows."""
    models = [lr.model for lr in learners]
    first = models[0]
    return (all(lr.device.type == "cpu" for lr in learners)
            and all(isinstance(m.encoder, FastEncoder) and m.lstm is None and not m.encoder.planes
                    and m.net.goal_fusion in ("flat", "heads") and not m.net.belief_input for m in models)
            and all(lr.rows == learners[0].rows for lr in learners)
            and all(m.net == first.net and m.shared == first.shared and len(m.agents) == len(first.agents)
                    for m in models)
            and all([p.shape for p in m.parameters()] == [p.shape for p in first.parameters()] for m in models))


def block_diagonal(*layers: torch.nn.Linear) -> tuple[torch.Tensor, torch.Tensor]:
    """The weight ``[in, out]`` (for ``x @ w``) and bias of the layers side by side, each on its own inputs."""
    weight = torch.block_diag(*(layer.weight for layer in layers)).T
    return weight, torch.cat([layer.bias for layer in layers])


class StackedActing:
    """Acting for ``learners`` (``can_stack``) in one set of batched operations; call ``refresh`` after their
    weights change (the trainer does at each rollout's start)."""

    def __init__(self, learners: list[Learner]):
        if not can_stack(learners):
            raise ValueError("these learners cannot act stacked: each must be a fast feed-forward network of the "
                             "same shape on the CPU (train.stacked.can_stack)")
        self.learners = learners
        model = learners[0].model
        self.encoder: FastEncoder = model.encoder
        self.num_actions = model.env.num_actions
        self.head_in = model.policy[0].in_features
        self.weights: list[tuple[torch.Tensor, torch.Tensor]] = []
        self.storage: dict[str, torch.Tensor] = {}
        self.parts: dict[str, list[torch.Tensor]] = {}  # storage[key][i], learner i's rollout storage of view key
        for learner in learners:  # a shared network's rows say which agent each is: the same at every step
            if learner.identity is not None:
                learner.views["identity"] = learner.identity.expand(learner.ppo.num_steps, -1, -1).contiguous()

    # ------------------------------------------------------------------ weights
    @torch.no_grad()
    def refresh(self) -> None:
        """Stack the learners' current weights, each layer as ``(weight [L, in, out], bias [L, 1, out])``."""
        per_learner = [self._layers(lr.model) for lr in self.learners]
        self.weights = [(torch.stack([w for w, _ in layer]), torch.stack([b for _, b in layer])[:, None])
                        for layer in zip(*per_learner)]

    def _layers(self, model) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """One network's layers as ``(weight [in, out], bias)``: conv1 and conv2 on their patches, the encoder's
        dense layer with its window inputs in the order ``act`` lays them out, the heads joined."""
        enc: FastEncoder = model.encoder
        conv1, conv2, dense = enc.convs[0], enc.convs[2], enc.mlp[0]
        channels = conv2.out_channels
        dense_w = torch.cat(enc.dense_weights(), dim=1)  # the window's features cell-major, as in the encoder
        # the goal head reads the encoder's output only: zero weights for any other head input (the goal)
        aux = model.aux[0]
        aux_w = torch.cat([aux.weight, aux.weight.new_zeros(aux.out_features, self.head_in - aux.in_features)], 1)
        first = (torch.cat([model.policy[0].weight, model.value[0].weight, aux_w]).T,
                 torch.cat([model.policy[0].bias, model.value[0].bias, aux.bias]))
        return [(conv1.weight.reshape(conv1.out_channels, -1).T, conv1.bias),
                (conv2.weight.permute(0, 2, 3, 1).reshape(channels, -1).T, conv2.bias),
                (dense_w.T, dense.bias), first,
                block_diagonal(model.policy[2], model.value[2]),
                block_diagonal(model.policy[4], model.value[4]),
                (model.aux[2].weight.T, model.aux[2].bias)]

    # ------------------------------------------------------------------ acting
    def views_of(self, key: str, shape: tuple[int, ...]) -> torch.Tensor:
        """``[L, num_steps, rows, *shape]`` float storage for view ``key``, each learner's part its rollout storage."""
        stored = self.storage.get(key)
        steps, rows = self.learners[0].ppo.num_steps, self.learners[0].rows
        if stored is None or stored.shape[3:] != shape:
            with torch.inference_mode(False):  # a normal tensor: the update reads it with autograd on
                stored = self.storage[key] = torch.empty(len(self.learners), steps, rows, *shape)
                self.parts[key] = list(stored)  # each learner's part, one tensor object each, kept
        for learner, part in zip(self.learners, self.parts[key]):
            if learner.views.get(key) is not part:  # (set once, unless something replaced it)
                learner.views[key] = part
        return stored

    @torch.inference_mode()
    def act(self, inputs: list[dict[str, torch.Tensor]]) -> list[tuple[np.ndarray, np.ndarray]]:
        """One step for every learner (``inputs`` in the order of ``learners``, each as for ``Learner.act``): each
        one's sampled actions ``[rows]`` and goal probabilities ``[rows, C]``, kept in its buffers as ``act`` keeps
        them."""
        enc, L, t = self.encoder, len(self.learners), self.learners[0].steps
        rows = self.learners[0].rows
        obs = inputs[0]["obs"][0]  # (every learner's board has this shape; a pack's trials have boards of their own)
        P = obs.shape[1]
        patches = self.views_of("patches", (enc.cells ** 2, P + 1, 9))
        coarse = self.views_of("coarse", (P * -(-obs.shape[2] // enc.pool) * -(-obs.shape[3] // enc.pool),))
        for i, x in enumerate(inputs):
            views.window_patches(x["obs"][0], x["me"][0], enc.radius, enc.cells, out=patches[i, t])
        board = None
        for i, x in enumerate(inputs):  # one coarse view per board: a trial's learners share theirs
            this = x["obs"][0]
            if board is not None and this.data_ptr() == board.data_ptr() and this.shape == board.shape:
                coarse[i, t] = coarse[i - 1, t]
            else:
                views.pooled(this, enc.pool, out=coarse[i, t])
            board = this
        sides = [learner.model.side_inputs(x["goal"], x["extras"], learner.identity)[0]
                 for learner, x in zip(self.learners, inputs)]
        (w1, b1), (w2, b2), (w3, b3), (wa, ba), (wb, bb), (wc, bc), (wg, bg) = self.weights
        h = torch.baddbmm(b1, patches[:, t].reshape(L, rows * enc.cells ** 2, -1), w1).relu_()
        h = h.view(L, rows, enc.cells ** 2, -1).index_select(2, enc.gather2)  # each output cell's 3x3 inputs
        h = torch.baddbmm(b2, h.view(L, rows * enc.out2 ** 2, -1), w2).relu_()
        x = torch.baddbmm(b3, torch.cat([h.view(L, rows, -1), coarse[:, t], torch.stack(sides)], dim=2), w3).relu_()
        if self.head_in > x.shape[2]:  # goal_fusion="heads": the goal joins the heads' input
            x = torch.cat([x, torch.stack([i["goal"][0] for i in inputs])], dim=2)
        a = torch.baddbmm(ba, x, wa).tanh_()  # [policy 64 | value 64 | goal 64]
        b = torch.baddbmm(bb, a[..., :wb.shape[1]], wb).tanh_()
        out = torch.baddbmm(bc, b, wc)  # [logits | value]
        goal_probs = torch.softmax(torch.baddbmm(bg, a[..., wb.shape[1]:], wg), dim=2)
        probs = torch.softmax(out[..., :self.num_actions], dim=2)
        actions = sample_from(probs, torch.stack([torch.rand(rows, 1, generator=lr.generator)
                                                  for lr in self.learners]))
        logp = torch.log(probs.gather(2, actions[..., None])[..., 0])
        values = out[..., self.num_actions]
        for i, (learner, x_i) in enumerate(zip(self.learners, inputs)):
            learner.keep(x_i, actions[i], logp[i], values[i])
        actions, goal_probs = actions.numpy(), goal_probs.numpy()
        return [(actions[i], goal_probs[i]) for i in range(L)]
