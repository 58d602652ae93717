"""Sweeps without Ray (``colorgrid sweep run FILE --local N``): trials as plain processes, stopped with a checkpoint
by SIGTERM, Ctrl+C or ``--stop-after`` and continued by the same command to exactly the metrics of a run never
stopped; kept and finished trials skipped; the folder's tables the same as a Ray sweep's; a folder run by one
executor only."""

import json
import signal
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from train.sweep.local import grid, local_name, run_local
from train.sweep.results import read_tables
from train.sweep.spec import SweepError, load_sweep
from tests.sweep_files import sweep_file, wait_for_step

ROOT = Path(__file__).resolve().parents[1]
MACHINE = {"sps", "rollout_sps", "update_sps", "wall_time_s"}


def tiny(tmp_path: Path, seeds="[0]", total=512, save_every=2, top="", tables="") -> Path:
    return sweep_file(tmp_path, "tiny", '[params]\n"ppo.lr" = [1e-4, 1e-3]', seeds=seeds, total=total,
                      save_every=save_every, top=top, tables=tables)


MORE_SEEDS = '\n[[more_seeds]]\nseeds = [{seeds}]\nwhere = {{ "ppo.lr" = {where} }}\n'


def learned(curves: pd.DataFrame) -> pd.DataFrame:
    """What each trial learned, step by step, keyed by configuration and seed (folder names differ by executor)."""
    columns = [c for c in curves.columns if c not in MACHINE and c != "trial"]
    return curves[columns].sort_values(["configuration", "seed", "step"]).reset_index(drop=True)


def colorgrid(*args: str, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "colorgrid_apps", *args], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, **kw)


def test_grid_lists_every_trial_seed_by_seed(tmp_path):
    spec = load_sweep(tiny(tmp_path, seeds="[3, 4]"))
    assert grid(spec) == [{"seed": 3, "ppo.lr": 1e-4}, {"seed": 3, "ppo.lr": 1e-3},
                          {"seed": 4, "ppo.lr": 1e-4}, {"seed": 4, "ppo.lr": 1e-3}]
    names = {local_name(spec, p) for p in grid(spec)}
    assert len(names) == 4
    more = load_sweep(tiny(tmp_path, seeds="[3, 4, 5]"))  # more seeds: the same folders for the same trials
    assert names < {local_name(more, p) for p in grid(more)}


def test_grid_lists_more_seeds_last_and_for_their_configurations_only(tmp_path):
    spec = load_sweep(tiny(tmp_path, seeds="[3, 4]", tables=MORE_SEEDS.format(seeds="7, 5", where="1e-3")))
    assert grid(spec) == [{"seed": 3, "ppo.lr": 1e-4}, {"seed": 3, "ppo.lr": 1e-3},
                          {"seed": 4, "ppo.lr": 1e-4}, {"seed": 4, "ppo.lr": 1e-3},
                          {"seed": 7, "ppo.lr": 1e-3}, {"seed": 5, "ppo.lr": 1e-3}]
    assert len(grid(spec)) == spec.num_trials() == 6
    both = load_sweep(tiny(tmp_path, seeds="[3]", tables=MORE_SEEDS.format(seeds="4", where="[1e-4, 0.001]")))
    assert grid(both) == [{"seed": 3, "ppo.lr": 1e-4}, {"seed": 3, "ppo.lr": 1e-3},
                          {"seed": 4, "ppo.lr": 1e-4}, {"seed": 4, "ppo.lr": 1e-3}]


