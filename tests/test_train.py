"""The IPPO trainer: golden values for GAE and the losses, architecture, recurrence, resume, presets, partners."""

import dataclasses
import json
import math
import os
import re
import signal
import subprocess
import sys
import threading
import time
from multiprocessing import forkserver
from pathlib import Path

import numpy as np
import pytest
import torch

from colorgrid import EnvConfig
from colorgrid.policies import make_policy
from colorgrid.rollout import run_episodes
from train.checkpoint import export_agent, load_checkpoint
from train.config import (NetConfig, TrainConfig, TrainConfigError, from_dict, load_preset, merge,
                          parse_override, preset_names)
from train.learner import sample
from train.nets import ActorCritic, FastEncoder, count_parameters, egocentric, goal_planes, layers
from train.policy import load_policy
from train.ppo import LossWeights, compute_gae, ppo_loss
from train import update_process
from train.trainer import Trainer

TINY = {"ppo": {"num_envs": 4, "num_steps": 16, "num_minibatches": 2, "update_epochs": 2},
        "eval_every": 0, "save_every": 2, "env": {"horizon": 12}}


def tiny(**changes) -> TrainConfig:
    return from_dict(merge(TINY, changes))


def weights(model) -> dict:
    return {k: v.detach().clone() for k, v in model.state_dict().items()}


# ---------------------------------------------------------------- pure functions
def test_gae_golden_values_with_an_episode_boundary():
    rewards = torch.tensor([[1.0], [0.0], [2.0]])
    values = torch.tensor([[0.5], [0.4], [0.3]])
    next_values = torch.tensor([[0.4], [0.9], [0.2]])  # t=1 ended an episode: V(final obs) = 0.9
    dones = torch.tensor([[False], [True], [False]])
    adv, ret = compute_gae(rewards, values, next_values, dones, gamma=0.9, lam=0.8)
    # delta2 = 2 + .9*.2 - .3 = 1.88; delta1 = .9*.9 - .4 = .41 (trace cut); delta0 = 1 + .9*.4 - .5 = .86
    assert adv[:, 0].tolist() == pytest.approx([0.86 + 0.9 * 0.8 * 0.41, 0.41, 1.88])
    assert ret[:, 0].tolist() == pytest.approx([1.6552, 0.81, 2.18])


def test_ppo_loss_golden_values():
    logits = torch.zeros(2, 2)  # new policy: 0.5 / 0.5
    actions = torch.tensor([0, 1])
    old_logp = torch.log(torch.tensor([0.25, 0.5]))  # ratios 2 and 1
    w = LossWeights(clip_coef=0.2, clip_vloss=True, ent_coef=0.01, vf_coef=0.5, aux_coef=0.2, norm_adv=False)
    total, s = ppo_loss(logits, torch.tensor([1.0, 0.0]), torch.zeros(2, 3), actions, old_logp,
                        old_values=torch.tensor([0.5, 0.0]), advantages=torch.tensor([1.0, -1.0]),
                        returns=torch.tensor([2.0, 1.0]), goal=torch.tensor([0, 2]), w=w)
    assert float(s["policy_loss"]) == pytest.approx(-0.1)  # mean(max(-2, -1.2), max(1, 1))
    assert float(s["value_loss"]) == pytest.approx(0.6725)  # 0.5 * mean(max(1, 1.69), max(1, 1))
    assert float(s["entropy"]) == pytest.approx(math.log(2))
    assert float(s["aux_loss"]) == pytest.approx(math.log(3))
    assert float(s["approx_kl"]) == pytest.approx((1 - math.log(2)) / 2)
    assert float(s["clip_frac"]) == pytest.approx(0.5)
    assert float(total) == pytest.approx(-0.1 - 0.01 * math.log(2) + 0.5 * 0.6725 + 0.2 * math.log(3))


def test_paper_architecture_parameter_count():
    model = ActorCritic(NetConfig(arch="paper"), EnvConfig(), 0)
    assert count_parameters(model) == 8_484_360


def test_the_paper_codes_fusion_joins_the_goal_after_the_projection():
    """``projected``: 43264 -> 192 (Tanh), then 192 + goal -> 192 -> 192, as the paper's code builds it; the
    goal reaches the features only through the second layer's last columns."""
    model = ActorCritic(NetConfig(arch="paper", goal_fusion="projected"), EnvConfig(), 0)
    shapes = {k: tuple(v.shape) for k, v in model.state_dict().items() if k.startswith("encoder.")}
    assert shapes["encoder.projection.0.weight"] == (192, 43264) and shapes["encoder.mlp.0.weight"] == (192, 195)
    assert shapes["encoder.mlp.2.weight"] == (192, 192) and "encoder.mlp.4.weight" not in shapes
    assert count_parameters(model) == 8_484_360
    obs = torch.randint(0, 2, (1, 2, 5, 32, 32), dtype=torch.uint8)
    view = model.prepare(obs, torch.zeros(1, 2, 2, dtype=torch.long))
    goals = torch.eye(3)[[0, 2]][None]
    logits, *_ = model(view, goals, torch.zeros(1, 2, 0), torch.zeros(1, 2, dtype=torch.bool), None)
    with torch.no_grad():
        model.encoder.mlp[0].weight[:, 192:] = 0  # without the goal's columns, the goal changes nothing
        blind, *_ = model(view, goals, torch.zeros(1, 2, 0), torch.zeros(1, 2, dtype=torch.bool), None)
        same, *_ = model(view, goals.flip(2), torch.zeros(1, 2, 0), torch.zeros(1, 2, dtype=torch.bool), None)
    assert not torch.allclose(logits, blind) and torch.equal(blind, same)


def test_old_fusion_names_still_load_as_what_they_did():
    assert NetConfig(goal_fusion="early").goal_fusion == "flat"
    assert NetConfig(arch="paper", goal_fusion="late").goal_fusion == "heads"
    early, flat = (ActorCritic(NetConfig(arch="paper", goal_fusion=f), EnvConfig(), 0) for f in ("early", "flat"))
    late = ActorCritic(NetConfig(goal_fusion="late"), EnvConfig(), 0)
    assert {k: v.shape for k, v in early.state_dict().items()} == {k: v.shape for k, v in flat.state_dict().items()}
    assert late.policy[0].in_features == 128 + 3  # the goal joins at the heads
    # the shipped leader's checkpoint names its idle partner's network "early"
    saved = load_checkpoint(Path(__file__).resolve().parents[1] / "checkpoints" / "leader.pt")
    assert saved["config"]["follower"]["net"]["goal_fusion"] == "early"
    assert TrainConfig.from_dict(saved["config"]).follower.net.goal_fusion == "flat"
    with pytest.raises(ValueError, match="'projected' joins the goal after the paper network's"):
        NetConfig(goal_fusion="projected")
    assert all(from_dict(load_preset(name)).section(role).net.goal_fusion == "projected"
               for name in preset_names() if name.startswith("paper_") for role in ("leader", "follower"))


def test_egocentric_window_centres_the_agent_and_marks_walls():
    obs = torch.zeros(1, 5, 8, 8, dtype=torch.uint8)
    obs[0, 0, 0, 1] = 1  # a red block at (0, 1)
    win = egocentric(obs, torch.tensor([[0, 0]]), radius=3)  # agent in the top-left corner
    assert win.shape == (1, 6, 7, 7)
    assert win[0, 0, 3, 4] == 1  # one column right of the centre
    assert win[0, 5, :3].sum() == 0 and win[0, 5, :, :3].sum() == 0  # off-grid rows and columns
    assert win[0, 5, 3:, 3:].all()


