"""Sweeps on a real local Ray instance (one for the module): tables and report, a trial killed mid-run that
resumes to exactly the metrics it would have had, a sweep interrupted by Ctrl+C and finished by ``sweep
resume``, and ASHA stopping trials early."""

import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pandas as pd
import pytest
import ray

from train.sweep.local import run_local
from train.sweep.report import mean_interval, write_report
from train.sweep.results import read_tables
from train.sweep.runner import resume_sweep, run_sweep
from train.sweep.spec import load_sweep
from tests.sweep_files import sweep_file, wait_for_step

ROOT = Path(__file__).resolve().parents[1]
MACHINE = {"sps", "rollout_sps", "update_sps", "wall_time_s", "torch_threads", "numba_threads"}
"""Columns that describe the machine, not what was learned (the thread counts come from Tune's reports, whose
last few before a kill are lost)."""


@pytest.fixture(scope="module", autouse=True)
def local_ray():
    ray.init(num_cpus=2, include_dashboard=False, logging_level="WARNING", log_to_driver=False)
    yield
    ray.shutdown()


def learned(curves: pd.DataFrame) -> pd.DataFrame:
    """What a trial learned, step by step: its curves without the machine's timings."""
    columns = [c for c in curves.columns if c not in MACHINE and c not in ("trial", "node_id")]
    return curves[columns].reset_index(drop=True)


def test_tiny_sweep_writes_tables_and_report(tmp_path):
    path = sweep_file(tmp_path, "tiny", '[params]\n"ppo.lr" = [1e-4, 1e-3]',
                      tables='\n[[paper]]\nwhere = { "ppo.lr" = 1e-3 }\nvalue = 12.5\n')
    spec = load_sweep(path, out=tmp_path / "out")
    assert run_sweep(spec) == 0
    trials, curves = read_tables(tmp_path / "out")
    assert sorted(zip(trials["ppo.lr"], trials["seed"])) == [(1e-4, 0), (1e-4, 1), (1e-3, 0), (1e-3, 1)]
    assert trials["finished"].all() and (trials["steps"] == 512).all()
    assert (pd.read_csv(tmp_path / "out" / "trials.csv")["final_team_reward"].to_numpy()
            == pytest.approx(trials["final_team_reward"].to_numpy()))
    for _, trial in trials.iterrows():  # the final value is the mean of the trial's last final_window reports
        mine = curves[curves["trial"] == trial["trial"]].sort_values("step")
        assert list(mine["step"]) == list(range(64, 513, 64))
        assert (mine["torch_threads"] == 1).all() and (mine["numba_threads"] == 1).all()  # the trial's one CPU
        assert trial["final_team_reward"] == pytest.approx(mine["team_reward"].dropna().iloc[-2:].mean())
        run = tmp_path / "out" / trial["trial"] / "run"
        config = json.loads((run / "config.json").read_text())
        assert (config["ppo"]["lr"], config["seed"], config["threads"]) == (trial["ppo.lr"], trial["seed"], 1)
        assert (run / "checkpoints" / "latest.pt").exists() and not list(run.glob("checkpoints/step_*"))
    text, pictures = write_report(tmp_path / "out")
    assert (tmp_path / "out" / "report.md").read_text() == text
    assert [p.name for p in pictures] == ["curves_team_reward.png"] and pictures[0].stat().st_size > 10_000
    assert pictures[0].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    summary = pd.read_csv(tmp_path / "out" / "summary.csv")
    row = summary[summary["ppo.lr"] == 1e-3].iloc[0]
    mean, half, n = mean_interval(trials[trials["ppo.lr"] == 1e-3]["final_team_reward"])
    assert (row["seeds"], n) == (2, 2)
    assert row["final_team_reward_mean"] == pytest.approx(mean) and row["final_team_reward_ci95"] == pytest.approx(half)
    assert f"| ppo.lr=0.001 | 2 (2) | 512 | {mean:+.2f} ± {half:.2f} | +12.5 |" in text
    # a second run into the same folder is refused: the sweep is resumed, never overwritten
    with pytest.raises(ValueError, match="already holds a sweep; finish it with colorgrid sweep resume"):
        run_sweep(spec)
    with pytest.raises(ValueError, match="holds a sweep run on Ray Tune; finish it with colorgrid sweep resume"):
        run_local(spec, processes=1)  # nor continued without Ray: both would hold the same trials


