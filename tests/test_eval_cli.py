"""The evaluation command, run as a user would."""

import json
import subprocess
import sys


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "colorgrid_apps", *args], capture_output=True, text=True, timeout=300)


def test_eval_prints_a_table_and_writes_documented_json(tmp_path):
    out = tmp_path / "report.json"
    result = run_cli("eval", "--leader", "astar", "--follower", "bayes", "--episodes", "4", "--seed", "3",
                     "--set", "horizon=32", "--json", str(out))
    assert result.returncode == 0, result.stderr
    assert "follower belief accuracy" in result.stdout and "astar + bayes" in result.stdout
    report = json.loads(out.read_text())
    assert {"env_id", "config", "episodes", "seed", "leader", "follower", "agents", "team_reward",
            "wall_seconds", "cpu_seconds", "goal_switches_per_episode"} <= set(report)
    assert report["config"]["horizon"] == 32 and report["episodes"] == 4
    follower = report["agents"]["follower"]
    assert {"block_reward", "goal_pickups", "wrong_pickups", "net_pickups", "belief"} <= set(follower)
    assert set(follower["belief"]) == {"accuracy", "log_loss"}
    assert {"mean", "ci95"} == set(report["team_reward"])
    goal, wrong = follower["goal_pickups"]["mean"], follower["wrong_pickups"]["mean"]
    assert abs(follower["net_pickups"]["mean"] - (goal - wrong)) < 1e-9


def test_eval_compare_uses_the_same_seeds(tmp_path):
    out = tmp_path / "cmp.json"
    result = run_cli("eval", "--compare", "idle", "oracle", "--episodes", "3", "--set", "horizon=24", "--json", str(out))
    assert result.returncode == 0, result.stderr
    reports = json.loads(out.read_text())["reports"]
    assert [r["follower"]["policy"] for r in reports] == ["idle", "oracle"]
    assert reports[0]["agents"]["follower"]["goal_pickups"]["mean"] == 0.0
    assert reports[1]["agents"]["follower"]["wrong_pickups"]["mean"] == 0.0


def test_eval_reports_bad_arguments_clearly():
    result = run_cli("eval", "--follower", "nope", "--episodes", "2")
    assert result.returncode == 2 and "unknown policy 'nope'" in result.stderr
    result = run_cli("eval", "--set", "wrong_penalty=-1", "--episodes", "2")
    assert result.returncode == 2 and "wrong_penalty must be a finite non-negative magnitude" in result.stderr


def test_compare_columns_of_one_kind_with_different_parameters_read_apart():
    from colorgrid.config import EnvConfig
    from colorgrid.evaluate import evaluate, format_reports

    config = EnvConfig(horizon=16)
    specs = ["person:base=astar,slip=0.1", "person:base=astar,slip=0.3"]
    reports = [evaluate(config, spec, "bayes", episodes=1, seed=0) for spec in specs]
    assert [r["specs"]["leader"] for r in reports] == specs
    head = format_reports(reports).splitlines()[0]
    assert f"{specs[0]} + bayes" in head and f"{specs[1]} + bayes" in head


def test_replays_of_two_settings_of_one_policy_keep_apart(tmp_path):
    """``--compare`` of one policy at two settings with ``--record``: each setting's replays under its own name."""
    from colorgrid.config import EnvConfig
    from colorgrid.evaluate import evaluate, replay_tag
    from colorgrid.replay import load

    config = EnvConfig(horizon=16)
    paths = [evaluate(config, "astar", f"bayes:lapse={lapse}", 2, 0, record_dir=tmp_path)["replays"]
             for lapse in (0.1, 0.3)]
    assert len(set(paths[0] + paths[1])) == 4 and len(list(tmp_path.glob("*.replay.json"))) == 4
    assert [load(p).agents["follower"]["params"]["lapse"] for p in (paths[0][0], paths[1][0])] == [0.1, 0.3]
    long = "shielded:mover=ippo-people,reader=(bayes:rationality=3,lapse=0.05),min_belief=0.8"
    assert len(replay_tag(long)) == 60 and replay_tag(long) != replay_tag(long.replace("0.8", "0.9"))
    assert replay_tag("runs/a/x.pt:temperature=0") == "x_temperature_0" and replay_tag("astar") == "astar"