@pytest.mark.parametrize("planes", [False, True])
def test_fast_encoder_patches_compute_its_convolutions_exactly(planes):
    """The patch/matmul form of the fast network's convs is the same function as the convs on the window."""
    torch.manual_seed(0)
    enc = FastEncoder(EnvConfig(), goal_in=3, hidden=32, planes=planes)
    obs = (torch.rand(40, 5, 32, 32) < 0.2).to(torch.uint8)
    me = torch.stack([torch.arange(40) % 32, (torch.arange(40) * 7) % 32], dim=1)  # corners and edges included
    g = torch.softmax(torch.randn(40, 3), dim=1)
    window = egocentric(obs, me, enc.radius)
    patches = enc.prepare(obs, me)["patches"]
    cut = window[:, :, :21, :21].reshape(40, 6, 7, 3, 7, 3).permute(0, 2, 4, 1, 3, 5).reshape(40, 49, 6, 9)
    assert torch.equal(patches, cut)
    window, patches = window.float(), patches.float()
    if planes:
        window = torch.cat([window, goal_planes(window[:, :3], g)], dim=1)
        patches = torch.cat([patches, goal_planes(patches[:, :, :3].transpose(1, 2), g).transpose(1, 2)], dim=2)
    reference = enc.convs(window)[:, enc.local_order]  # local() gives the window's features cell-major
    assert reference.abs().sum() > 0
    assert torch.allclose(enc.local(patches), reference, atol=1e-5)
    grads = []
    for out in (enc.local(patches), enc.convs(window)[:, enc.local_order]):
        enc.zero_grad()
        (out * torch.linspace(-1, 1, out.shape[1])).sum().backward()
        grads.append(torch.cat([p.grad.flatten() for p in enc.convs.parameters()]))
    assert torch.allclose(grads[0], grads[1], atol=1e-4)


@pytest.mark.parametrize("planes", [False, True])
def test_fast_encoder_computes_the_modules_and_their_gradients(planes):
    """The fast encoder's forward (convs as products on patches, the dense layer in two parts) and its gradients are
    those of nn.Conv2d, nn.Flatten and nn.Linear on the window, for every parameter, in float64 (no rounding to hide
    in)."""
    torch.manual_seed(1)
    enc = FastEncoder(EnvConfig(), goal_in=3, hidden=32, planes=planes).double()
    obs = (torch.rand(24, 5, 32, 32) < 0.2).to(torch.uint8)
    me = torch.stack([torch.arange(24) % 32, (torch.arange(24) * 5) % 32], dim=1)
    view = {k: v.double() for k, v in enc.prepare(obs, me).items()}
    side = torch.randn(24, 3, dtype=torch.float64)
    g = torch.softmax(torch.randn(24, 3, dtype=torch.float64), dim=1)

    def through_modules():
        window = egocentric(obs, me, enc.radius).double()
        coarse = view["coarse"]
        if planes:
            window = torch.cat([window, goal_planes(window[:, :3], g)], dim=1)
            coarse = torch.cat([coarse, goal_planes(coarse.reshape(24, 5, -1)[:, :3], g).flatten(1)], dim=1)
        return enc.mlp(torch.cat([enc.convs(window), coarse, side], dim=1))

    outs, grads = [], []
    for run in (through_modules, lambda: enc(view, side, g)):
        enc.zero_grad()
        out = run()
        (out * torch.linspace(-1, 1, out.shape[1], dtype=torch.float64)).sum().backward()
        outs.append(out)
        grads.append({name: p.grad.clone() for name, p in enc.named_parameters()})
    assert (outs[0] > 0).float().mean() > 0.2  # a live ReLU layer: gradients flow through it
    assert torch.allclose(outs[0], outs[1], rtol=0, atol=1e-12)
    for name, grad in grads[0].items():
        assert grad.abs().sum() > 0, name
        assert torch.allclose(grads[1][name], grad, rtol=0, atol=1e-12), name


def test_layers_compute_what_the_modules_do_to_the_bit():
    """``layers`` (the networks' stacks without nn.Module's call overhead) is each stack called as a module,
    forward and backward, for every layer kind it shortcuts and one it calls as usual."""
    torch.manual_seed(0)
    stack = torch.nn.Sequential(torch.nn.Linear(7, 16), torch.nn.Tanh(), torch.nn.Linear(16, 16), torch.nn.ReLU(),
                                torch.nn.LeakyReLU(), torch.nn.Linear(16, 3))
    x = torch.randn(2, 5, 7)
    outs, grads = [], []
    for run in (stack, lambda t: layers(stack, t)):
        stack.zero_grad()
        out = run(x)
        (out * torch.linspace(-1, 1, 3)).sum().backward()
        outs.append(out)
        grads.append([p.grad.clone() for p in stack.parameters()])
    assert torch.equal(outs[0], outs[1])
    assert all(torch.equal(a, b) for a, b in zip(*grads))


@pytest.mark.parametrize("height, width", [(32, 32), (30, 27), (5, 7)])
def test_compiled_fast_view_equals_the_tensor_ops(height, width):
    """The fast network's view cut by train.views' kernels is the tensor ops' to the bit, pooled edges included."""
    enc = FastEncoder(EnvConfig(height=height, width=width, block_density=0.3), goal_in=3, hidden=8)
    generator = torch.Generator().manual_seed(height * width)
    obs = (torch.rand(50, 5, height, width, generator=generator) < 0.4).to(torch.uint8)
    me = torch.stack([torch.randint(0, height, (50,), generator=generator),
                      torch.randint(0, width, (50,), generator=generator)], dim=1)
    compiled, reference = enc.prepare(obs, me), enc.prepare_with_tensor_ops(obs, me)
    assert compiled.keys() == reference.keys()
    for key, value in compiled.items():
        assert value.dtype == reference[key].dtype and torch.equal(value, reference[key]), key


def test_sampled_actions_follow_the_probabilities():
    probs = torch.tensor([[0.1, 0.2, 0.0, 0.7]]).repeat(40_000, 1)
    actions = sample(probs, torch.Generator().manual_seed(0))
    freq = torch.bincount(actions, minlength=4).float() / len(actions)
    assert freq[2] == 0  # an action of probability 0 is never drawn
    assert torch.allclose(freq, probs[0], atol=0.01)  # 0.01 is over 4 standard errors at 40,000 draws


MINIBATCHES = """
import resource, sys, torch
from torch import nn
from train.memory import keep_freed_memory
if sys.argv[1] == "keep":
    assert keep_freed_memory()
torch.set_num_threads(1)
faults = lambda: resource.getrusage(resource.RUSAGE_SELF).ru_minflt
net = nn.Sequential(nn.Conv2d(5, 32, 3), nn.LeakyReLU(), nn.Conv2d(32, 64, 3), nn.LeakyReLU(), nn.Conv2d(64, 64, 3),
                    nn.Flatten(), nn.Linear(43264, 8))  # the paper encoder's convs: ~50 MB of activations at 256
x = torch.rand(256, 5, 32, 32)
per_minibatch = []
for _ in range(5):
    before = faults()
    net(x).sum().backward()
    per_minibatch.append(faults() - before)
print(per_minibatch)
"""


def test_keeping_freed_memory_stops_page_faults_in_paper_sized_minibatches():
    """glibc unmaps large freed blocks, so every minibatch faults its activations in again; kept, they are reused."""
    def faults(mode: str) -> list[int]:
        out = subprocess.run([sys.executable, "-c", MINIBATCHES, mode], capture_output=True, text=True, check=True)
        return json.loads(out.stdout)

    default, kept = faults("default"), faults("keep")
    assert min(default[1:]) > 50_000  # ~200,000 a minibatch (one per 4 kB page of activations)
    assert sorted(kept[1:])[1] < 1_000 and sum(kept[1:]) < sum(default[1:]) / 10, (default, kept)
    with pytest.raises(TrainConfigError, match="keep_freed_memory='yes' is invalid: true or false"):
        tiny(keep_freed_memory="yes")