def test_a_file_that_adds_seeds_continues_its_folder(tmp_path):
    """A file that gains a ``[[more_seeds]]`` table continues the sweep's folder and trains only the new trials;
    one that drops it again leaves those trials out of the tables; a file whose trials differ is refused."""
    folder = tmp_path / "out"
    assert run_local(load_sweep(tiny(tmp_path), out=folder), processes=2) == 0
    assert len(read_tables(folder)[0]) == 2
    logs = {log: log.read_bytes() for log in folder.glob("trial_*/run/metrics.jsonl")}
    more = tiny(tmp_path, tables=MORE_SEEDS.format(seeds="1", where="1e-3"))
    run = colorgrid("sweep", "run", str(more), "--out", str(folder), "--local", "2")
    out, _ = run.communicate(timeout=300)
    assert run.returncode == 0, out
    assert "3 trials (2 configurations x 1 seed, and 1 more where [[more_seeds]] adds seeds)" in out, out
    assert "2 finished here before; 1 to run" in out and "1 of 1 trials ran to the end here" in out, out
    trained = sorted(json.loads((log.parent.parent / "params.json").read_text())["seed"]
                     for log in folder.glob("trial_*/run/metrics.jsonl"))
    assert trained == [0, 0, 1]
    assert all(log.read_bytes() == before for log, before in logs.items())  # the first two were not trained again
    trials, curves = read_tables(folder)
    assert sorted(zip(trials["ppo.lr"], trials["seed"])) == [(1e-4, 0), (1e-3, 0), (1e-3, 1)]
    assert trials["finished"].all() and curves.groupby("trial").size().tolist() == [8, 8, 8]
    assert (folder / "sweep.toml").read_text() == more.read_text()  # the folder keeps the file it now runs

    assert run_local(load_sweep(tiny(tmp_path), out=folder), processes=1) == 0  # back to the first file
    trials, _ = read_tables(folder)
    assert sorted(zip(trials["ppo.lr"], trials["seed"])) == [(1e-4, 0), (1e-3, 0)]

    other = sweep_file(tmp_path, "other", '[params]\n"ppo.lr" = [1e-4, 3e-3]', seeds="[0]")
    with pytest.raises(SweepError, match="holds a sweep of another file"):
        run_local(load_sweep(other, out=folder), processes=1)
    longer = tiny(tmp_path, total=1024, tables=MORE_SEEDS.format(seeds="1", where="1e-3"))
    with pytest.raises(SweepError, match="holds a sweep of another file"):
        run_local(load_sweep(longer, out=folder), processes=1)


def test_stopped_local_sweep_continues_to_the_metrics_of_one_never_stopped(tmp_path):
    path = tiny(tmp_path, total=64 * 60, save_every=5)
    straight = tmp_path / "straight"
    assert run_local(load_sweep(path, out=straight), processes=2) == 0

    folder = tmp_path / "stopped"
    run = colorgrid("sweep", "run", str(path), "--out", str(folder), "--local", "2")
    try:
        wait_for_step(folder, 64 * 8)  # SIGTERM three iterations after a trial's first checkpoint (at 5)
        run.send_signal(signal.SIGTERM)
        out, _ = run.communicate(timeout=120)
    finally:
        run.kill()
    assert run.returncode == 130, out
    assert "stopped before its end; continue it with the same command" in out
    for log in folder.glob("trial_*/run/metrics.jsonl"):  # each ended with a checkpoint of its last iteration
        last = json.loads(log.read_text().splitlines()[-1])["step"]
        assert last < 64 * 60
        assert (log.parent / "checkpoints" / "latest.pt").exists()

    again = colorgrid("sweep", "run", str(path), "--out", str(folder), "--local", "2")
    out, _ = again.communicate(timeout=300)
    assert again.returncode == 0, out
    assert "0 finished here before; 2 to run" in out and "2 of 2 trials ran to the end here" in out
    trials, curves = read_tables(folder)
    assert trials["finished"].all() and (trials["steps"] == 64 * 60).all()
    for trial in trials["trial"]:  # every step once, in order
        assert list(curves[curves["trial"] == trial]["step"]) == list(range(64, 64 * 61, 64))
    _, straight_curves = read_tables(straight)
    pd.testing.assert_frame_equal(learned(curves), learned(straight_curves))

    out, _ = colorgrid("sweep", "run", str(path), "--out", str(folder), "--local", "2").communicate(timeout=120)
    assert "2 finished here before; 0 to run" in out


def test_stop_after_ends_every_trial_and_starts_no_other(tmp_path):
    path = tiny(tmp_path, seeds="[0, 1]", total=64 * 100_000, save_every=1000)
    folder = tmp_path / "out"
    assert run_local(load_sweep(path, out=folder), processes=1, stop_after=0.5) == 130
    started = [p for p in folder.glob("trial_*") if (p / "run" / "metrics.jsonl").exists()]
    assert len(started) == 1  # the other three waited for a turn that came after the deadline
    log = started[0] / "run" / "metrics.jsonl"
    last = json.loads(log.read_text().splitlines()[-1])["step"]
    assert 64 <= last < 64 * 100_000 and (log.parent / "checkpoints" / "latest.pt").exists()
    assert json.loads((started[0] / "params.json").read_text()) == grid(load_sweep(path))[0]


