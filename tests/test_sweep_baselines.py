"""``colorgrid sweep baselines``: a sweep file's baselines evaluated on each trial seed's own evaluation episodes and
kept beside its results, checked against what is kept, and the kept files of the project reproduced by it."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import ROOT
from tests.sweep_files import sweep_file

CLAIM = """
[[claim]]
name = "beats copy"
paper = "a test claim"
metric = "eval_astar/follower_net_pickups"
a = {{ lr = 0.001 }}
b = {{ baseline = "{baseline}" }}
expect = ">"
"""


def colorgrid(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "colorgrid_apps", "sweep", *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=600)


def tiny(tmp_path: Path, baseline: str = "astar/copy", top: str = "") -> Path:
    """A one-trial-a-seed sweep of a follower beside the A* leader, evaluated beside A* on 3 episodes."""
    results = tmp_path / "kept"
    path = sweep_file(tmp_path, "baselines", '[params]\nlr = { keys = ["ppo.lr"], grid = [0.001] }',
                      top=f'results = "{results}"\n{top}', tables=CLAIM.format(baseline=baseline),
                      metric="eval_astar/follower_net_pickups")
    path.write_text(path.read_text().replace(
        '"eval_every=0"', '"eval_every=1", "eval_episodes=3", "leader.policy=astar", "eval_partners=[\\"astar\\"]"'))
    return path


@pytest.fixture
def tiny_file(tmp_path):
    return tiny(tmp_path, top='baselines = ["astar/bayes"]')


def test_the_baselines_are_the_eval_of_each_trial_seeds_evaluation_episodes(tiny_file, tmp_path):
    done = colorgrid("baselines", str(tiny_file))
    assert done.returncode == 0, done.stderr
    kept = json.loads((tmp_path / "kept" / "baselines.json").read_text())
    assert kept["seeds"] == [1_000_000, 1_000_001] and kept["episodes"] == 3
    assert list(kept["baselines"]) == ["astar/copy", "astar/bayes"]  # the claim's, then the file's list
    for follower in ("copy", "bayes"):
        figures = kept["baselines"][f"astar/{follower}"]
        for i, seed in enumerate(kept["seeds"]):  # what colorgrid eval prints for the same episodes
            out = tmp_path / f"{follower}_{seed}.json"
            ran = subprocess.run([sys.executable, "-m", "colorgrid_apps", "eval", "--leader", "astar", "--follower",
                                  follower, "--episodes", "3", "--seed", str(seed), "--set", "env.horizon=32",
                                  "--json", str(out)], cwd=ROOT, capture_output=True, text=True, timeout=600)
            assert ran.returncode == 0, ran.stderr
            report = json.loads(out.read_text())["agents"]["follower"]
            for figure in ("net_pickups", "wrong_pickups", "goal_pickups", "block_reward"):
                assert figures[f"{figure}_per_seed"][i] == report[figure]["mean"]
        assert figures["net_pickups"] == pytest.approx(sum(figures["net_pickups_per_seed"]) / 2)


def test_check_passes_on_what_it_wrote_and_names_a_changed_figure(tiny_file, tmp_path):
    assert colorgrid("baselines", str(tiny_file)).returncode == 0
    same = colorgrid("baselines", str(tiny_file), "--check")
    assert same.returncode == 0 and "every kept figure reproduced" in same.stdout
    path = tmp_path / "kept" / "baselines.json"
    kept = json.loads(path.read_text())
    kept["baselines"]["astar/bayes"]["wrong_pickups_per_seed"][1] += 0.5
    path.write_text(json.dumps(kept))
    changed = colorgrid("baselines", str(tiny_file), "--check")
    assert changed.returncode == 1
    assert "astar/bayes wrong_pickups_per_seed: kept" in changed.stdout and "1 difference(s)" in changed.stdout
    assert json.loads(path.read_text()) == kept  # a check writes nothing


def test_the_kept_baselines_of_the_partner_sweep_are_reproduced():
    """The baselines the IPPO-partner claims are paired with (docs/reproduction/assistant_partner) are what the
    command gives today, figure for figure."""
    done = colorgrid("baselines", "sweeps/assistant_partner.toml", "--check")
    assert done.returncode == 0, done.stdout + done.stderr
    assert "every kept figure reproduced" in done.stdout


@pytest.mark.parametrize("change, words", [
    (("baseline", "mystery/copy"), "claim[0].metric='eval_astar/follower_net_pickups' is invalid: an evaluation "
                                   "column played beside the baseline's partner 'mystery': eval_mystery/..."),
    (("baseline", "ippo-leader/copy"), "an evaluation column played beside the baseline's partner 'ippo-leader'"),
    (("top", 'baselines = ["mystery/copy"]'), "its partner 'mystery' is neither a policy name nor one of the trials' "
                                              "evaluation"),
    (("top", "baselines = [1]"), "baselines=[1] is invalid: a list of '<partner>/<policy>' strings"),
    (("top", "results_none"), "no results folder"),
    (("check", ""), "does not exist: run colorgrid sweep baselines"),
])
def test_a_bad_baselines_request_is_one_line_and_exit_2(tmp_path, change, words):
    kind, value = change
    path = tiny(tmp_path, **({"baseline": value} if kind == "baseline" else {"top": value} if kind == "top" else {}))
    if value == "results_none":
        path.write_text("\n".join(line for line in path.read_text().splitlines()
                                  if not line.startswith("results") and not line.startswith("results_none")))
    done = colorgrid("baselines", str(path), *(["--check"] if kind == "check" else []))
    assert done.returncode == 2, done.stdout + done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and words in lines[0], done.stderr


@pytest.mark.parametrize("name, key, grid, field", [
    ("density", "env.block_density", [0.1, 0.05], "env"),
    ("episodes", "eval_episodes", [3, 4], "eval_episodes"),
])
def test_configurations_evaluated_on_other_episodes_share_no_baseline(tmp_path, name, key, grid, field):
    path = tiny(tmp_path)
    path.write_text(path.read_text().replace("[params]\n", f'[params]\n{name} = {{ keys = ["{key}"], grid = {grid} }}\n')
                    .replace("a = { lr = 0.001 }", f"a = {{ lr = 0.001, {name} = {grid[0]} }}"))
    done = colorgrid("baselines", str(path))
    assert done.returncode == 2, done.stdout + done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and f"has another {field} than" in lines[0] and "own sweep file" in lines[0], done.stderr
    assert not (tmp_path / "kept" / "baselines.json").exists()


def test_a_claim_on_the_main_evaluation_pairs_only_with_a_baseline_beside_the_arms_own_partner(tmp_path):
    """``eval/...`` is played beside the partner the arm trains with (A* here): a baseline beside another leader
    played other episodes, and is refused when the file is read; beside A* itself it pairs."""
    path = tiny(tmp_path, baseline="ippo-leader/copy")
    path.write_text(path.read_text().replace('metric = "eval_astar/follower_net_pickups"',
                                             'metric = "eval/follower_net_pickups"'))
    done = colorgrid("check", str(path))
    assert done.returncode == 2 and "claim[0].b='ippo-leader/copy' is invalid: a baseline beside the partner side " \
                                    "a's trials are evaluated beside on 'eval/follower_net_pickups' (['astar'])" \
                                    in done.stderr, done.stderr
    path.write_text(path.read_text().replace("ippo-leader/copy", "astar/copy"))
    assert colorgrid("check", str(path)).returncode == 0


def test_check_is_only_for_baselines(tmp_path):
    done = colorgrid("check", str(tiny(tmp_path)), "--check")
    assert done.returncode == 2 and "--check is for sweep baselines" in done.stderr
