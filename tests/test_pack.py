"""Packs of trials (train/pack.py): K runs trained as one compute what each computes alone, on the CPU bit for bit
(every learner's update at one thread, as alone) and through the batched update (train/packed_update.py) up to
float rounding; a packed run resumes exactly; ``colorgrid train --seeds`` trains a pack."""

import json
import subprocess
import sys

import pytest
import torch

from train.cli import main as train_main
from train.config import from_dict, merge
from train.pack import Pack
from train.trainer import Trainer

TINY = {"ppo": {"num_envs": 4, "num_steps": 16, "num_minibatches": 2, "update_epochs": 3},
        "eval_every": 2, "eval_episodes": 2, "replay_episodes": 0, "save_every": 2, "env": {"horizon": 12},
        "total_steps": 3 * 64, "threads": 2}

# trials that differ only in values: seed, kappa (the goal head's weight), annealing, learning rate, reward weights,
# target KL, partner, total steps, and one with a memory (its follower acts and updates on its own in the pack)
TRIALS = {
    "seed 0": {"seed": 0},
    "seed 1, kappa 0, annealed": {"seed": 1, "follower": {"aux_coef": 0.0},
                                  "schedule": {"penalty_start": 0, "penalty_end": 128}},
    "seed 2, lr, target KL, own reward, PPO's values": {
        "seed": 2, "follower": {"train_reward": "own", "wrong_weight": 2.0},
        "ppo": {"lr": 3e-4, "target_kl": 1e-9, "gamma": 0.97, "gae_lambda": 0.9, "clip_coef": 0.1, "ent_coef": 0.02,
                "vf_coef": 0.4, "max_grad_norm": 1.0}},
    "seed 3, beside A*, a teacher's belief, fewer steps": {"seed": 3, "leader": {"policy": "astar"},
                                                            "follower": {"aux_target": "bayes"}, "total_steps": 2 * 64},
    "seed 4, a memory": {"seed": 4, "follower": {"net": {"lstm": True, "extra_inputs": True}}},
    "seed 5, a memory, kappa 0": {"seed": 5, "follower": {"net": {"lstm": True, "extra_inputs": True},
                                                          "aux_coef": 0.0}},
}


def trainer(path, changes: dict) -> Trainer:
    return Trainer(from_dict(merge(TINY, changes)), path, progress=False, tensorboard=False)


def rows(run) -> list[dict]:
    """A run's logged rows, without the clock's."""
    timing = lambda k: "sps" in k or k == "wall_time_s"  # noqa: E731
    return [{k: v for k, v in json.loads(line).items() if not timing(k)}
            for line in (run / "metrics.jsonl").read_text().splitlines()]


def assert_close_rows(got: list[dict], expected: list[dict], name: str) -> None:
    """The same rows, every figure to float rounding."""
    assert [r.keys() for r in got] == [r.keys() for r in expected], name
    for g, e in zip(got, expected):
        for key, value in e.items():
            assert g[key] == (pytest.approx(value, rel=1e-4, abs=1e-6) if isinstance(value, float) else value), \
                (name, g["step"], key)


def assert_same_weights(a: Trainer, b: Trainer, atol: float = 0.0) -> None:
    assert list(a.learners) == list(b.learners)
    for la, lb in zip(a.learners.values(), b.learners.values()):
        for (name, x), y in zip(la.model.state_dict().items(), lb.model.state_dict().values()):
            torch.testing.assert_close(x, y, atol=atol, rtol=0, msg=name)


def train_alone_at_the_packs_threads(path, changes: dict) -> Trainer:
    """A trial trained alone with each learner's update at one thread, as in a stacked pack. Two learners update at
    one thread each alone too; a trial with one learner would update at every thread, which on CPUs whose MKL splits
    a small product's sum across threads (an Intel Xeon with AVX-512) gives other last bits: it trains at one."""
    t = trainer(path, changes)  # (sets the config's torch threads)
    threads = torch.get_num_threads()
    torch.set_num_threads(1 if len(t.learners) == 1 else threads)
    try:
        t.train()
    finally:
        torch.set_num_threads(threads)
    return t