def test_a_packed_sweep_keeps_what_an_unpacked_one_does(tmp_path):
    """``[resources] pack = 3``: the four trials train as two packs of two, in two processes, and
    the tables hold every figure the same as when each trial trains alone (bit for bit on a CPU)."""
    (tmp_path / "alone").mkdir()
    (tmp_path / "packed").mkdir()
    alone = tiny(tmp_path / "alone", seeds="[0, 1]", total=256)
    packed = tiny(tmp_path / "packed", seeds="[0, 1]", total=256, tables="pack = 3")
    assert run_local(load_sweep(alone, out=tmp_path / "a"), processes=2) == 0
    run = colorgrid("sweep", "run", str(packed), "--out", str(tmp_path / "p"), "--local", "2")
    out, _ = run.communicate(timeout=300)
    assert run.returncode == 0, out
    assert "4 trials in 2 packs of up to 3, 2 at a time" in out and "4 of 4 trials ran to the end here" in out
    trials_a, curves_a = read_tables(tmp_path / "a")
    trials_p, curves_p = read_tables(tmp_path / "p")
    pd.testing.assert_frame_equal(learned(curves_p), learned(curves_a))
    same = [c for c in trials_a.columns if c not in MACHINE and c != "trial" and "time" not in c]
    order = ["configuration", "seed"]
    pd.testing.assert_frame_equal(trials_p[same].sort_values(order).reset_index(drop=True),
                                  trials_a[same].sort_values(order).reset_index(drop=True))
    assert trials_p["finished"].all() and len(trials_p) == 4
    again = colorgrid("sweep", "run", str(packed), "--out", str(tmp_path / "p"), "--local", "2")
    out, _ = again.communicate(timeout=120)
    assert "4 finished here before; 0 to run" in out  # finished trials are not trained again


def test_kept_trials_are_not_run_and_tables_hold_them(tmp_path):
    from train.sweep.report import publish_report

    results = tmp_path / "kept"
    first = tiny(tmp_path, top=f'results = "{results}"')
    assert run_local(load_sweep(first, out=tmp_path / "one"), processes=2) == 0
    _, count, _ = publish_report(tmp_path / "one")
    assert count == 2
    more = tiny(tmp_path, seeds="[0, 1]", top=f'results = "{results}"')
    assert run_local(load_sweep(more, out=tmp_path / "two"), processes=2) == 0
    trained = sorted(json.loads((log.parent.parent / "params.json").read_text())["seed"]
                     for log in (tmp_path / "two").glob("trial_*/run/metrics.jsonl"))
    assert trained == [1, 1]
    trials, _ = read_tables(tmp_path / "two")
    assert sorted(zip(trials["ppo.lr"], trials["seed"])) == [(1e-4, 0), (1e-4, 1), (1e-3, 0), (1e-3, 1)]
    assert trials["finished"].all()


def test_a_folder_is_run_by_one_executor(tmp_path):
    path = tiny(tmp_path)
    folder = tmp_path / "out"
    folder.mkdir()
    (folder / "sweep.toml").write_text("description = 'another'\n")
    with pytest.raises(SweepError, match="holds a sweep of another file"):
        run_local(load_sweep(path, out=folder), processes=1)
    (folder / "sweep.toml").unlink()
    assert run_local(load_sweep(path, out=folder), processes=2) == 0
    from train.sweep.runner import run_sweep

    with pytest.raises(SweepError, match=r"holds a sweep run without Ray \(--local\); continue it with"):
        run_sweep(load_sweep(path, out=folder))


@pytest.mark.parametrize("args, words", [
    (["--local", "0"], "--local takes the number of trials to run at a time (>= 1), got 0"),
    (["--local", "1", "--stop-after", "0"], "--stop-after takes seconds (> 0), got 0.0"),
    (["--stop-after", "10"], "--local N is for sweep run, and --stop-after goes with --local"),
])
def test_bad_local_options_get_one_line(tmp_path, args, words):
    run = colorgrid("sweep", "run", str(tiny(tmp_path)), "--out", str(tmp_path / "out"), *args)
    out, _ = run.communicate(timeout=120)
    assert run.returncode == 2
    assert len(out.strip().splitlines()) == 1 and words in out, out


def test_publish_keeps_the_standing_of_unfinished_trials(tmp_path):
    from train.sweep.report import publish_report

    results = tmp_path / "kept"
    path = tiny(tmp_path, total=64 * 40, save_every=5, top=f'results = "{results}"')
    folder = tmp_path / "out"
    assert run_local(load_sweep(path, out=folder), processes=1, stop_after=0.5) == 130
    _, count, _ = publish_report(folder)
    assert count == 0
    standing = pd.read_csv(results / "unfinished.csv")
    assert set(standing["configuration"]) == {"ppo.lr=0.0001"} and standing["step"].max() < 64 * 40
    assert list(standing["step"]) == list(range(64, standing["step"].max() + 1, 64))
    assert {"team_reward", "penalty_coef", "seed", "ppo.lr"} <= set(standing.columns)
    assert pd.read_csv(results / "trials.csv").empty
    assert run_local(load_sweep(path, out=folder), processes=2) == 0
    _, count, _ = publish_report(folder)
    assert count == 2 and not (results / "unfinished.csv").exists()