def test_a_packed_sweep_on_ray_keeps_what_an_unpacked_one_does(tmp_path, capsys):
    """``[resources] pack = 3`` on Ray Tune: two Tune trials train the four trials (two packs of two),
    each trial in a folder of its own with a checkpoint; the tables are those of the trials trained alone."""
    params = '[params]\n"ppo.lr" = [1e-4, 1e-3]'
    alone = sweep_file(tmp_path, "alone", params)
    packed = sweep_file(tmp_path, "packed", params, tables="pack = 3")
    assert run_local(load_sweep(alone, out=tmp_path / "a"), processes=2) == 0
    capsys.readouterr()
    assert run_sweep(load_sweep(packed, out=tmp_path / "p")) == 0
    out = capsys.readouterr().out
    assert "ended [pack of 2: ppo.lr=0.0001, seed=0; ppo.lr=0.001, seed=0]" in out, out
    assert "ended [pack of 2: ppo.lr=0.0001, seed=1; ppo.lr=0.001, seed=1]" in out, out
    assert "4 of 4 trials ran to the end" in out, out
    trials_a, curves_a = read_tables(tmp_path / "a")
    trials_p, curves_p = read_tables(tmp_path / "p")
    assert len(trials_p) == 4 and trials_p["finished"].all()
    order = ["configuration", "seed", "step"]
    columns = [c for c in learned(curves_a).columns if c in curves_p.columns]
    pd.testing.assert_frame_equal(curves_p[columns].sort_values(order).reset_index(drop=True),
                                  curves_a[columns].sort_values(order).reset_index(drop=True))
    for trial in trials_p["trial"]:  # each trial's own folder, run and checkpoint, beside its pack's Tune trial
        assert (tmp_path / "p" / trial / "run" / "checkpoints" / "latest.pt").exists()
        assert "pack" not in json.loads((tmp_path / "p" / trial / "params.json").read_text())
    mine = curves_p.sort_values("step")  # the node and threads of each step, as an unpacked Ray trial's
    assert (mine["torch_threads"] == 1).all() and (mine["numba_threads"] == 1).all()
    assert (trials_p["node"].str.len() > 10).all()
    with pytest.raises(ValueError, match=r"^\[resources\] pack = 3 with \[scheduler\] kind = 'asha': "):
        run_sweep(load_sweep(sweep_file(tmp_path, "asha", params, tables="pack = 3\n[scheduler]\nkind = 'asha'"),
                             out=tmp_path / "asha"))


