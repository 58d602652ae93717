"""``colorgrid replay release --recipe SWEEP_DIR``: one replay per arm of the recipe ablation
(docs/ASSISTANT_RECIPE.md), recorded from real trials of a small form of the sweep (sweeps/assistant_recipe_small.toml,
three arms, 256 steps, run without Ray), listed in the release's index and in the replay browser, and kept by a
release without it."""

import hashlib
import json
import shutil
import tomllib
from pathlib import Path

import pytest
from PIL import Image

from colorgrid import EnvConfig
from colorgrid.replay import load, verify
from colorgrid_apps.cli import main
from colorgrid_apps.release import RECIPE_SETTING, arm_slug
from train.sweep.local import local_name, run_local
from train.sweep.spec import load_sweep
from tests.conftest import start_server, stop_server
from tests.sweep_files import sweep_file

ROOT = Path(__file__).resolve().parents[1]
ARMS = ("recipe", "ippo-leader partner", "no memory")
"""The arms trained here: the recipe, the one with another training partner, one with another network."""
TOTAL = 256  # 4 iterations of 2 envs x 32 steps


def arms_file(tmp_path: Path) -> Path:
    """The small sweep file's settings and arms, only ``ARMS`` and ``TOTAL`` steps (its claims name the other arms)."""
    small = tomllib.loads((ROOT / "sweeps" / "assistant_recipe_small.toml").read_text())
    settings = [s for s in small["set"] if s.split("=")[0] not in ("total_steps", "eval_every", "save_every")]
    settings += [f"total_steps={TOTAL}", "eval_every=4", "save_every=4"]
    options = small["params"]["arm"]["options"]
    lines = ['description = "three arms of the recipe ablation, for the release tests"',
             f"preset = {json.dumps(small['preset'])}", f"set = {json.dumps(settings)}", "seeds = [0]",
             f"metric = {json.dumps(small['metric'])}", "final_window = 2", "", "[params.arm.options]"]
    for arm in ARMS:
        settings_of_arm = ", ".join(f"{json.dumps(key)} = {json.dumps(value)}" for key, value in options[arm].items())
        lines.append(f"{json.dumps(arm)} = {{ {settings_of_arm} }}")
    path = tmp_path / "arms.toml"
    path.write_text("\n".join([*lines, "", "[resources]", "cpus_per_trial = 1", ""]))
    return path


@pytest.fixture(scope="module")
def sweeps(tmp_path_factory):
    """``finished``: the three arms trained to their last step. ``mixed``: the same sweep where the recipe's trial
    stopped after its first iteration (a real stop with a checkpoint, as Ctrl+C leaves it) and the 'no memory'
    trial never started."""
    tmp = tmp_path_factory.mktemp("recipe")
    spec = load_sweep(arms_file(tmp), out=tmp / "finished")
    recipe = local_name(spec, {"seed": 0, "arm": "recipe"})
    # one trial at a time, stopped at once: the first (the recipe's) ends its first iteration with a checkpoint
    assert run_local(spec, processes=1, stop_after=1e-3) == 130
    shutil.copytree(tmp / "finished" / recipe, tmp / "stopped_recipe")
    assert run_local(spec, processes=2) == 0
    shutil.copytree(tmp / "finished", tmp / "mixed")
    shutil.rmtree(tmp / "mixed" / recipe)
    shutil.copytree(tmp / "stopped_recipe", tmp / "mixed" / recipe)
    shutil.rmtree(tmp / "mixed" / local_name(spec, {"seed": 0, "arm": "no memory"}))
    return {"finished": tmp / "finished", "mixed": tmp / "mixed",
            "trials": {arm: tmp / "finished" / local_name(spec, {"seed": 0, "arm": arm}) for arm in ARMS}}


def release(capsys, out: Path, *recipe: str) -> tuple[int, list[str], str]:
    """``colorgrid replay release`` (one episode per scripted pair): exit code, stdout lines, stderr."""
    code = main(["replay", "release", "--out", str(out), "--episodes", "1",
                 *(["--recipe", str(recipe[0])] if recipe else [])])
    captured = capsys.readouterr()
    return code, captured.out.splitlines(), captured.err


def recipe_entries(out: Path) -> dict[str, dict]:
    index = json.loads((out / "index.json").read_text())
    return {e["arm"]: e for e in index["replays"] if e.get("setting") == RECIPE_SETTING}