def test_a_pack_trains_each_trial_bit_for_bit_as_it_trains_alone_on_the_cpu(tmp_path):
    alone = [train_alone_at_the_packs_threads(tmp_path / "alone" / str(k), c) for k, c in enumerate(TRIALS.values())]
    assert [len(t.learners) for t in alone] == [2, 2, 2, 1, 2, 2]  # (the A* trial's follower alone learns)
    packed = [trainer(tmp_path / "packed" / str(k), c) for k, c in enumerate(TRIALS.values())]
    seen = []
    Pack(packed).train(lambda done: seen.extend((k, row["iteration"], saved is not None)
                                                for k, (row, saved) in done.items()))
    for name, a, p in zip(TRIALS, alone, packed):
        assert p.step == a.step == a.config.num_iterations * 64
        for la, lp in zip(a.learners.values(), p.learners.values()):
            assert lp.generator.get_state().equal(la.generator.get_state())
        if "memory" in name:  # alone its leader acts through its own network, in the pack stacked with the others'
            assert_close_rows(rows(p.run_dir), rows(a.run_dir), name)
            assert_same_weights(a, p, atol=1e-5)
            continue
        assert rows(p.run_dir) == rows(a.run_dir), name  # every iteration's and evaluation's figures
        assert_same_weights(a, p)
    assert sorted(seen) == sorted((k, i, i % 2 == 0 or i == t.config.num_iterations)
                                  for k, t in enumerate(packed) for i in range(1, t.config.num_iterations + 1))
    # the trial with fewer steps left the pack after its last iteration; the others went on
    assert [trial for trial, iteration, _ in seen if iteration == 3] == [0, 1, 2, 4, 5]


def test_the_batched_update_computes_what_each_learner_computes_alone(tmp_path):
    """``pack_mode="vmap"`` (what a GPU runs): the first rollout is the same, the losses and weights after it
    agree to float rounding, and a learner whose KL stops its epochs early stops there while the others go on."""
    trials = TRIALS
    alone = [trainer(tmp_path / "alone" / str(k), c) for k, c in enumerate(trials.values())]
    packed = [trainer(tmp_path / "packed" / str(k), c) for k, c in enumerate(trials.values())]
    for t in alone:
        t.start()  # (its log: ``train_iteration`` writes a row)
    first = [t.train_iteration() for t in alone]
    pack = Pack(packed, mode="vmap")
    placement = pack.placement(tuple(range(len(packed))))
    for t in packed:
        t.start()
    together = pack.train_iteration()
    groups = [keys for keys, batched in placement._update_groups if batched is not None]
    assert [len(keys) for keys in groups] == [9, 2]  # every feed-forward learner: one network shape; the LSTMs
    for name, a, p, row_a, row_p in zip(trials, alone, packed, first, together):
        for la, lp in zip(a.learners.values(), p.learners.values()):
            for key in ("actions", "logp"):  # the same rollout: acting is not batched differently
                torch.testing.assert_close(torch.stack(lp.buffer[key]), torch.stack(la.buffer[key]), atol=1e-6,
                                           rtol=0)
            lname = la.name
            assert row_p[f"{lname}/epochs"] == row_a[f"{lname}/epochs"], name
            for stat in ("loss", "policy_loss", "value_loss", "aux_loss", "approx_kl", "entropy"):
                assert row_p[f"{lname}/{stat}"] == pytest.approx(row_a[f"{lname}/{stat}"], rel=1e-4, abs=1e-6), \
                    (name, lname, stat)
        assert_same_weights(a, p, atol=1e-6)
        if "target KL" in name:  # its KL limit stopped it after the first epoch; the others ran all three
            assert row_p["leader/epochs"] == row_p["follower/epochs"] == 1
        else:
            assert set(row_p[f"{lr.name}/epochs"] for lr in p.learners.values()) == {3}
    pack.close()
    for t in [*alone, *packed]:
        t.log.close()