# ----------------------------------------------------------------- recurrence
@pytest.mark.parametrize("fusion", ["early", "planes"])  # LSTM core, or LSTM belief core feeding goal planes
def test_lstm_log_probs_recomputed_at_update_match_the_rollout(fusion):
    config = tiny(leader={"policy": "astar"},
                  follower={"net": {"lstm": True, "extra_inputs": True, "belief_input": True, "goal_fusion": fusion}},
                  ppo={"num_steps": 30})  # horizon 12: episodes start inside the rollout
    trainer = Trainer(config, "unused", progress=False, tensorboard=False)
    trainer.collect_rollout()
    trainer.collect_rollout()  # the second rollout starts mid-episode, from a carried state
    learner = trainer.learners[1]
    b = learner.stacked()
    assert b["starts"].any() and not b["starts"][0].all()
    with torch.no_grad():
        logits, values, _, _ = learner.model(b["view"], b["goal"], b["extras"], b["starts"], learner.initial_state)
    logp = torch.log_softmax(logits, dim=2).gather(2, b["actions"][..., None])[..., 0]
    torch.testing.assert_close(logp, b["logp"], atol=1e-5, rtol=0)
    torch.testing.assert_close(values, b["values"], atol=1e-5, rtol=0)
    # without the recurrent state carried in, the recomputation would differ
    with torch.no_grad():
        _, cold, cold_goal, _ = learner.model(b["view"], b["goal"], b["extras"], b["starts"], learner.model.initial_state(4))
    _, _, warm_goal, _ = learner.model(b["view"], b["goal"], b["extras"], b["starts"], learner.initial_state)
    assert not torch.allclose(cold_goal[0], warm_goal[0], atol=1e-5)


# --------------------------------------------------------------------- runs
def straight_and_resumed(tmp_path, changes: dict) -> tuple[Trainer, Trainer]:
    """A run of 4 iterations in ``tmp_path/a``, and one stopped after 2 and resumed in ``tmp_path/b``."""
    straight = Trainer(tiny(**changes), tmp_path / "a", progress=False, tensorboard=False)
    straight.train()
    first = Trainer(tiny(**{**changes, "total_steps": 2 * 64}), tmp_path / "b", progress=False, tensorboard=False)
    first.train()
    resumed = Trainer(tiny(**changes), tmp_path / "b", progress=False, tensorboard=False)
    resumed.restore(tmp_path / "b" / "checkpoints" / "latest.pt")
    assert resumed.step == 128
    resumed.train()
    return straight, resumed


def test_resume_continues_exactly_like_an_uninterrupted_run(tmp_path):
    changes = dict(leader={"policy": "astar"}, follower={"net": {"lstm": True, "extra_inputs": True}},
                   schedule={"penalty_start": 0, "penalty_end": 200}, total_steps=4 * 64)
    straight, resumed = straight_and_resumed(tmp_path, changes)
    for key, value in weights(straight.learners[1].model).items():
        assert torch.equal(value, resumed.learners[1].model.state_dict()[key]), key
    rows = lambda d: [json.loads(x) for x in (d / "metrics.jsonl").read_text().splitlines()]  # noqa: E731
    timing = lambda k: "sps" in k or k == "wall_time_s"  # noqa: E731
    drop = lambda r: {k: v for k, v in r.items() if not timing(k)}  # noqa: E731
    assert [drop(r) for r in rows(tmp_path / "a")] == [drop(r) for r in rows(tmp_path / "b")]
    times = [r["wall_time_s"] for r in rows(tmp_path / "b") if r["stream"] == "train"]
    assert len(times) == 4 and all(b > a > 0 for a, b in zip(times, times[1:]))  # carried across the resume


def test_two_learners_updating_side_by_side_match_one_after_the_other(tmp_path):
    """Two torch threads: the follower updates in a process of its own (the default) or on a second thread; either
    way two iterations' updates leave the weights, optimizer states, generators and statistics of the learners
    updated one after the other at one torch thread, bit for bit."""
    threads = torch.get_num_threads()
    config = tiny(threads=2, follower={"net": {"lstm": True}})
    trainers = {name: Trainer(dataclasses.replace(config, update_processes=name != "threads"), tmp_path / name,
                              progress=False, tensorboard=False) for name in ("processes", "threads", "in_turn")}
    results = {name: [] for name in trainers}
    try:
        for _ in range(2):
            for name, trainer in trainers.items():
                trainer.collect_rollout()
                torch.set_num_threads(1 if name == "in_turn" else 2)
                results[name].append(trainer._update_learners())
                torch.set_num_threads(threads)
        payloads = {name: trainer.checkpoint_payload() for name, trainer in trainers.items()}
        assert set(trainers["processes"]._processes) == {1} and trainers["processes"]._processes[1].process.is_alive()
        assert trainers["threads"]._pool is not None and not trainers["threads"]._processes
        assert trainers["in_turn"]._pool is None and not trainers["in_turn"]._processes  # each path was taken
    finally:
        torch.set_num_threads(threads)
        for trainer in trainers.values():
            trainer.close()
    assert not trainers["processes"]._processes
    expected = payloads["in_turn"]
    for name in ("processes", "threads"):
        assert results[name] == results["in_turn"], name
        for agent, entry in expected["agents"].items():
            got = payloads[name]["agents"][agent]
            for key, value in entry["state_dict"].items():
                assert torch.equal(got["state_dict"][key], value), (name, agent, key)
            for p, state in entry["optimizer"]["state"].items():
                for key, value in state.items():
                    assert torch.equal(got["optimizer"]["state"][p][key], value), (name, agent, p, key)
        for learner, state in expected["trainer_state"]["learners"].items():
            assert torch.equal(payloads[name]["trainer_state"]["learners"][learner]["generator"], state["generator"])


def test_resume_with_the_follower_updating_in_its_process_continues_exactly(tmp_path):
    """Two torch threads, both agents learning (stacked acting, the follower's update in its process): the optimizer
    state saved from the process and restored into a new one gives the uninterrupted run's weights and metrics."""
    threads = torch.get_num_threads()
    used = []
    try:
        changes = dict(threads=2, total_steps=4 * 64, schedule={"penalty_start": 0, "penalty_end": 200})
        straight = Trainer(tiny(**changes), tmp_path / "a", progress=False, tensorboard=False)
        straight.train(lambda row, saved: used.append(sorted(straight._processes)))
        first = Trainer(tiny(**{**changes, "total_steps": 2 * 64}), tmp_path / "b", progress=False, tensorboard=False)
        first.train()
        resumed = Trainer(tiny(**changes), tmp_path / "b", progress=False, tensorboard=False)
        resumed.restore(tmp_path / "b" / "checkpoints" / "latest.pt")
        resumed.train()
    finally:
        torch.set_num_threads(threads)
    assert used == [[1]] * 4 and not straight._processes  # the follower updated in its process, ended with the run
    for i in (0, 1):
        for key, value in weights(straight.learners[i].model).items():
            assert torch.equal(value, resumed.learners[i].model.state_dict()[key]), (i, key)
    rows = lambda d: [json.loads(x) for x in (d / "metrics.jsonl").read_text().splitlines()]  # noqa: E731
    drop = lambda r: {k: v for k, v in r.items() if "sps" not in k and k != "wall_time_s"}  # noqa: E731
    assert [drop(r) for r in rows(tmp_path / "a")] == [drop(r) for r in rows(tmp_path / "b")]