@pytest.fixture(scope="module")
def released(sweeps, tmp_path_factory):
    out = tmp_path_factory.mktemp("release") / "replays"
    code = main(["replay", "release", "--out", str(out), "--episodes", "1", "--recipe", str(sweeps["finished"])])
    assert code == 0
    return out


def test_one_replay_per_finished_arm_with_its_follower_beside_astar_and_its_beliefs(sweeps, released):
    assert sorted(p.name for p in (released / RECIPE_SETTING).iterdir()) == sorted(
        ["recipe_seed2026.replay.json", "ippo-leader-partner_seed2026.replay.json", "no-memory_seed2026.replay.json"])
    entries = recipe_entries(released)
    assert list(entries) == list(ARMS)  # the sweep file's order
    for arm in ARMS:
        trial = sweeps["trials"][arm]
        checkpoint = trial / "run" / "checkpoints" / "latest.pt"
        path = released / RECIPE_SETTING / f"{arm_slug(arm)}_seed2026.replay.json"
        replay = load(path)
        assert verify(replay, path).ok
        assert replay.seed == 2026 and replay.num_steps == 32  # the trial's own env: horizon 32
        assert replay.config == EnvConfig.from_dict(json.loads((trial / "run" / "config.json").read_text())["env"])
        follower = replay.agents["follower"]
        assert replay.agents["leader"] == {"policy": "astar"}  # the ippo-leader partner's arm too
        assert follower["policy"] == f"ippo [{arm}]"
        assert follower["checkpoint"] == str(checkpoint)
        assert follower["checkpoint_sha256"] == hashlib.sha256(checkpoint.read_bytes()).hexdigest()
        beliefs = replay.goal_probs["follower"]
        assert len(beliefs) == 32 and all(len(b) == 3 and abs(sum(b) - 1) < 1e-3 for b in beliefs)
        assert "leader" not in replay.goal_probs
        assert replay.meta == {"setting": RECIPE_SETTING, "arm": arm, "sweep": str(sweeps["finished"]),
                               "trial": trial.name, "step": TOTAL}
        entry = entries[arm]
        assert entry["file"] == f"{RECIPE_SETTING}/{arm_slug(arm)}_seed2026.replay.json"
        assert entry["agents"] == replay.agents and entry["final"] == replay.final()
        assert entry["description"] == (f"The recipe ablation's '{arm}' follower (seed 0, 256 steps) beside the A* "
                                        f"leader; asymmetric, +1/-1, goal hidden (docs/ASSISTANT_RECIPE.md).")
    index = json.loads((released / "index.json").read_text())
    assert index["generated_by"].endswith(f"--recipe {sweeps['finished']}")
    assert len(index["replays"]) == 12 + 3  # the scripted set (one episode each) and the arms


def test_export_makes_a_gif_of_a_recipe_replay(released, tmp_path, capsys):
    gif = tmp_path / "recipe.gif"
    assert main(["export", str(released / RECIPE_SETTING / "recipe_seed2026.replay.json"), "--format", "gif",
                 "--out", str(gif)]) == 0
    assert Image.open(gif).n_frames == 33  # every state of 32 steps


def test_a_release_without_recipe_keeps_the_recipe_replays(released, tmp_path, capsys):
    out = tmp_path / "replays"
    shutil.copytree(released, out)
    before = {p.name: p.read_bytes() for p in (out / RECIPE_SETTING).iterdir()}
    code, lines, _ = release(capsys, out)
    assert code == 0 and lines == [f"wrote 15 replays (3 of the recipe ablation's arms) and {out}/index.json"]
    assert recipe_entries(out) == recipe_entries(released)
    assert {p.name: p.read_bytes() for p in (out / RECIPE_SETTING).iterdir()} == before
    assert json.loads((out / "index.json").read_text())["generated_by"] == \
        f"colorgrid replay release --out {out} --episodes 1"


