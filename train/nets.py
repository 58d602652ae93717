"""Actor-critic networks: the paper's architecture and a fast CPU default, optional LSTM, auxiliary goal head.

Every network maps one agent's observation to action logits, a value and goal logits
(the auxiliary head, whose softmax is the agent's belief over the goal). Inputs come as
``[T, B, ...]`` sequences so that the recurrent core can run whole rollouts (truncated BPTT);
feed-forward networks simply flatten the time axis.
"""

from __future__ import annotations

import dataclasses
from contextlib import contextmanager

import torch
from torch import nn
from torch.nn import functional as F

from colorgrid.config import EnvConfig
from train import views
from train.config import NetConfig


def extra_size(env: EnvConfig) -> int:
    """Last step's reward (1), every agent's action (one-hot) and collected color (one-hot)."""
    return 1 + env.num_agents * env.num_actions + env.num_agents * env.num_colors


def progress_size(env: EnvConfig) -> int:
    """``leader_progress``: one value per leader and color, after the extras (the belief core's only)."""
    return env.num_leaders * env.num_colors


def egocentric(obs: torch.Tensor, me: torch.Tensor, radius: int) -> torch.Tensor:
    """The ``(2r+1) x (2r+1)`` window of ``obs [N, P, H, W]`` centred on cell ``me [N, 2]``: ``[N, P + 1, 2r+1, 2r+1]``.

    The extra plane is 1 on the grid and 0 beyond the walls. Works on any dtype (uint8 is fastest).
    """
    windows = pad_board(obs, radius).unfold(2, 2 * radius + 1, 1).unfold(3, 2 * radius + 1, 1)  # a view
    return windows[torch.arange(obs.shape[0], device=obs.device), :, me[:, 0], me[:, 1]]  # [N, P+1, 2r+1, 2r+1]


def pad_board(obs: torch.Tensor, r: int) -> torch.Tensor:
    """``obs [N, P, H, W]`` padded with ``r`` cells of zeros, plus a plane that is 1 on the grid.

    Returns ``[N, P + 1, H + 2r, W + 2r]``."""
    N, P, H, W = obs.shape
    x = obs.new_zeros(N, P + 1, H + 2 * r, W + 2 * r)
    x[:, :P, r:r + H, r:r + W] = obs
    x[:, P, r:r + H, r:r + W] = 1
    return x