def test_an_update_process_that_dies_fails_the_next_update_in_one_line(tmp_path):
    threads = torch.get_num_threads()
    trainer = Trainer(tiny(threads=2), tmp_path, progress=False, tensorboard=False)
    try:
        trainer.collect_rollout()
        trainer._update_learners()
        process = trainer._processes[1].process
        os.kill(process.pid, 9)
        process.join(10)
        trainer.collect_rollout()
        with pytest.raises(RuntimeError, match=r"^the follower learner's update process stopped \(exit code -9\)"):
            trainer._update_learners()
    finally:
        torch.set_num_threads(threads)
        trainer.close()  # no second error: the process is gone, its optimizer state with it
    assert not trainer._processes


def test_an_update_process_that_blocks_is_ended_with_its_stacks_and_fails_the_update_in_one_line(tmp_path, capfd):
    """A process alive but using no CPU while its answer is owed (here stopped by SIGSTOP before the update reaches
    it) is taken as blocked after ``stall_s``: ended by SIGABRT, which writes its threads' stacks to stderr, and the
    update fails in one line instead of waiting for ever."""
    threads = torch.get_num_threads()
    trainer = Trainer(tiny(threads=2), tmp_path, progress=False, tensorboard=False)
    try:
        trainer.collect_rollout()
        trainer._update_learners()
        update = trainer._processes[1]
        views = trainer.learners[1].views  # (made before the fork: an update sends their step count, not their memory)
        assert views and all(update._inherited[k] is v and v.is_shared() for k, v in views.items())
        update.stall_s = 1.0
        process = update.process
        os.kill(process.pid, signal.SIGSTOP)
        trainer.collect_rollout()
        with pytest.raises(RuntimeError, match=r"^the follower learner's update process used no CPU for 1 s while its "
                                               r"answer was owed: stopped \(exit code -6; its threads' stacks are on "
                                               r"stderr\)$"):
            trainer._update_learners()
        assert not process.is_alive() and process.exitcode == -signal.SIGABRT
    finally:
        torch.set_num_threads(threads)
        trainer.close()
    assert not trainer._processes
    err = capfd.readouterr().err
    # where the process was: in _serve, waiting for the request
    assert "Fatal Python error: Aborted" in err and "update_process.py\", line" in err and " in _serve\n" in err


def parent_pid(pid: int) -> int:
    status = Path(f"/proc/{pid}/status").read_text()
    return int(status.split("\nPPid:", 1)[1].split()[0])


def test_update_processes_come_from_a_fork_server_of_their_own_whose_blocked_start_is_ended(tmp_path, capfd,
                                                                                             monkeypatch):
    """An update process is the child of ``train.update_process``'s own fork server, not of multiprocessing's shared
    one (which anything in the trainer's process may start with other modules). A server whose start blocks (here
    a module it loads waits for ever) is held to the process's rule: after ``stall_s`` with no CPU it is ended by
    SIGABRT, its stacks on stderr, and the process is ``Unavailable`` (the trainer then updates on threads), as is
    every process asked for after it, at once."""
    threads = torch.get_num_threads()
    trainer = Trainer(tiny(threads=2), tmp_path / "run", progress=False, tensorboard=False)
    try:
        trainer.collect_rollout()
        trainer._update_learners()
        process = trainer._processes[1].process
        assert parent_pid(process.pid) == update_process._SERVER._forkserver_pid
        assert update_process._SERVER is not forkserver._forkserver
        waiting = tmp_path / "waiting"
        (tmp_path / "blocked_preload.py").write_text(f"import pathlib, threading\npathlib.Path({str(waiting)!r})."
                                                     f"touch()\nthreading.Event().wait()\n")
        monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(tmp_path), os.environ.get("PYTHONPATH")])))
        blocked = forkserver.ForkServer()
        blocked.set_forkserver_preload(["train.update_server", "blocked_preload"])
        monkeypatch.setattr(update_process, "_SERVER", blocked)
        monkeypatch.setattr(update_process, "_SERVER_BLOCKED", None)
        blocked.ensure_running()
        server = blocked._forkserver_pid
        while not waiting.exists():  # (the server is in the module's wait: it has loaded train.update_server)
            assert os.waitpid(server, os.WNOHANG)[0] == 0, "the server ended before it blocked"
            time.sleep(0.05)
        reason = (f"the update processes' fork server (pid {server}) used no CPU for 1 s before forking: stopped "
                  f"(its threads' stacks are on stderr)")
        with pytest.raises(update_process.Unavailable, match=f"^no process for the follower learner's update "
                                                             f"\\({re.escape(reason)}\\)$"):
            update_process.UpdateProcess(trainer.learners[1], stall_s=1.0)
        assert not Path(f"/proc/{server}").exists()  # ended, and waited for
        assert update_process._SERVER is not blocked and update_process._SERVER._forkserver_pid is None
        with pytest.raises(update_process.Unavailable, match=f"\\({re.escape(reason)} before\\)$"):
            update_process.UpdateProcess(trainer.learners[1])  # not tried again: no new server started
        assert update_process._SERVER._forkserver_pid is None
    finally:
        torch.set_num_threads(threads)
        trainer.close()
    err = capfd.readouterr().err
    assert "Fatal Python error: Aborted" in err and "blocked_preload.py\", line 3" in err  # where the server waited


def test_a_script_without_a_main_guard_trains_with_update_processes_and_runs_once(tmp_path):
    """The update process starts from the fork server and runs a function of ``train.update_process``, never the
    script that trains: a script with no ``if __name__ == "__main__"`` guard runs once, its follower updating in a
    process of its own, as when forked from the trainer."""
    script = tmp_path / "train_me.py"
    script.write_text(f"""import sys
from train.config import from_dict
from train.trainer import Trainer
print("the script ran", flush=True)
trainer = Trainer(from_dict({dict(TINY, threads=2)!r}), sys.argv[1], progress=False, tensorboard=False)
trainer.collect_rollout()
trainer._update_learners()
print("update processes:", sorted(trainer._processes), flush=True)
trainer.close()
""")
    done = subprocess.run([sys.executable, str(script), str(tmp_path / "run")], capture_output=True, text=True,
                          timeout=300, cwd=Path(__file__).resolve().parents[1])
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == ["the script ran", "update processes: [1]"], done.stdout


@pytest.mark.timeout(method="thread")  # this test sets its own SIGALRM; the suite's bound (900 s) by a thread
def test_ctrl_c_during_an_update_ends_the_update_processes_at_once(tmp_path):
    """SIGINT while the learners update (the follower in its process): the KeyboardInterrupt comes through, the
    process is ended at once rather than asked for a state it is still changing, and closing raises nothing."""
    threads = torch.get_num_threads()
    trainer = Trainer(from_dict({"threads": 2, "eval_every": 0}), tmp_path, progress=False, tensorboard=False)
    try:
        trainer.collect_rollout()
        trainer._update_learners()  # the process starts; an update of the paper's batch takes about 0.2 s
        process = trainer._processes[1].process
        trainer.collect_rollout()
        signal.setitimer(signal.ITIMER_REAL, 0.05)
        previous = signal.signal(signal.SIGALRM, signal.default_int_handler)  # raises KeyboardInterrupt
        try:
            with pytest.raises(KeyboardInterrupt):
                trainer._update_learners()
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, previous)
        assert not trainer._processes and not process.is_alive() and process.exitcode == -signal.SIGKILL
        trainer.close()
    finally:
        torch.set_num_threads(threads)