def test_kept_trials_are_not_run_again(tmp_path, capsys):
    """A sweep publishes its finished trials into its results folder; the same sweep with more seeds (one of them
    for one configuration only, ``[[more_seeds]]``), started in a fresh folder (a new machine), trains only the
    trials not kept, and its tables hold both."""
    from train.sweep.report import publish_report

    results = tmp_path / "kept"
    first = sweep_file(tmp_path, "kept", '[params]\n"ppo.lr" = [1e-4, 1e-3]', seeds="[0]", top=f'results = "{results}"')
    assert run_sweep(load_sweep(first, out=tmp_path / "one")) == 0
    _, count, _ = publish_report(tmp_path / "one")
    assert count == 2 and len(pd.read_csv(results / "trials.csv")) == 2
    more = sweep_file(tmp_path, "kept", '[params]\n"ppo.lr" = [1e-4, 1e-3]', seeds="[0, 1]",
                      top=f'results = "{results}"',
                      tables='\n[[more_seeds]]\nseeds = [2]\nwhere = { "ppo.lr" = 1e-3 }\n')
    capsys.readouterr()
    assert run_sweep(load_sweep(more, out=tmp_path / "two")) == 0
    out = capsys.readouterr().out
    assert "5 trials (2 configurations x 2 seeds, and 1 more where [[more_seeds]] adds seeds)" in out, out
    assert "2 of 5 trials are kept in" in out, out
    assert "5 of 5 trials ran to the end; tables in" in out, out  # the grid's (1e-4, seed 2) is no trial of it
    assert "seed=2" not in out.replace("ppo.lr=0.001, seed=2", ""), out  # nor printed as one
    trained = sorted(json.loads((log.parent.parent / "params.json").read_text())["seed"]
                     for log in (tmp_path / "two").glob("trial_*/run/metrics.jsonl"))
    assert trained == [1, 1, 2]  # seed 0 of each configuration is kept: not trained again; seed 2 for 1e-3 only
    trials, curves = read_tables(tmp_path / "two")
    assert len(trials) == 5
    assert sorted(zip(trials["ppo.lr"], trials["seed"])) == [(1e-4, 0), (1e-4, 1), (1e-3, 0), (1e-3, 1), (1e-3, 2)]
    assert not ((trials["ppo.lr"] == 1e-4) & (trials["seed"] == 2)).any()
    assert trials["finished"].all() and curves.groupby("trial").size().tolist() == [8, 8, 8, 8, 8]
    kept = pd.read_csv(results / "trials.csv").set_index("trial")
    for _, row in trials[trials["seed"] == 0].iterrows():
        assert row["final_team_reward"] == pytest.approx(kept.loc[row["trial"], "final_team_reward"])