def goal_planes(blocks: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
    """From block planes ``[N, C, ...]`` and a goal vector ``g [N, C]`` (one-hot or a belief): two planes,
    ``[N, 2, ...]``: the (expected) goal-colored blocks and the rest. The goal becomes spatial."""
    weights = g.reshape(*g.shape, *([1] * (blocks.dim() - 2)))
    goal = (blocks * weights).sum(dim=1, keepdim=True)
    return torch.cat([goal, blocks.sum(dim=1, keepdim=True) - goal], dim=1)


class PaperEncoder(nn.Module):
    """conv 5->32->64->64 (3x3, stride 1, no padding, LeakyReLU), then three Tanh layers of 192.

    The side inputs (the goal one-hot, extras, a shared network's identity) join either the flattened conv
    features (``projected=False``: 43264 + side -> 192 -> 192 -> 192, as the paper's text lists it) or the
    first layer's output (``projected=True``: a ``projection`` 43264 -> 192, then 192 + side -> 192 -> 192,
    as the paper's code builds it: ``feature_linear(cat(projection_linear(flatten(conv(obs))), goal))``).
    """

    def __init__(self, env: EnvConfig, goal_in: int, planes: bool = False, projected: bool = False):
        super().__init__()
        P = env.num_colors + env.num_agents
        self.C, self.planes = env.num_colors, planes
        self.convs = nn.Sequential(
            nn.Conv2d(P + (2 if planes else 0), 32, 3), nn.LeakyReLU(), nn.Conv2d(32, 64, 3), nn.LeakyReLU(),
            nn.Conv2d(64, 64, 3), nn.LeakyReLU(), nn.Flatten())
        flat = 64 * (env.height - 6) * (env.width - 6)
        if projected:
            self.projection = nn.Sequential(nn.Linear(flat, 192), nn.Tanh())
            self.mlp = nn.Sequential(nn.Linear(192 + goal_in, 192), nn.Tanh(), nn.Linear(192, 192), nn.Tanh())
        else:
            self.projection = None
            self.mlp = nn.Sequential(nn.Linear(flat + goal_in, 192), nn.Tanh(), nn.Linear(192, 192), nn.Tanh(),
                                     nn.Linear(192, 192), nn.Tanh())
        self.out_size = 192

    def prepare(self, obs: torch.Tensor, me: torch.Tensor) -> dict[str, torch.Tensor]:
        return {"obs": obs}

    def forward(self, view: dict[str, torch.Tensor], side: torch.Tensor, g: torch.Tensor | None) -> torch.Tensor:
        x = view["obs"].float()
        if self.planes:
            x = torch.cat([x, goal_planes(x[:, :self.C], g)], dim=1)
        x = self.convs(x)
        if self.projection is not None:
            x = layers(self.projection, x)
        return layers(self.mlp, torch.cat([x, side], dim=1))


class FastEncoder(nn.Module):
    """CPU-friendly: an egocentric window downsampled 3x by its first conv, plus a coarse view of the whole board.

    * local: the ``(2r+1)^2`` window around the agent (r = 11), conv 3x3 stride 3 -> 16,
      conv 3x3 stride 2 -> 32 (translation-friendly: what is near the agent looks the same anywhere);
    * global: every plane average-pooled 4x4 (block densities and both agents, coarsely);
    * both, with the side inputs (goal, extras), through one ReLU layer of ``hidden`` units.

    The two convolutions are computed as matrix products on patches: the first conv's
    kernel equals its stride, so its patches do not overlap and are cut once per sample in
    ``prepare``; the second gathers its nine 3x3 patches from the first's output. This is the
    same function as ``self.convs`` (same weights; a test checks the two agree) but several
    times faster on a CPU than small strided convolutions, forward and backward.
    """

    radius = 11
    pool = 4

    def __init__(self, env: EnvConfig, goal_in: int, hidden: int, planes: bool = False):
        super().__init__()
        P = env.num_colors + env.num_agents
        self.C, self.P, self.planes = env.num_colors, P, planes
        extra = 2 if planes else 0
        self.convs = nn.Sequential(
            nn.Conv2d(P + 1 + extra, 16, 3, stride=3), nn.ReLU(), nn.Conv2d(16, 32, 3, stride=2), nn.ReLU(),
            nn.Flatten())
        side = 2 * self.radius + 1
        self.cells = side // 3  # first conv's output is cells x cells (7x7); its patches cover 3 * cells rows
        out2 = (self.cells - 3) // 2 + 1  # second conv's output side (3)
        local = 32 * out2 * out2
        # index of each (output cell, kernel cell) of the second conv into the first conv's cells x cells output
        rows = torch.arange(out2)[:, None, None, None] * 2 + torch.arange(3)[None, None, :, None]
        cols = torch.arange(out2)[None, :, None, None] * 2 + torch.arange(3)[None, None, None, :]
        self.register_buffer("gather2", (rows * self.cells + cols).reshape(-1), persistent=False)
        self.out2 = out2
        # offsets of the first conv's patches into the flattened padded board, in [cell, plane, 3x3] order
        height, width = env.height + 2 * self.radius, env.width + 2 * self.radius
        cell, kernel = torch.arange(self.cells) * 3, torch.arange(3)
        rows = cell[:, None, None, None, None] + kernel[None, None, None, :, None]  # [k, 1, 1, 3, 1]
        cols = cell[None, :, None, None, None] + kernel[None, None, None, None, :]  # [1, k, 1, 1, 3]
        planes = torch.arange(P + 1)[None, None, :, None, None]
        self.register_buffer("patch_offsets", (planes * height * width + rows * width + cols).reshape(-1),
                             persistent=False)
        coarse = (P + extra) * -(-env.height // self.pool) * -(-env.width // self.pool)
        self.mlp = nn.Sequential(nn.Linear(local + coarse + goal_in, hidden), nn.ReLU())
        self.out_size = hidden
        # for each window feature in cell-major order (how the second conv's product lays them out), its
        # channel-major column of the dense layer (how ``nn.Flatten`` lays them out)
        order = torch.arange(self.convs[2].out_channels)[None, :] * out2 * out2 + torch.arange(out2 * out2)[:, None]
        self.register_buffer("local_order", order.reshape(-1), persistent=False)

    def prepare(self, obs: torch.Tensor, me: torch.Tensor) -> dict[str, torch.Tensor]:
        """The network's view of ``obs [N, P, H, W]``: computed once per sample, reused by every epoch.

        ``patches [N, cells^2, P + 1, 9]`` (float): the egocentric window (``egocentric``) cut
        into the first conv's 3x3 patches; ``coarse [N, P * ceil(H/4) * ceil(W/4)]`` (float): every
        plane average-pooled. Float, because PPO epochs reuse it: converting once per sample is
        cheaper than once per minibatch. A uint8 board on the CPU is cut by compiled kernels
        (``train.views``), anything else by tensor ops (``prepare_with_tensor_ops``): the same values.
        """
        if obs.device.type == "cpu" and obs.dtype == torch.uint8:  # one compiled pass each (train/views.py)
            return {"patches": views.window_patches(obs, me, self.radius, self.cells),
                    "coarse": views.pooled(obs, self.pool)}
        return self.prepare_with_tensor_ops(obs, me)

    def prepare_with_tensor_ops(self, obs: torch.Tensor, me: torch.Tensor) -> dict[str, torch.Tensor]:
        """``prepare`` with tensor ops on any device and dtype (the same values: a test checks)."""
        N, P = obs.shape[:2]
        padded = pad_board(obs, self.radius)
        # the window's top-left corner in padded coordinates is the agent's own cell
        corner = me[:, 0] * padded.shape[3] + me[:, 1]
        index = corner[:, None] + self.patch_offsets[None]
        patches = padded.reshape(N, -1).gather(1, index).reshape(N, self.cells ** 2, P + 1, 9)
        return {"patches": patches.float(),
                "coarse": F.avg_pool2d(obs.float(), self.pool, ceil_mode=True).flatten(1)}

    def local(self, patches: torch.Tensor) -> torch.Tensor:
        """``self.convs`` on the window, from its patches ``[N, cells^2, channels, 9]`` (float): ``[N, 32 * 3 * 3]``,
        cell-major (each output cell's 32 channels in turn, as the second conv's product lays them out;
        ``nn.Flatten``'s channel-major column of each is ``local_order``)."""
        N, cells = patches.shape[:2]
        conv1, conv2 = self.convs[0], self.convs[2]
        # ``addmm`` on the transposed weight: autograd forms the weight's gradient as patches^T x grad, the faster of
        # the two layouts at the update's shape (16 output columns)
        x = torch.addmm(conv1.bias, patches.reshape(N * cells, -1), conv1.weight.reshape(conv1.out_channels, -1).T)
        x = x.relu_().view(N, cells, -1).index_select(1, self.gather2)  # [N, out2^2 * 9, 16]: each cell's 3x3 inputs
        w2 = conv2.weight.permute(0, 2, 3, 1).reshape(conv2.out_channels, -1)  # (kh, kw, c) order, as gathered
        return torch.addmm(conv2.bias, x.view(N * self.out2 ** 2, -1), w2.T).relu_().view(N, -1)

    def forward(self, view: dict[str, torch.Tensor], side: torch.Tensor, g: torch.Tensor | None) -> torch.Tensor:
        """The dense layer on ``[local | coarse | side]`` as two products: the window's part on its own, so that
        autograd forms an input gradient for the window's 288 features only, not for the ~320 others (functions of
        the observation, which need none)."""
        patches, coarse = view["patches"], view["coarse"]
        if self.planes:
            patches = torch.cat([patches, goal_planes(patches[:, :, :self.C].transpose(1, 2), g).transpose(1, 2)],
                                dim=2)
            grid = coarse.reshape(coarse.shape[0], self.P, -1)
            coarse = torch.cat([coarse, goal_planes(grid[:, :self.C], g).flatten(1)], dim=1)
        window_w, rest_w = self.dense_weights()
        rest = F.linear(join([coarse, side], dim=1), rest_w, self.mlp[0].bias)
        return torch.addmm(rest, self.local(patches), window_w.T).relu_()

    def dense_weights(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The dense layer's weight in two parts: the columns of the window's features in ``local``'s cell-major
        order, and the columns of the other inputs (coarse view, side inputs)."""
        weight = self.mlp[0].weight
        return weight.index_select(1, self.local_order), weight[:, len(self.local_order):]


def layers(stack: nn.Sequential, x: torch.Tensor) -> torch.Tensor:
    """``stack(x)`` for a stack of ``Linear``, ``ReLU`` and ``Tanh`` layers (others are called as usual), through
    the functions those layers call: the same tensor, without ``nn.Module``'s call overhead (about 8 us a layer
    on this project's CPU, as much as a layer's own arithmetic at a rollout's batch of 16)."""
    for layer in stack:
        kind = type(layer)
        if kind is nn.Linear:
            x = F.linear(x, layer.weight, layer.bias)
        elif kind is nn.Tanh:
            x = torch.tanh(x)
        elif kind is nn.ReLU and not layer.inplace:
            x = torch.relu(x)
        else:
            x = layer(x)
    return x


def join(tensors: list[torch.Tensor], dim: int) -> torch.Tensor:
    """``torch.cat``, skipping empty parts and the copy when only one is left (rollouts run small steps)."""
    parts = [t for t in tensors if t.shape[dim]]
    return parts[0] if len(parts) == 1 else torch.cat(parts or tensors, dim=dim)


def _head(n_in: int, n_out: int, gain: float) -> nn.Sequential:
    head = nn.Sequential(nn.Linear(n_in, 64), nn.Tanh(), nn.Linear(64, 64), nn.Tanh(), nn.Linear(64, n_out))
    nn.init.orthogonal_(head[-1].weight, gain)
    nn.init.zeros_(head[-1].bias)
    return head


class ActorCritic(nn.Module):
    """Encoder -> optional LSTM -> policy, value and auxiliary goal heads.

    With ``goal_fusion="planes"`` and ``belief_input`` (an assistant that does not see the
    goal), the LSTM is a *belief core* over the last-step inputs: its goal head's (detached)
    softmax weights the block planes the encoder sees, so the follower looks at the board
    through what it believes the goal is.

    ``agents`` is the agent index the network plays, or a tuple of two or more indices that
    share it (parameter sharing within a role): each then gets its position in the tuple as a
    one-hot input (``identity``), joined to the encoder's side inputs, so that one network can
    act differently for each of them.
    """

    def __init__(self, net: NetConfig, env: EnvConfig, agents: int | tuple[int, ...]):
        super().__init__()
        self.net, self.env = net, env
        self.stepwise = False  # the LSTM step by step (``recurrence_by_steps``: what ``torch.func.vmap`` can batch)
        self.agents = tuple(int(a) for a in agents) if isinstance(agents, (tuple, list)) else (int(agents),)
        self.shared = len(self.agents) > 1
        C = env.num_colors
        planes = net.goal_fusion == "planes"
        self.belief_core = planes and net.belief_input
        side = ((C if self.goal_in_trunk else 0) + (extra_size(env) if net.extra_inputs else 0)
                + (len(self.agents) if self.shared else 0))
        self.encoder = (PaperEncoder(env, side, planes, projected=net.goal_fusion == "projected")
                        if net.arch == "paper" else FastEncoder(env, side, net.hidden, planes))
        core = self.encoder.out_size
        self.lstm = None
        if net.lstm:
            core_in = extra_size(env) + (progress_size(env) if net.leader_progress else 0)
            self.lstm = nn.LSTM(core_in if self.belief_core else core, net.lstm_size)
        aux_in = net.lstm_size if net.lstm else core
        if net.lstm and not self.belief_core:
            core = net.lstm_size
        head_in = core + (C if net.goal_fusion == "heads" else 0) + (C if net.belief_input else 0)
        self.policy = _head(head_in, env.num_actions, 0.01)
        self.value = _head(head_in, 1, 1.0)
        self.aux = nn.Sequential(nn.Linear(aux_in, 64), nn.Tanh(), nn.Linear(64, C))

    @property
    def goal_in_trunk(self) -> bool:
        """Whether the goal one-hot joins the encoder's side inputs (``flat`` or ``projected`` fusion)."""
        return self.net.goal_fusion in ("flat", "projected")

    @property
    def agent_index(self) -> int:
        """The agent this network plays (the first of those sharing it)."""
        return self.agents[0]

    def identity(self, agents: tuple[int, ...], batch: int, device=None) -> torch.Tensor | None:
        """``[1, len(agents) * batch, k]``: for rows of ``batch`` envs per agent (agent-major), the one-hot of each
        row's agent among the ``k`` sharing this network; None for a network of one agent (it needs none)."""
        if not self.shared:
            return None
        slots = torch.tensor([self.agents.index(a) for a in agents], device=device).repeat_interleave(batch)
        return F.one_hot(slots, len(self.agents)).float()[None]

    def _recur(self, x, starts, state):
        """Run the LSTM over ``x [T, B, F]`` in segments that start where any env starts an episode (step by step
        under ``recurrence_by_steps``)."""
        if self.stepwise:
            return lstm_by_steps(self.lstm, x, starts, state)
        T = x.shape[0]
        bounds = sorted({0, *torch.nonzero(starts.any(dim=1)).flatten().tolist(), T})
        h, c = state
        outs = []
        for t0, t1 in zip(bounds[:-1], bounds[1:]):
            keep = (~starts[t0]).float()[None, :, None]
            out, (h, c) = self.lstm(x[t0:t1], (h * keep, c * keep))
            outs.append(out)
        return torch.cat(outs, dim=0), (h, c)

    def initial_state(self, batch: int, device=None) -> tuple[torch.Tensor, torch.Tensor] | None:
        if self.lstm is None:
            return None
        zeros = torch.zeros(1, batch, self.net.lstm_size, device=device)
        return (zeros, zeros.clone())

    def prepare(self, obs: torch.Tensor, me: torch.Tensor, identity: torch.Tensor | None = None
                ) -> dict[str, torch.Tensor]:
        """``obs [T, B, P, H, W]`` (uint8) and own cell ``me [T, B, 2]`` to the encoder's input view, ``[T, B, ...]``;
        a shared network's view also holds each row's ``identity [T, B, k]`` (see ``identity``)."""
        T, B = obs.shape[:2]
        view = self.encoder.prepare(obs.reshape(T * B, *obs.shape[2:]), me.reshape(T * B, 2))
        view = {k: v.reshape(T, B, *v.shape[1:]) for k, v in view.items()}
        if self.shared:
            if identity is None:
                raise ValueError(f"this network is shared by agents {list(self.agents)}: say which one each row is "
                                 f"(ActorCritic.identity)")
            view["identity"] = identity
        return view

    def side_inputs(self, goal: torch.Tensor, extras: torch.Tensor, identity: torch.Tensor | None) -> torch.Tensor:
        """What joins the encoder's features, ``[T, B, k]``: the goal (``goal_in_trunk``), the extras and a shared
        network's row identity, each where the network takes it."""
        side = []
        if self.goal_in_trunk:
            side.append(goal)
        if self.net.extra_inputs:  # with leader_progress, the extras' tail is the belief core's alone
            side.append(extras[..., :extra_size(self.env)] if self.net.leader_progress else extras)
        if self.shared:
            side.append(identity)
        return join(side, dim=2) if side else goal.new_zeros(*goal.shape[:2], 0)

    def forward(self, view, goal, extras, starts, state):
        """``view`` from ``prepare``; all inputs ``[T, B, ...]``. Returns ``(logits, value, goal_logits, state)``.

        ``starts [T, B]`` marks the first step of an episode: the recurrent state is zeroed
        there, so sequences that span an episode boundary stay correct.
        """
        T, B = goal.shape[:2]
        side = self.side_inputs(goal, extras, view.get("identity"))
        flat = {k: v.reshape(T * B, *v.shape[2:]) for k, v in view.items()}
        goal_logits, g = None, goal
        if self.belief_core:
            b, state = self._recur(extras, starts, state)
            goal_logits = layers(self.aux, b)
            g = torch.softmax(goal_logits, dim=2).detach()
        x = self.encoder.forward(flat, side.reshape(T * B, -1), g.reshape(T * B, -1)).reshape(T, B, -1)
        if self.lstm is not None and not self.belief_core:
            x, state = self._recur(x, starts, state)
        if goal_logits is None:
            goal_logits = layers(self.aux, x)
        heads = [x]
        if self.net.goal_fusion == "heads":
            heads.append(goal)
        if self.net.belief_input:
            heads.append(torch.softmax(goal_logits, dim=2).detach())
        h = join(heads, dim=2)
        return layers(self.policy, h), layers(self.value, h)[..., 0], goal_logits, state


def lstm_by_steps(lstm: nn.LSTM, x: torch.Tensor, starts: torch.Tensor, state: tuple[torch.Tensor, torch.Tensor]
                  ) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
    """``lstm`` over ``x [T, B, F]`` one step at a time, the state zeroed in each row at its episode starts
    (``starts [T, B]``): what ``ActorCritic._recur`` computes with ``nn.LSTM`` on segments (the same gates, to float
    rounding), with no control flow that depends on the data, so ``torch.func.vmap`` batches it over networks."""
    h, c = state  # [1, B, H] each
    gates_in = F.linear(x, lstm.weight_ih_l0, lstm.bias_ih_l0)  # [T, B, 4H]: the input's part, all steps at once
    outs = []
    for t in range(x.shape[0]):
        keep = (~starts[t]).to(x.dtype)[None, :, None]
        h, c = h * keep, c * keep
        i, f, g, o = (gates_in[t][None] + F.linear(h, lstm.weight_hh_l0, lstm.bias_hh_l0)).chunk(4, dim=-1)
        c = torch.sigmoid(f) * c + torch.sigmoid(i) * torch.tanh(g)
        h = torch.sigmoid(o) * torch.tanh(c)
        outs.append(h)
    return torch.cat(outs, dim=0), (h, c)


@contextmanager
def recurrence_by_steps(model: "ActorCritic"):
    """Within: ``model``'s LSTM runs step by step (``lstm_by_steps``), as ``torch.func.vmap`` needs (it has no
    batching rule for ``aten::lstm``, and segments split where episodes start depend on the data)."""
    before, model.stepwise = model.stepwise, True
    try:
        yield model
    finally:
        model.stepwise = before


def with_leader_progress(model: ActorCritic) -> ActorCritic:
    """The same network with ``net.leader_progress`` added: the belief core's new input weights are zero, so it
    computes exactly what ``model`` does until training gives them weight (a warm start for the new input)."""
    if model.net.leader_progress or not model.belief_core:
        raise ValueError(f"leader_progress is added to a belief core without it; this network is {model.net}")
    wider = ActorCritic(dataclasses.replace(model.net, leader_progress=True), model.env,
                        model.agents if model.shared else model.agents[0])
    state = model.state_dict()
    old = state["lstm.weight_ih_l0"]
    new = torch.zeros_like(wider.state_dict()["lstm.weight_ih_l0"])
    new[:, :old.shape[1]] = old
    wider.load_state_dict({**state, "lstm.weight_ih_l0": new})
    return wider


def count_parameters(module: nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())