def test_learners_acting_side_by_side_collect_what_acting_in_turn_does(tmp_path):
    """With two torch threads the learners act on two threads, one torch thread each; the rollout is the one they
    collect acting in turn on one thread, to the bit (the follower recurrent, so its state is carried too)."""
    threads = torch.get_num_threads()
    config = tiny(threads=2, follower={"net": {"lstm": True}}, env={"horizon": 6})  # episodes end mid-rollout
    side_by_side, in_turn = (Trainer(config, tmp_path / name, progress=False, tensorboard=False) for name in "ab")
    acting_threads = set()
    for learner in side_by_side.learners.values():
        act = learner.act
        learner.act = lambda x, act=act: acting_threads.add(threading.current_thread().name) or act(x)
    try:
        side_by_side.collect_rollout()
        torch.set_num_threads(1)
        in_turn.collect_rollout()
    finally:
        torch.set_num_threads(threads)
    assert len(acting_threads) == 2  # both paths were taken
    for i in (0, 1):
        a, b = side_by_side.learners[i].stacked(), in_turn.learners[i].stacked()
        assert a.keys() == b.keys() and a["dones"].any()
        for key in a:
            pairs = a[key].items() if key == "view" else [(key, a[key])]
            for name, value in pairs:
                other = b["view"][name] if key == "view" else b[key]
                assert torch.equal(value, other), (i, name)
        assert all(torch.equal(s, t) for s, t in zip(side_by_side.learners[i].state or (),
                                                       in_turn.learners[i].state or ()))


def test_a_frozen_partner_never_changes_and_the_learner_does(tmp_path):
    Trainer(tiny(follower={"policy": "idle"}, total_steps=64), tmp_path / "lead", progress=False,
            tensorboard=False).train()
    leader_file = export_agent(tmp_path / "lead" / "checkpoints" / "latest.pt", "leader", tmp_path / "leader.pt")
    before = load_checkpoint(leader_file)["agents"]["leader"]["state_dict"]
    trainer = Trainer(tiny(leader={"policy": str(leader_file)}, total_steps=3 * 64), tmp_path / "f",
                      progress=False, tensorboard=False)
    follower_before = weights(trainer.learners[1].model)
    trainer.train()
    frozen = trainer.partners[0].model.state_dict()
    assert all(torch.equal(before[k], frozen[k]) for k in before)
    after = trainer.learners[1].model.state_dict()
    assert any(not torch.equal(follower_before[k], after[k]) for k in after)
    saved = load_checkpoint(tmp_path / "f" / "checkpoints" / "latest.pt")
    assert saved["agents"]["leader"] is None and saved["agents"]["follower"] is not None


@pytest.mark.parametrize("preset", preset_names())
def test_every_preset_runs_with_a_tiny_budget(tmp_path, preset, shipped_leader):
    data = merge(load_preset(preset), merge(TINY, {"total_steps": 32, "eval_every": 1, "eval_episodes": 2,
                                                   "replay_episodes": 1,
                                                   "ppo": {"num_envs": 2, "num_steps": 16, "num_minibatches": 1}}))
    config = from_dict(data)
    Trainer(config, tmp_path, progress=False, tensorboard=False).train()
    rows = [json.loads(x) for x in (tmp_path / "metrics.jsonl").read_text().splitlines()]
    from train.config import eval_stream

    assert [r["stream"] for r in rows] == ["train", "eval", *(eval_stream(p) for p in config.eval_partners)]
    assert all(math.isfinite(v) for k, v in rows[0].items() if k.endswith("/loss"))
    assert len(list((tmp_path / "replays").rglob("*.replay.json"))) == 1
    assert (tmp_path / "checkpoints" / "latest.pt").is_file()


@pytest.fixture(scope="session")
def shipped_leader():
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "checkpoints" / "leader.pt"
    assert path.is_file(), "the shipped leader checkpoint is missing (presets refer to it)"
    return path


# -------------------------------------------------------------- bad input
def test_config_errors_name_the_field_and_what_is_allowed():
    cases = [
        ({"ppo": {"lr": -1}}, "ppo.lr=-1 is invalid"),
        ({"ppo": {"num_envs": 6, "num_minibatches": 4}}, "must divide ppo.num_envs=6"),
        ({"leader": {"policy": "nope"}}, "'learn', one of"),
        ({"leader": {"policy": "astar"}, "follower": {"policy": "idle"}}, "at least one agent must have"),
        ({"follower": {"net": {"arch": "resnet"}}}, "choose one of ['fast', 'paper']"),
        ({"schedule": {"penalty_start": 5}}, "set both penalty_start and penalty_end"),
        ({"ppo": {"learning_rate": 1}}, "unknown field(s) ['learning_rate'] in ppo"),
        ({"env": {"height": 2}}, "height"),
        ({"follower": {"net": {"goal_fusion": "planes", "belief_input": True}}}, "set net.lstm=true and"),
        ({"follower": {"train_reward": "team"}}, "'env' (the env's reward) or 'own'"),
        ({"follower": {"wrong_weight": 2.0}}, "1.0 unless train_reward='own'"),
        ({"follower": {"train_reward": "own", "wrong_weight": -1}}, "follower.wrong_weight=-1 is invalid"),
        ({"follower": {"aux_target": "nope"}}, "follower.aux_target='nope' is invalid: 'goal', or for"),
        ({"leader": {"policy": "astar", "aux_target": "bayes"}}, "leader.aux_target='bayes' is invalid"),
    ]
    for change, message in cases:
        with pytest.raises(ValueError) as err:
            from_dict(change)
        assert message in str(err.value), (change, str(err.value))
    with pytest.raises(TrainConfigError, match="expected KEY=VALUE"):
        parse_override("ppo.lr")
    assert parse_override("follower.net.lstm=true") == {"follower": {"net": {"lstm": True}}}


def test_a_caution_weight_scales_only_the_learners_own_wrong_blocks(tmp_path):
    trainer = Trainer(tiny(leader={"policy": "astar"}, follower={"train_reward": "own", "wrong_weight": 3.0}),
                      tmp_path / "run", progress=False, tensorboard=False)
    team = np.array([[2.0, 2.0], [-1.0, -1.0], [0.0, 0.0]], dtype=np.float32)  # shared: both get the sum
    own = np.array([[1.0, 1.0], [0.0, -1.0], [1.0, -1.0]], dtype=np.float32)
    infos = {"block_reward": own, "distance_shaping": np.zeros_like(own), "potential_shaping": np.zeros_like(own)}
    out = trainer._training_rewards(team, infos, shaping=False)
    np.testing.assert_array_equal(out[:, 1], [1.0, -3.0, -3.0])  # the follower: own goals +1, own wrongs x3
    np.testing.assert_array_equal(out[:, 0], team[:, 0])  # the scripted leader's column is untouched


BELIEF_CORE = {"net": {"lstm": True, "extra_inputs": True, "goal_fusion": "planes", "belief_input": True}}


def test_distilling_the_oracles_belief_trains_exactly_like_the_true_goal(tmp_path):
    """The oracle's belief is the one-hot true goal: as a soft target it must give the same updates, so the
    teacher's belief reaches the loss in the rows and steps of the learner's own samples."""
    runs = {}
    for target in ("goal", "oracle", "bayes-people"):
        trainer = Trainer(tiny(leader={"policy": "astar"}, follower={**BELIEF_CORE, "aux_target": target},
                               total_steps=2 * 64), tmp_path / target, progress=False, tensorboard=False)
        runs[target] = (trainer, trainer.train())
    (goal, goal_row), (oracle, oracle_row) = runs["goal"], runs["oracle"]
    assert 1 in oracle.teachers and not goal.teachers
    assert oracle_row["follower/aux_loss"] == pytest.approx(goal_row["follower/aux_loss"], rel=1e-5)
    taught = runs["bayes-people"][0].learners[1].model.state_dict()  # another target: another goal head
    gap = max(float((taught[k] - v).abs().max()) for k, v in weights(goal.learners[1].model).items() if "aux" in k)
    assert gap > 1e-5, gap
    after = oracle.learners[1].model.state_dict()
    for key, value in weights(goal.learners[1].model).items():
        torch.testing.assert_close(after[key], value, rtol=1e-5, atol=1e-6, msg=key)