def test_arms_not_finished_are_skipped_with_one_line_each(sweeps, released, tmp_path, capsys):
    mixed = sweeps["mixed"]
    fresh = tmp_path / "fresh"
    code, lines, _ = release(capsys, fresh, mixed)
    assert code == 0
    stopped = local_name(load_sweep(mixed / "sweep.toml"), {"seed": 0, "arm": "recipe"})
    assert lines == [
        f"skipped the arm 'recipe': its seed-0 trial ({stopped}) has not finished (step 64 of 256)",
        f"skipped the arm 'no memory': its seed-0 trial has not started in {mixed}",
        f"recorded the arm 'ippo-leader partner' ({sweeps['trials']['ippo-leader partner'].name}, step 256): "
        f"{fresh}/{RECIPE_SETTING}/ippo-leader-partner_seed2026.replay.json",
        f"wrote 13 replays (1 of the recipe ablation's arms) and {fresh}/index.json"]
    assert [p.name for p in (fresh / RECIPE_SETTING).iterdir()] == ["ippo-leader-partner_seed2026.replay.json"]

    again = tmp_path / "again"  # over an earlier release: the skipped arms keep the replays they had
    shutil.copytree(released, again)
    code, lines, _ = release(capsys, again, mixed)
    assert code == 0 and lines[-1] == f"wrote 15 replays (3 of the recipe ablation's arms) and {again}/index.json"
    kept, before = recipe_entries(again), recipe_entries(released)
    assert list(kept) == list(ARMS)
    assert kept["recipe"] == before["recipe"] and kept["no memory"] == before["no memory"]
    assert kept["ippo-leader partner"]["sweep"] == str(mixed)


def test_arms_that_finished_on_another_machine_say_so(sweeps, tmp_path, capsys):
    """The trials ran on a lent machine, and only their results came back (``colorgrid sweep publish``): the
    checkpoints are not here, and the release says so instead of calling the trials not started."""
    from train.sweep.results import publish

    kept, lent, here = tmp_path / "kept", tmp_path / "lent", tmp_path / "here"
    shutil.copytree(sweeps["finished"], lent)
    text = f"results = {json.dumps(str(kept))}\n" + (lent / "sweep.toml").read_text()
    (lent / "sweep.toml").write_text(text)
    assert publish(lent) == (kept, 3)
    here.mkdir()
    (here / "sweep.toml").write_text(text)
    code, lines, _ = release(capsys, tmp_path / "replays", here)
    assert code == 0 and lines == [
        *(f"skipped the arm '{arm}': its seed-0 trial finished elsewhere (its results are kept in {kept}); its "
          f"checkpoint is not in {here}" for arm in ARMS),
        f"wrote 12 replays (0 of the recipe ablation's arms) and {tmp_path / 'replays'}/index.json"]


def test_a_folder_that_is_not_a_recipe_sweep_is_refused_in_one_line(tmp_path, capsys):
    out = tmp_path / "replays"
    code, lines, err = release(capsys, out, tmp_path)
    assert code == 2 and lines == []
    assert err == (f"colorgrid replay release: error: {tmp_path}: not a sweep folder (no sweep.toml); colorgrid sweep "
                   f"run FILE makes one\n")
    other = tmp_path / "other"  # a sweep, but of something else than the arms
    other.mkdir()
    (other / "sweep.toml").write_text(sweep_file(tmp_path, "lr", '[params]\n"ppo.lr" = [1e-4, 1e-3]').read_text())
    code, lines, err = release(capsys, out, other)
    assert code == 2 and lines == []
    assert err == (f"colorgrid replay release: error: {other}: not a recipe ablation (its trials vary ['ppo.lr'], not "
                   f"the arm alone)\n")
    assert not out.exists()  # refused before anything was recorded


def test_the_replay_browser_lists_each_arm_by_name(released, browser, tmp_path):
    from playwright.sync_api import expect

    server = start_server(tmp_path, "--released-dir", str(released))
    try:
        page = browser.new_page()
        page.goto(server.url + "/replays")
        page.select_option("#collection", "released")
        page.select_option("#setting", RECIPE_SETTING)
        expect(page.locator("#list tbody tr")).to_have_count(3)
        rows = page.locator("#list tbody tr")
        assert sorted(rows.locator("td:nth-child(6)").all_text_contents()) == sorted(f"ippo [{arm}]" for arm in ARMS)
        assert set(rows.locator("td:nth-child(3)").all_text_contents()) == {"recipe ablation"}
        assert set(rows.locator("td:nth-child(5)").all_text_contents()) == {"astar"}
        page.close()
    finally:
        stop_server(server)