def parent(pid: int) -> int:
    return int((Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()[1])


def trial_processes() -> list[int]:
    """The pids of the processes running a Tune trial of this test's Ray (Ray names them ``ray::ImplicitFunc...``;
    they descend from this process, which started Ray)."""
    pids = []
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            if not cmdline.read_bytes().startswith(b"ray::ImplicitFunc"):
                continue
            pid = ancestor = int(cmdline.parent.name)
            while ancestor > 1 and ancestor != os.getpid():
                ancestor = parent(ancestor)
            if ancestor == os.getpid():
                pids.append(pid)
        except (OSError, ValueError, IndexError):  # a process that ended while we looked
            continue
    return pids


def watch_and_kill(folder: Path, at_step: int, stop: threading.Event, killed: list) -> None:
    """SIGKILL the (only) running trial's process once its training log has passed ``at_step``."""
    while not stop.is_set():
        for log in folder.glob("trial_*/run/metrics.jsonl"):
            try:
                steps = [json.loads(line)["step"] for line in log.read_text().splitlines() if line.endswith("}")]
            except (OSError, ValueError):
                continue
            pids = trial_processes()
            if steps and steps[-1] >= at_step and len(pids) == 1:
                os.kill(pids[0], signal.SIGKILL)
                killed.append(steps[-1])
                return
        time.sleep(0.02)


def steps_reported(trial_dir: Path) -> list[int]:
    """Every step a trial's training log recorded, in order (a restarted trial's repeated steps included)."""
    lines = (trial_dir / "run" / "metrics.jsonl").read_text().splitlines()
    return [row["step"] for row in map(json.loads, lines) if row["stream"] == "train"]


def test_trial_killed_mid_run_resumes_to_the_same_metrics(tmp_path):
    """Two trials of one configuration (two options that change nothing), run one after the other; the first is
    SIGKILLed six iterations past its first checkpoint. Tune restarts it from a checkpoint, not from the start,
    and it ends with exactly the other's learning curve."""
    path = sweep_file(tmp_path, "kill", '[params.copy.options]\nkilled = {}\nuntouched = {}', seeds="[3]",
                      total=64 * 40, save_every=8)
    path.write_text(path.read_text().replace("cpus_per_trial = 1", "cpus_per_trial = 1\nmax_concurrent = 1"))
    folder = tmp_path / "out"
    stop, killed = threading.Event(), []
    watcher = threading.Thread(target=watch_and_kill, args=(folder, 64 * 14, stop, killed), daemon=True)
    watcher.start()
    try:
        assert run_sweep(load_sweep(path, out=folder)) == 0
    finally:
        stop.set()
        watcher.join()
    assert killed and killed[0] < 64 * 40, "the trial ended before it could be killed"
    trials, curves = read_tables(folder)
    assert trials["finished"].all()
    by_copy = {c: learned(curves[curves["copy"] == c]).drop(columns=["copy", "configuration"])
               for c in ("killed", "untouched")}
    assert len(by_copy["killed"]) == 40
    pd.testing.assert_frame_equal(by_copy["killed"], by_copy["untouched"])
    steps = steps_reported(folder / trials[trials["copy"] == "killed"]["trial"].iloc[0])
    drops = [i for i in range(1, len(steps)) if steps[i] <= steps[i - 1]]
    assert len(drops) == 1, steps  # one restart ...
    restart = steps[drops[0]]
    assert restart > 64 and (restart - 64) % (64 * 8) == 0, steps  # ... from a checkpoint (every 8 iterations)


def test_interrupted_sweep_finishes_with_sweep_resume(tmp_path):
    path = sweep_file(tmp_path, "stop", '[params]\n"ppo.lr" = [1e-4, 3e-4]', total=64 * 60, save_every=5)
    folder = tmp_path / "out"
    run = subprocess.Popen([sys.executable, "-m", "colorgrid_apps", "sweep", "run", str(path), "--out", str(folder),
                            "--num-cpus", "1"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        wait_for_step(folder, 64 * 8)  # Ctrl+C three iterations after a trial's first checkpoint (at 5)
        run.send_signal(signal.SIGINT)
        out, _ = run.communicate(timeout=120)
    finally:
        run.kill()
    assert run.returncode == 130, out
    assert f"finish it with: colorgrid sweep resume {folder}" in out
    trials, _ = read_tables(folder)
    assert not trials["finished"].all()
    assert resume_sweep(folder) == 0
    trials, curves = read_tables(folder)
    assert len(trials) == 4 and trials["finished"].all() and (trials["steps"] == 64 * 60).all()
    for trial in trials["trial"]:  # every step once in the table, in order
        assert list(curves[curves["trial"] == trial]["step"]) == list(range(64, 64 * 61, 64))
    restarts = [steps[i] for trial in trials["trial"] for steps in [steps_reported(folder / trial)]
                for i in range(1, len(steps)) if steps[i] <= steps[i - 1]]
    assert restarts and all(r > 64 and (r - 64) % (64 * 5) == 0 for r in restarts), restarts  # from checkpoints


def test_asha_stops_trailing_trials_early(tmp_path):
    """Trials run one at a time, each worse than the last (the metric is the penalty coefficient, which the
    config sets and the log reports): ASHA lets the first run to the end and stops the others at the first rung."""
    path = sweep_file(tmp_path, "asha", '[params]\n"env.penalty_coef" = [1.0, 0.75, 0.5, 0.25]', seeds="[0]",
                      total=64 * 16, metric="penalty_coef", top="",
                      tables="\n[scheduler]\nkind = \"asha\"\ngrace_period = 128\nreduction_factor = 2\n")
    text = path.read_text().replace("cpus_per_trial = 1", "cpus_per_trial = 1\nmax_concurrent = 1")
    path.write_text(text)
    assert run_sweep(load_sweep(path, out=tmp_path / "out")) == 0
    trials, _ = read_tables(tmp_path / "out")
    steps = dict(zip(trials["env.penalty_coef"], trials["steps"]))
    assert steps[1.0] == 64 * 16
    assert all(steps[p] < 64 * 16 for p in (0.75, 0.5, 0.25)), steps
    assert not math.isnan(trials["best_penalty_coef"].iloc[0])