def test_a_role_of_learners_and_scripted_agents_distils_only_for_its_learners():
    config = from_dict({"env": {"num_followers": 2}, "follower": {"policies": ["learn", "bayes"],
                                                                  "aux_target": "bayes-people"}})
    assert [a.aux_target for a in config.agents] == ["goal", "bayes-people", "goal"]


def test_a_bayesian_teachers_belief_is_the_soft_target(tmp_path):
    trainer = Trainer(tiny(leader={"policy": "astar"}, follower={**BELIEF_CORE, "aux_target": "bayes-people"}),
                      tmp_path / "run", progress=False, tensorboard=False)
    trainer.collect_rollout()
    buffer = trainer.learners[1].stacked()
    target, goal = buffer["aux_target"], buffer["true_goal"]  # [T=16, B=4, C], [T, B]; episodes of 12 steps
    assert target.shape == (16, 4, 3)
    torch.testing.assert_close(target.sum(dim=2), torch.ones(16, 4))
    torch.testing.assert_close(target[[0, 12]], torch.full((2, 4, 3), 1 / 3))  # each episode starts uniform
    assert ((target > 0.01) & (target < 0.99)).any()  # a belief, not the true goal
    assert (target[11].argmax(dim=1) == goal[11]).float().mean() > 0.5  # by then it mostly knows the goal
    np.testing.assert_array_equal(target[-1].numpy(), trainer.teachers[1].belief.astype(np.float32))


def test_a_teacher_without_a_belief_is_refused_in_one_line(tmp_path):
    trainer = Trainer(tiny(leader={"policy": "astar"}, follower={"aux_target": "copy"}), tmp_path / "run",
                      progress=False, tensorboard=False)
    with pytest.raises(ValueError, match=r"^follower.aux_target='copy' keeps no belief over the goal to distil"):
        trainer.collect_rollout()


def test_checkpoint_errors_are_clear(tmp_path):
    Trainer(tiny(follower={"policy": "idle"}, total_steps=64), tmp_path / "run", progress=False,
            tensorboard=False).train()
    ckpt = tmp_path / "run" / "checkpoints" / "latest.pt"
    with pytest.raises(ValueError, match="holds no trained follower"):
        load_policy(ckpt, role="follower")
    with pytest.raises(ValueError, match="does not fit this environment .*height: trained 32, requested 16"):
        run_episodes(EnvConfig(height=16, width=16), load_policy(ckpt, "leader"), make_policy("idle"), 1, 0)
    # a network trained without "stay" may act where the leader can stay (the server's real-time mode)
    run_episodes(EnvConfig(allow_stay=True), load_policy(ckpt, "leader"), make_policy("random"), 1, 0)
    with pytest.raises(ValueError, match="was trained with"):
        Trainer(tiny(leader={"init": str(ckpt), "net": {"lstm": True}}, follower={"policy": "idle"}),
                tmp_path / "x", progress=False, tensorboard=False)
    broken = tmp_path / "broken.pt"
    broken.write_bytes(ckpt.read_bytes()[:1000])
    with pytest.raises(ValueError, match="not a readable ColorGrid checkpoint"):
        load_policy(broken)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_policy(tmp_path / "missing.pt")
    exported = export_agent(ckpt, "leader", tmp_path / "small.pt")
    assert exported.stat().st_size < ckpt.stat().st_size / 2
    with pytest.raises(ValueError, match="exported policy"):
        Trainer(tiny(follower={"policy": "idle"}), tmp_path / "y", progress=False, tensorboard=False).restore(exported)