@pytest.mark.parametrize("mode", ["stacked", "vmap"])
def test_a_packed_run_stopped_and_resumed_continues_bit_for_bit(tmp_path, mode):
    trials = [TRIALS["seed 0"], TRIALS["seed 1, kappa 0, annealed"]]
    straight = [trainer(tmp_path / "a" / str(k), c) for k, c in enumerate(trials)]
    Pack(straight, mode=mode).train()
    first = [trainer(tmp_path / "b" / str(k), c) for k, c in enumerate(trials)]
    asked = iter([False, True])
    Pack(first, mode=mode).train(stop=lambda: next(asked))  # stopped after iteration 2, with a checkpoint
    assert [t.iteration for t in first] == [2, 2]
    resumed = [trainer(tmp_path / "b" / str(k), c) for k, c in enumerate(trials)]
    for t in resumed:
        t.restore(t.run_dir / "checkpoints" / "latest.pt")
    Pack(resumed, mode=mode).train()
    for a, b in zip(straight, resumed):
        assert rows(b.run_dir) == rows(a.run_dir)
        assert_same_weights(a, b)


def test_trials_of_other_shapes_cannot_share_a_pack(tmp_path):
    with pytest.raises(ValueError, match=r"^trial 1 of the pack has ppo.num_envs=8 where trial 0 has 4: a pack's "
                                         r"trials share"):
        Pack([trainer(tmp_path / "a", {"seed": 0}), trainer(tmp_path / "b", {"seed": 1, "ppo": {"num_envs": 8}})])


def test_cli_trains_seeds_as_one_pack_and_resumes_them(tmp_path):
    run = tmp_path / "run"
    tiny = ["--set", "ppo.num_envs=4", "--set", "ppo.num_steps=16", "--set", "env.horizon=12", "--set",
            "eval_every=0", "--no-progress", "--no-tensorboard"]
    cli = [sys.executable, "-m", "colorgrid_apps", "train"]
    done = subprocess.run([*cli, "--out", str(run), "--seeds", "0-1,5", "--set", "total_steps=64", *tiny],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "as one pack of 3 (seeds 0, 1, 5)" in done.stdout
    for seed in (0, 1, 5):
        assert json.loads((run / f"seed_{seed}" / "config.json").read_text())["seed"] == seed
        assert (run / f"seed_{seed}" / "checkpoints" / "latest.pt").is_file()
    assert (run / "seed_0" / "train.csv").read_text() != (run / "seed_1" / "train.csv").read_text()
    resumed = subprocess.run([*cli, "--resume", str(run), "--set", "total_steps=128", "--no-progress",
                              "--no-tensorboard"], capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    assert f"resuming {run} at step 64, 64, 64" in resumed.stdout
    assert resumed.stdout.count("done at step 128") == 3
    bad = subprocess.run([*cli, "--seeds", "3-1", "--print-config"], capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and bad.stderr.strip().splitlines() == [
        "colorgrid train: error: --seeds '3-1': give seeds as a range 0-7, a list 0,3,5, or both 0-3,8 (whole numbers "
        ">= 0, each range low-high with low <= high)"]


@pytest.mark.parametrize("text", ["3-1", "a,b", "-2", "", "0-99999"])
def test_bad_seeds_get_one_line_and_exit_code_2(text, capsys):
    assert train_main(["--seeds", text, "--print-config"]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"colorgrid train: error: --seeds {text!r}: give seeds as a range 0-7, a list 0,3,5, or both 0-3,8 "
        f"(whole numbers >= 0, each range low-high with low <= high)"]


def test_a_pack_of_one_is_the_trainer(tmp_path):
    """``Trainer.train`` runs through ``Pack``: one trial's placement is its own (the follower's update in its
    process on two threads), the pack makes no placement of its own, and ``on_iteration(row, saved)`` is called
    after every iteration as before packs."""
    t = trainer(tmp_path, TRIALS["seed 0"])
    assert Pack([t]).placement((0,)) is t.placement
    seen = []
    t.train(on_iteration=lambda row, saved: seen.append((row["iteration"], saved is not None,
                                                         sorted(t.placement._processes))))
    assert seen == [(1, False, [1]), (2, True, [1]), (3, True, [1])]  # the follower (learner 1) in its process