def test_cli_trains_exports_and_evaluates_a_checkpoint(tmp_path):
    run = tmp_path / "run"
    cmd = [sys.executable, "-m", "colorgrid_apps", "train", "--preset", "leader_solo", "--out", str(run),
           "--no-progress", "--set", "total_steps=64", "--set", "ppo.num_envs=4", "--set", "ppo.num_steps=16",
           "--set", "eval_every=1", "--set", "eval_episodes=2", "--set", "replay_episodes=1"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert (run / "train.csv").read_text().startswith("step,")
    assert list((run / "tb").iterdir())
    small = tmp_path / "leader.pt"
    done = subprocess.run([sys.executable, "-m", "colorgrid_apps", "checkpoint", "export",
                           str(run / "checkpoints" / "latest.pt"), "--agent", "leader", "--out", str(small)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    done = subprocess.run([sys.executable, "-m", "colorgrid_apps", "eval", "--leader", str(small), "--follower",
                           "idle", "--episodes", "2"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "leader net pickups" in done.stdout
    bad = subprocess.run([sys.executable, "-m", "colorgrid_apps", "train", "--set", "ppo.clip_coef=-1"],
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "ppo.clip_coef=-1 is invalid" in bad.stderr


def test_ctrl_c_stops_training_after_the_iteration_with_a_checkpoint_that_resumes(tmp_path):
    """Ctrl+C (SIGINT to the process group) on ``colorgrid train`` at two torch threads (the follower's update in its
    process): the iteration ends, its checkpoint is written, the command names the step and how to go on (exit code
    130), every process it started ends, and ``--resume`` continues from that step."""
    run = tmp_path / "run"
    tiny_run = ["--set", "ppo.num_envs=4", "--set", "ppo.num_steps=16", "--set", "env.horizon=12", "--set",
                "eval_every=0", "--set", "threads=2", "--no-progress", "--no-tensorboard"]
    train = subprocess.Popen([sys.executable, "-m", "colorgrid_apps", "train", "--out", str(run), "--set",
                              "total_steps=640000", *tiny_run], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True, start_new_session=True)
    metrics = run / "metrics.jsonl"
    deadline = time.monotonic() + 120
    while not (metrics.is_file() and metrics.read_text().count('"train"') >= 3):
        assert train.poll() is None and time.monotonic() < deadline, train.communicate()
        time.sleep(0.1)
    children = lambda pid: [int(p) for p in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]  # noqa: E731
    started = [(p, children(p)) for p in children(train.pid)]  # the fork server, with the follower's update process
    assert any(below for _, below in started), started  # (the resource tracker, a child too, has none)
    started = [p for p, below in started for p in (p, *below)]
    os.killpg(train.pid, signal.SIGINT)  # as a terminal's Ctrl+C: to the process group, the update process too
    out, err = train.communicate(timeout=120)
    assert train.returncode == 130, err
    step = int(re.search(r"stopped at step (\d+) of 640000; continue with: colorgrid train --resume (\S+)",
                         out).group(1))
    assert "stopping after this iteration" in err and "Traceback" not in err
    assert load_checkpoint(run / "checkpoints" / "latest.pt")["step"] == step > 0
    deadline = time.monotonic() + 60  # (the fork server ends when it sees its trainer's end, the update process before)
    while [p for p in started if Path(f"/proc/{p}").exists()]:
        assert time.monotonic() < deadline, [p for p in started if Path(f"/proc/{p}").exists()]
        time.sleep(0.05)
    resumed = subprocess.run([sys.executable, "-m", "colorgrid_apps", "train", "--resume", str(run), "--set",
                              f"total_steps={step + 128}", "--no-progress", "--no-tensorboard"],
                             capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    assert f"resuming {run} at step {step}" in resumed.stdout and f"done at step {step + 128}" in resumed.stdout


def test_model_card_evaluates_against_the_baselines_on_the_same_seeds(tmp_path):
    from train.card import model_card

    Trainer(tiny(leader={"policy": "astar"}, total_steps=64), tmp_path / "run", progress=False,
            tensorboard=False).train()
    small = export_agent(tmp_path / "run" / "checkpoints" / "latest.pt", "follower", tmp_path / "f.pt")
    text, data = model_card(str(small), "follower", str(tmp_path / "run"), "colorgrid train ...", episodes=3)
    assert "| astar + bayes |" in text and "| astar + f |" in text and "64 env steps" in text
    assert "torch threads)" in text.split("**Hardware**:")[1].splitlines()[0]  # recorded by the run
    assert load_checkpoint(small)["wall_time_s"] > 0 and "**Wall time**: 0 min (" in text
    assert [r["seed"] for r in data["reports"]] == [0] * 5 and all(r["episodes"] == 3 for r in data["reports"])


# --------------------------------------------------------- shipped agents
CARDS = Path(__file__).resolve().parents[1] / "checkpoints"


def card_report(card: str, leader: str, follower: str) -> dict:
    """The evaluation a model card was written from (its JSON beside the card)."""
    for report in json.loads((CARDS / f"{card}.json").read_text())["reports"]:
        if (report["leader"].get("checkpoint") or report["leader"]["policy"]) == leader and \
                (report["follower"].get("checkpoint") or report["follower"]["policy"]) == follower:
            return report
    raise AssertionError(f"{card}.json has no report for {leader} + {follower}")


def assert_reproduces(report: dict, card: dict) -> None:
    """Every action is the card's (so every count is), and the float32 belief log-loss within 1e-5.

    Policies act on float32 network outputs, which differ in their last bits between CPU kernels
    (ATEN_CPU_CAPABILITY, MKL/oneDNN paths, thread counts); a sampled action would only change if
    its uniform draw fell within about 1e-7 of a boundary. The log-loss is a float32 mean of
    12,800 terms: its rounding error is a few ulp times log2(12,800) ~ 14, well under 1e-5.
    """
    for agent, metrics in card["agents"].items():
        got = dict(report["agents"][agent])
        belief, expected = got.pop("belief", None), dict(metrics)
        expected_belief = expected.pop("belief", None)
        assert got == expected, agent
        if expected_belief is not None:
            assert belief["accuracy"] == expected_belief["accuracy"]
            assert belief["log_loss"] == pytest.approx(expected_belief["log_loss"], rel=1e-5)
    assert report["team_reward"] == card["team_reward"]


def test_the_shipped_follower_reproduces_its_card_and_assists_the_astar_leader():
    """The card's own command, and the bar: net pickups clearly positive (95% interval above zero)."""
    from colorgrid.evaluate import evaluate

    report = evaluate(EnvConfig(), "astar", str(CARDS / "follower.pt"), episodes=100, seed=0)
    assert_reproduces(report, card_report("follower", "astar", "checkpoints/follower.pt"))
    net = report["agents"]["follower"]["net_pickups"]
    assert net["mean"] - net["ci95"] > 0, net
    assert report["agents"]["follower"]["belief"]["accuracy"] > 0.5


def test_the_unannealed_follower_reproduces_its_card_and_assists_the_astar_leader():
    """The simpler recipe's checkpoint (no annealing): its card's command, and the same bar."""
    from colorgrid.evaluate import evaluate

    report = evaluate(EnvConfig(), "astar", str(CARDS / "follower_unannealed.pt"), episodes=100, seed=0)
    assert_reproduces(report, card_report("follower_unannealed", "astar", "checkpoints/follower_unannealed.pt"))
    net = report["agents"]["follower"]["net_pickups"]
    assert net["mean"] - net["ci95"] > 0, net


def test_the_shipped_leader_reproduces_its_card_and_collects_goal_blocks():
    from colorgrid.evaluate import evaluate

    report = evaluate(EnvConfig(), str(CARDS / "leader.pt"), "bayes", episodes=100, seed=0)
    assert_reproduces(report, card_report("leader", "checkpoints/leader.pt", "bayes"))
    net = report["agents"]["leader"]["net_pickups"]
    assert net["mean"] - net["ci95"] > 0, net


@pytest.mark.parametrize("stage", ["0.2M", "0.4M", "0.8M", "2.5M"])
def test_each_leader_stage_reproduces_its_card(stage):
    """The training partners at several skill levels (checkpoints/leader_stages): each card's row beside the idle
    follower, by the name the trainer registers for it."""
    from colorgrid.evaluate import evaluate

    report = evaluate(EnvConfig(), f"ippo-leader-{stage}", "idle", episodes=100, seed=0)
    assert_reproduces(report, card_report(f"leader_stages/leader_{stage}",
                                          f"checkpoints/leader_stages/leader_{stage}.pt", "idle"))


def test_the_leader_stages_rise_in_skill():
    """Saved along one run, each later stage collects more net goal blocks than the one before (the cards' rows:
    100 episodes each, intervals apart), so a population of them is partners at several skill levels."""
    nets = [card_report(f"leader_stages/leader_{stage}", f"checkpoints/leader_stages/leader_{stage}.pt",
                        "idle")["agents"]["leader"]["net_pickups"] for stage in ("0.2M", "0.4M", "0.8M", "2.5M")]
    assert all(a["mean"] + a["ci95"] < b["mean"] - b["ci95"] for a, b in zip(nets, nets[1:])), nets


EXACT_TRAINING_TESTS = ["test_fast_encoder_patches", "test_lstm_log_probs_recomputed",
                        "test_resume_continues_exactly", "test_two_learners_updating_side_by_side",
                        "test_resume_with_the_follower_updating_in_its_process",
                        "test_resume_with_a_teacher"]


@pytest.mark.skipif(os.environ.get("COLORGRID_SECOND_CPU_PATH") == "1", reason="this is the second run itself")
def test_exact_training_tests_also_hold_on_a_second_cpu_path():
    """The float-exact training tests again in a fresh process on other CPU kernels (ATEN_CPU_CAPABILITY)
    and one torch thread, so that a dependence on the CPU path shows up on any machine."""
    current = torch.backends.cpu.get_cpu_capability().lower()
    other = "default" if current != "default" else "avx2"
    env = {**os.environ, "ATEN_CPU_CAPABILITY": other, "OMP_NUM_THREADS": "1", "COLORGRID_SECOND_CPU_PATH": "1"}
    done = subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", __file__,
                           "-k", " or ".join(EXACT_TRAINING_TESTS)], capture_output=True, text=True, env=env,
                          timeout=600, cwd=CARDS.parent)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-2000:]
    assert re.search(r"\b8 passed", done.stdout) and "failed" not in done.stdout, done.stdout[-2000:]


def test_the_people_follower_reproduces_its_card_and_its_held_out_matrix():
    """The card's rows (beside the training population) and one cell of the held-out matrix it ships."""
    from colorgrid.evaluate import evaluate, mean_ci
    from colorgrid_apps.matrix import cell

    follower = str(CARDS / "follower_people.pt")
    report = evaluate(EnvConfig(), "population:people#training", follower, episodes=100, seed=0)
    assert_reproduces(report, card_report("follower_people", "population", "checkpoints/follower_people.pt"))
    matrix = json.loads((CARDS / "follower_people.held_out.json").read_text())
    leader = matrix["leaders"]["late_8"]
    metrics, nets = cell(EnvConfig(), leader, "ippo-people", 100, 0)
    expected = matrix["cells"]["late_8"]["ippo-people"]
    assert metrics["net_pickups"] == expected["net_pickups"] and metrics["wrong_pickups"] == expected["wrong_pickups"]
    assert metrics["belief_accuracy"] == expected["belief_accuracy"]
    _, copy_nets = cell(EnvConfig(), leader, "copy", 100, 0)  # the card's paired difference, recomputed
    copy = mean_ci(nets - copy_nets)
    assert copy == matrix["paired_difference"]["ippo-people"]["late_8"]
    assert metrics["net_pickups"]["mean"] > 0 and copy["mean"] - copy["ci95"] > 0  # better than copy beside it


def test_the_cautious_follower_reproduces_its_card_and_meets_its_held_out_figures():
    """The card's row beside the training population, a held-out cell and its difference from ``copy`` recomputed,
    and what the card claims of its held-out matrix, recomputed on fewer episodes: more net pickups than ``bayes``
    on average, better than ``copy`` beside every leader, fewer wrong pickups than the follower it was trained from
    and at most 2.0 an episode."""
    from colorgrid.evaluate import evaluate, mean_ci
    from colorgrid_apps.matrix import cell, evaluate_matrix, leaders_from

    follower = str(CARDS / "follower_cautious.pt")
    report = evaluate(EnvConfig(), "population:people#training", follower, episodes=100, seed=0)
    assert_reproduces(report, card_report("follower_cautious", "population", "checkpoints/follower_cautious.pt"))
    matrix = json.loads((CARDS / "follower_cautious.held_out.json").read_text())
    wanderer = matrix["leaders"]["wanderer"]  # the leader beside which its lead over copy is narrowest
    metrics, nets = cell(EnvConfig(), wanderer, "ippo-cautious", 100, 0)
    expected = matrix["cells"]["wanderer"]["ippo-cautious"]
    assert metrics["net_pickups"] == expected["net_pickups"] and metrics["wrong_pickups"] == expected["wrong_pickups"]
    _, copy_nets = cell(EnvConfig(), wanderer, "copy", 100, 0)
    copy = mean_ci(nets - copy_nets)
    assert copy == matrix["paired_difference"]["ippo-cautious"]["wanderer"]
    assert copy["mean"] - copy["ci95"] > 0  # better than copy beside it, by the card's 95% interval
    # The card's command on its held-out leaders, seed 0, with 32 episodes a cell instead of 100 (and one torch
    # thread, the faster for these small batches: about 15 s): its claims about the mean over leaders, and better
    # than copy (on average) beside every leader.
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        recomputed = evaluate_matrix(EnvConfig(), leaders_from("population:people#held_out"),
                                     ["copy", "bayes", "ippo-people", "ippo-cautious"], episodes=32, seed=0, workers=1)
    finally:
        torch.set_num_threads(threads)
    assert set(recomputed["leaders"]) == set(matrix["leaders"])
    mean = recomputed["mean_over_leaders"]
    assert mean["ippo-cautious"]["net_pickups"] >= mean["bayes"]["net_pickups"]
    assert mean["ippo-cautious"]["wrong_pickups"] < mean["ippo-people"]["wrong_pickups"]
    assert mean["ippo-cautious"]["wrong_pickups"] <= 2.0  # the target, which the card says is met
    for leader, difference in recomputed["paired_difference"]["ippo-cautious"].items():
        assert difference["mean"] > 0, leader
    assert load_policy(follower).min_belief == 0.5  # how the card says it acts


def test_resume_with_a_teacher_continues_exactly(tmp_path):
    """The teacher's belief carries across a resume, so the distilled targets (and the weights) do too."""
    changes = dict(leader={"policy": "population:people#training"},
                   follower={**BELIEF_CORE, "aux_target": "bayes-people"}, total_steps=4 * 64)
    straight, resumed = straight_and_resumed(tmp_path, changes)
    np.testing.assert_array_equal(straight.teachers[1].belief, resumed.teachers[1].belief)
    for key, value in weights(straight.learners[1].model).items():
        assert torch.equal(value, resumed.learners[1].model.state_dict()[key]), key


def test_loading_a_checkpoint_leaves_torchs_random_generator_alone():
    """Otherwise a run's fresh network would start from other weights when a partner's checkpoint is already
    loaded in the process (the model cache) than when it is read from disk."""
    before = torch.get_rng_state()
    load_policy(CARDS / "leader.pt")
    assert torch.equal(torch.get_rng_state(), before)


def test_resume_with_a_population_partner_continues_exactly(tmp_path):
    """Population play resumes with each env's drawn member and every member's own state."""
    changes = dict(leader={"policy": "population:people#held_out"}, total_steps=4 * 64, env={"horizon": 12})
    straight, resumed = straight_and_resumed(tmp_path, changes)
    assert (straight.partners[0].member == resumed.partners[0].member).all()
    for key, value in weights(straight.learners[1].model).items():
        assert torch.equal(value, resumed.learners[1].model.state_dict()[key]), key


def test_a_partner_is_pinned_to_the_checkpoints_inside_it_and_resumes_from_before_they_were(tmp_path):
    """A person around the IPPO leader keeps its base's sha256 in the checkpoint's record of the partner (and so in
    every replay's agents entry): a run resumes beside the same weights only. A record saved before nested
    checkpoints were pinned still resumes, pinned against the file as it is now."""
    import hashlib

    changes = dict(leader={"policy": "person:base=ippo-leader,slip=0.1"}, total_steps=2 * 64)
    Trainer(tiny(**changes), tmp_path, progress=False, tensorboard=False).train()
    path = tmp_path / "checkpoints" / "latest.pt"
    ckpt = torch.load(path, map_location="cpu", weights_only=False)
    base = ckpt["trainer_state"]["partners"]["leader"]["describe"]["base"]
    assert base["checkpoint_sha256"] == hashlib.sha256(Path(base["checkpoint"]).read_bytes()).hexdigest()

    def resume(sha: str | None) -> Trainer:
        base.pop("checkpoint_sha256", None)
        base.update({} if sha is None else {"checkpoint_sha256": sha})
        torch.save(ckpt, path)
        trainer = Trainer(tiny(**{**changes, "total_steps": 3 * 64}), tmp_path, progress=False, tensorboard=False)
        trainer.restore(path)
        return trainer

    assert resume(None).step == 128  # as saved before
    with pytest.raises(ValueError, match="resume with the same partner"):
        resume("0" * 64)  # other weights under the same name
    base["checkpoint"] = str(tmp_path / "moved" / "leader.pt")  # saved before, its file gone since
    with pytest.raises(ValueError, match="whose file cannot be read now .*; resume with the same partner"):
        resume(None)


def test_eval_partners_judge_the_learner_beside_other_partners_on_the_same_seeds(tmp_path):
    """Each evaluation partner plays the agents that do not learn, on the evaluation's own seeds: beside the idle
    leader the leader collects nothing, beside A* it collects, and the learner's own play is the same network's."""
    from train.config import eval_stream
    from train.metrics import MetricsLog

    config = tiny(total_steps=64, eval_every=1, eval_episodes=3, replay_episodes=0,
                  leader={"policy": "astar"}, env={"asymmetric": True, "horizon": 32},
                  eval_partners=["idle", "astar", "population:people#held_out"])
    trainer = Trainer(config, tmp_path, progress=False, tensorboard=False)
    trainer.log = MetricsLog(tmp_path, tensorboard=False)
    row = trainer.evaluate()
    trainer.close()
    trainer.log.close()
    assert eval_stream("population:people#held_out") == "eval_population_people_held_out"
    idle, astar = row["eval_idle/leader_goal_pickups"], row["eval_astar/leader_goal_pickups"]
    assert idle == 0 and row["eval_idle/leader_wrong_pickups"] == 0 and astar > 0
    assert astar == row["eval/leader_goal_pickups"]  # the training partner is A*: the same seeds, the same play
    assert "eval_population_people_held_out/follower_net_pickups" in row
    for stream in ("eval_idle", "eval_astar", "eval_population_people_held_out"):
        assert (tmp_path / f"{stream}.csv").read_text().startswith("step,")


def test_eval_partners_need_an_agent_that_does_not_learn():
    with pytest.raises(TrainConfigError, match="eval_partners=\\('astar',\\) is invalid: \\[\\] when every agent learns"):
        tiny(eval_partners=["astar"])
    with pytest.raises(TrainConfigError, match="'nope' is not a policy to evaluate beside"):
        tiny(leader={"policy": "astar"}, eval_partners=["nope"])
