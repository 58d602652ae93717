"""The sweep file: every kind of mistake gets one line naming the place and what is allowed, exit code 2;
good files build the trials' training configs as ``colorgrid train --set`` would. No Ray is started here."""

import hashlib
import json
from pathlib import Path

import pytest

from colorgrid_apps.cli import main
from train.config import from_dict, load_preset, merge, parse_override
from train.sweep.claim_spec import Baseline
from train.sweep.spec import SweepError, load_sweep
from train.sweep.trial import trial_config

ROOT = Path(__file__).resolve().parents[1]
GOOD = """
description = "a test"
preset = "default"
set = ["total_steps=4096", "env.asymmetric=false"]
seeds = [0, 1]
metric = "team_reward"

[params.aux]
keys = ["leader.aux_coef", "follower.aux_coef"]
grid = [0.0, 0.2]

[params.annealing.options]
none = {}
early = { "schedule.penalty_start" = 0, "schedule.penalty_end" = 2048 }

[params."ppo.lr"]
loguniform = [1e-5, 1e-3]
"""


def write(tmp_path: Path, text: str, name: str = "s.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_good_file_builds_each_trial_config_as_train_set_would(tmp_path):
    spec = load_sweep(write(tmp_path, "num_samples = 3\n" + GOOD))
    assert spec.num_trials() == 2 * 2 * 3 * 2 and spec.grid_size() == 4
    draws = spec.samples()
    assert len(draws) == 3 and all(1e-5 <= d["ppo.lr"] <= 1e-3 for d in draws)
    assert spec.samples() == draws  # drawn the same every time (resume rebuilds the same trials)
    params = {"seed": 1, "aux": 0.2, "annealing": "early", "ppo.lr": None, "sample": draws[2]}
    config = trial_config(spec, params)
    expected = load_preset("default")
    for line in ["total_steps=4096", "env.asymmetric=false", "leader.aux_coef=0.2", "follower.aux_coef=0.2",
                 "schedule.penalty_start=0", "schedule.penalty_end=2048", f"ppo.lr={draws[2]['ppo.lr']}", "seed=1",
                 "threads=1", "device=\"cpu\"", "update_processes=false"]:  # (threads in a Ray worker)
        expected = merge(expected, parse_override(line))
    assert config == from_dict(expected)
    none = trial_config(spec, {**params, "annealing": "none"})
    assert none.schedule.penalty_start is None and none.leader.aux_coef == 0.2


def test_shipped_sweep_files_load():
    files = sorted((ROOT / "sweeps").glob("*.toml"))
    assert files, "sweeps/ holds the paper's experiments"
    for path in files:
        spec = load_sweep(path)
        assert spec.num_trials() >= 1 and spec.description


def test_pinned_files_kept_in_the_repository_are_the_ones_pinned(monkeypatch):
    """A shipped sweep file that pins a file outside ``runs/`` (which a command makes again) pins one kept here,
    in ``sweeps/inputs/``, unchanged since it was pinned: ``sweep check`` accepts the file from the checkout."""
    monkeypatch.chdir(ROOT)
    kept = {}
    for path in sorted((ROOT / "sweeps").glob("*.toml")):
        spec = load_sweep(path)
        inside = {name: digest for name, digest in spec.pinned.items() if not name.startswith("runs/")}
        for name in inside:
            assert name.startswith("sweeps/inputs/"), f"{path.name} pins {name}: keep it in sweeps/inputs/"
        if inside:
            spec.check_files()  # (each pinned file's sha256 against its pin; the error names the file)
            kept[path.name] = inside
    assert "paper_warmstart_small_confirm_kept.toml" in kept, kept


MISTAKES = {
    "unknown top-level field": ("sedes = [1]\n" + GOOD, "unknown field 'sedes'"),
    "seeds not distinct": (GOOD.replace("seeds = [0, 1]", "seeds = [1, 1]"),
                           "seeds=[1, 1] is invalid: a list of distinct"),
    "negative seed": (GOOD.replace("seeds = [0, 1]", "seeds = [-1]"), "seeds=[-1] is invalid"),
    "unknown training key": (GOOD.replace('"follower.aux_coef"]', '"follower.aux_coeff"]'),
                             "params.aux.keys: unknown TrainConfig field 'follower.aux_coeff'; allowed: ["),
    "bad value for a key": (GOOD.replace("grid = [0.0, 0.2]", "grid = [0.0, -1.0]"),
                            "params (aux=-1.0, annealing='none', ppo.lr=1e-05): leader.aux_coef=-1.0 is invalid"),
    "bad option value": (GOOD.replace('"schedule.penalty_end" = 2048', '"schedule.penalty_end" = "soon"'),
                         "schedule.penalty_end='soon' is invalid"),
    "two kinds": (GOOD.replace("grid = [0.0, 0.2]", "grid = [0.0, 0.2]\nchoice = [1]"),
                  "params.aux: needs exactly one of"),
    "no kind": (GOOD.replace("grid = [0.0, 0.2]", "gird = [0.0, 0.2]"), "params.aux: unknown field 'gird'"),
    "loguniform from zero": (GOOD.replace("loguniform = [1e-5, 1e-3]", "loguniform = [0, 1e-3]"),
                             "params.ppo.lr.loguniform=[0, 0.001] is invalid: [low, high] with 0 < low < high"),
    "empty grid": (GOOD.replace("grid = [0.0, 0.2]", "grid = []"), "params.aux.grid=[] is invalid"),
    "seed as a parameter": (GOOD + '\n[params.seed]\ngrid = [1, 2]\n', "params='seed' is invalid: names of"),
    "seed in set": (GOOD.replace('"env.asymmetric=false"]', '"env.asymmetric=false", "seed=3"]'),
                    "set[2]='seed=3' is invalid: any training key but seed"),
    "set not KEY=VALUE": (GOOD.replace('"env.asymmetric=false"]', '"env.asymmetric"]'),
                          "set[1]: --set 'env.asymmetric': expected KEY=VALUE"),
    "unknown preset": (GOOD.replace('preset = "default"', 'preset = "defualt"'), "preset: unknown preset 'defualt'"),
    "unknown metric": (GOOD.replace('metric = "team_reward"', 'metric = "team_rewards"'),
                       "metric='team_rewards' is invalid: a column of the training log"),
    "bad mode": ('mode = "maximum"\n' + GOOD, "mode='maximum' is invalid: 'max' or 'min'"),
    "num_samples without random": ("num_samples = 2\n"
                                   + GOOD.replace('[params."ppo.lr"]\nloguniform = [1e-5, 1e-3]', ""),
                                   "num_samples=2 is invalid: 1 unless a parameter is random"),
    "bad scheduler": (GOOD + '\n[scheduler]\nkind = "hyperband"\n', "scheduler.kind='hyperband' is invalid"),
    "zero cpus": (GOOD + "\n[resources]\ncpus_per_trial = 0\n", "resources.cpus_per_trial=0 is invalid"),
    "unknown resource": (GOOD + "\n[resources]\ncpu = 1\n", "resources: unknown field 'cpu'"),
    "paper figure for an unknown value": (GOOD + '\n[[paper]]\nwhere = { aux = 0.5 }\nvalue = 48.8\n',
                                          "paper[0].where.aux=0.5 is invalid: one of [0.0, 0.2]"),
    "not TOML": ("seeds = [0,\n", "not valid TOML"),
    "a reserved parameter name": (GOOD + '\n[params.sample]\nkeys = ["ppo.ent_coef"]\ngrid = [0.0]\n',
                                  "params='sample' is invalid: names of 1 to 64 letters"),
    "two parameters set one key": (GOOD + '\n[params.kappa]\nkeys = ["follower.aux_coef"]\ngrid = [0.5]\n',
                                   "params.kappa='follower.aux_coef' is invalid: a key no other parameter sets "
                                   "(params.aux sets it too)"),
    "asha grace beyond the run": (GOOD + '\n[scheduler]\nkind = "asha"\ngrace_period = 5000\n',
                                  "scheduler.grace_period=5000 is invalid: fewer env steps than total_steps=4096"),
    "asha over runs of unequal length": (GOOD + '\n[params.budget]\nkeys = ["total_steps"]\ngrid = [4096, 8192]\n'
                                         '[scheduler]\nkind = "asha"\n', "a sweep whose trials all train as long"),
    "an empty paper where": (GOOD + '\n[[paper]]\nwhere = {}\nvalue = 1.0\n', "paper[0].where={} is invalid"),
    "more seeds already in seeds": (GOOD + '\n[[more_seeds]]\nseeds = [2, 1]\nwhere = { aux = 0.2 }\n',
                                    "more_seeds[0].seeds=[2, 1] is invalid: seeds not already in 'seeds' [0, 1] "
                                    "(1 is)"),
    "more seeds for an unknown parameter": (GOOD + '\n[[more_seeds]]\nseeds = [2]\nwhere = { kappa = 0.2 }\n',
                                            "more_seeds[0].where='kappa' is invalid: one of the listed parameters "
                                            "['aux', 'annealing']"),
    "more seeds for a random parameter": (GOOD + '\n[[more_seeds]]\nseeds = [2]\nwhere = { "ppo.lr" = 1e-4 }\n',
                                          "more_seeds[0].where='ppo.lr' is invalid: one of the listed parameters"),
    "more seeds for an unlisted value": (GOOD + '\n[[more_seeds]]\nseeds = [2]\nwhere = { aux = 0.5 }\n',
                                         "more_seeds[0].where.aux=0.5 is invalid: one of [0.0, 0.2]"),
    "more seeds for an unlisted option in a list": (
        GOOD + '\n[[more_seeds]]\nseeds = [2]\nwhere = { annealing = ["none", "late"] }\n',
        "more_seeds[0].where.annealing='late' is invalid: one of ['none', 'early']"),
    "more seeds with an empty where": (GOOD + '\n[[more_seeds]]\nseeds = [2]\nwhere = {}\n',
                                       "more_seeds[0].where={} is invalid: a non-empty table"),
    "more seeds not distinct": (GOOD + '\n[[more_seeds]]\nseeds = [2, 2]\nwhere = { aux = 0.2 }\n',
                                "more_seeds[0].seeds=[2, 2] is invalid: a list of distinct whole numbers >= 0"),
    "more seeds empty": (GOOD + '\n[[more_seeds]]\nseeds = []\nwhere = { aux = 0.2 }\n',
                         "more_seeds[0].seeds=[] is invalid: a list of distinct whole numbers >= 0"),
    "more seeds for an empty list": (GOOD + '\n[[more_seeds]]\nseeds = [2]\nwhere = { aux = [] }\n',
                                     "more_seeds[0].where.aux=[] is invalid: a value or a non-empty list of values"),
    "more seeds as one table": (GOOD + '\n[more_seeds]\nseeds = [2]\nwhere = { aux = 0.2 }\n',
                                "is invalid: a list of tables: [[more_seeds]]"),
    "a statistic of no learner": ('metric = "folower/aux_loss"\n' + GOOD.replace('metric = "team_reward"', ""),
                                  "'NAME/key' with NAME one of ['leader', 'follower', 'leader', 'follower']"),
}


@pytest.mark.parametrize("name", sorted(MISTAKES))
def test_each_mistake_is_one_line_and_exit_code_2(tmp_path, capsys, name):
    text, expected = MISTAKES[name]
    path = write(tmp_path, text)
    with pytest.raises(SweepError) as caught:
        load_sweep(path)
    assert expected in str(caught.value), str(caught.value)
    assert main(["sweep", "check", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("colorgrid sweep check: error: ") and err.count("\n") == 1 and str(path) in err


def test_more_seeds_go_to_the_configurations_they_name(tmp_path):
    """``[[more_seeds]]`` adds its seeds to the matching configurations only, after ``seeds``; a list in ``where``
    matches any of its values, and a value matches as the parameter lists it (``aux = 0`` is the grid's 0.0)."""
    text = ("num_samples = 3\n" + GOOD
            + '\n[[more_seeds]]\nseeds = [5, 2]\nwhere = { aux = 0, annealing = ["none", "early"] }\n'
            + 'note = "aux 0 left undecided"\n'
            + '\n[[more_seeds]]\nseeds = [2, 3]\nwhere = { annealing = "early" }\n')
    spec = load_sweep(write(tmp_path, text))
    assert spec.seeds == (0, 1) and spec.all_seeds == (0, 1, 5, 2, 3)
    assert spec.more_seeds[0].where == {"aux": 0.0, "annealing": ["none", "early"]}
    assert spec.more_seeds[0].note == "aux 0 left undecided"
    assert spec.configurations() == [{"aux": 0.0, "annealing": "none"}, {"aux": 0.0, "annealing": "early"},
                                     {"aux": 0.2, "annealing": "none"}, {"aux": 0.2, "annealing": "early"}]
    assert spec.seeds_for({"aux": 0.0, "annealing": "none"}) == (0, 1, 5, 2)
    assert spec.seeds_for({"aux": 0.0, "annealing": "early"}) == (0, 1, 5, 2, 3)  # both tables, 2 once
    assert spec.seeds_for({"aux": 0.2, "annealing": "early"}) == (0, 1, 2, 3)
    assert spec.seeds_for({"aux": 0.2, "annealing": "none"}) == (0, 1)
    # 4 configurations x 3 draws x 2 seeds, and per draw 2 + 3 + 2 + 0 more seeds
    assert spec.num_trials() == 3 * (4 * 2 + 2 + 3 + 2) == 45
    assert spec.summary() == "45 trials (12 configurations x 2 seeds, and 21 more where [[more_seeds]] adds seeds)"
    draw = spec.samples()[0]
    assert spec.wants({"seed": 5, "aux": 0.0, "annealing": "none", "ppo.lr": None, "sample": draw})
    assert not spec.wants({"seed": 5, "aux": 0.2, "annealing": "early", "ppo.lr": None, "sample": draw})
    assert not spec.wants({"seed": 4, "aux": 0.0, "annealing": "early", "ppo.lr": None, "sample": draw})
    plain = load_sweep(write(tmp_path, GOOD, "plain.toml"))
    assert plain.all_seeds == (0, 1) and plain.summary() == "8 trials (4 configurations x 2 seeds)"


def test_a_file_that_adds_seeds_trains_the_same_trials(tmp_path):
    """A sweep's folder may continue under a file that adds seeds (``same_trials``), not under one whose trials
    differ; with random parameters, whose draws are seeded by the file's text, any change makes other trials."""
    fixed = GOOD.replace('[params."ppo.lr"]\nloguniform = [1e-5, 1e-3]', "")
    more = '\n[[more_seeds]]\nseeds = [2]\nwhere = { aux = 0.2 }\n'
    first = load_sweep(write(tmp_path, fixed, "a.toml"))
    assert first.same_trials(load_sweep(write(tmp_path, fixed + more, "b.toml")))
    assert first.same_trials(load_sweep(write(tmp_path, fixed.replace("seeds = [0, 1]", "seeds = [0, 1, 2]"),
                                              "c.toml")))
    assert not first.same_trials(load_sweep(write(tmp_path, fixed.replace("grid = [0.0, 0.2]", "grid = [0.0, 0.3]"),
                                                  "d.toml")))
    assert not first.same_trials(load_sweep(write(tmp_path, fixed.replace("total_steps=4096", "total_steps=8192"),
                                                  "e.toml")))
    threads = fixed + "\n[resources]\ncpus_per_trial = 2\n"  # a trial's threads (and device) come from [resources]
    assert not first.same_trials(load_sweep(write(tmp_path, threads, "t.toml")))
    concurrent = fixed + "\n[resources]\nmax_concurrent = 3\n"  # how many run at once: the same trials
    assert first.same_trials(load_sweep(write(tmp_path, concurrent, "u.toml")))
    drawn = load_sweep(write(tmp_path, GOOD, "f.toml"))
    assert drawn.same_trials(load_sweep(write(tmp_path, GOOD, "g.toml")))
    assert not drawn.same_trials(load_sweep(write(tmp_path, GOOD + more, "h.toml")))


def test_paper_figures_match_their_configuration_by_value(tmp_path):
    """``where = {aux = 0}`` is the grid's 0.0, and a figure is shown beside that configuration only."""
    import pandas as pd

    from train.sweep.claim_spec import matches

    path = write(tmp_path, GOOD + '\n[[paper]]\nwhere = { aux = 0, annealing = "early" }\nvalue = 32.8\n')
    figure = load_sweep(path).paper[0]
    assert figure.where == {"aux": 0.0, "annealing": "early"}
    assert matches(figure.where, pd.Series({"aux": 0.0, "annealing": "early"}))
    assert not matches(figure.where, pd.Series({"aux": 0.2, "annealing": "early"}))
    assert not matches(figure.where, pd.Series({"aux": 0.0, "annealing": "none"}))


def test_missing_file_and_folders_that_are_not_sweeps(tmp_path, capsys):
    assert main(["sweep", "check", str(tmp_path / "none.toml")]) == 2
    assert "no such sweep file" in capsys.readouterr().err
    for action in ("report", "resume"):
        assert main(["sweep", action, str(tmp_path)]) == 2
        err = capsys.readouterr().err
        assert "not a sweep folder (no sweep.toml)" in err and err.count("\n") == 1


def test_checkpoint_files_the_trials_name_must_exist(tmp_path, capsys, monkeypatch):
    """A learner's init and a frozen partner's .pt file, named in the base settings or in one option, are read
    from the folder the sweep starts in; missing ones are named in one line (exit code 2) before anything starts.
    A shipped policy's name is not a file."""
    monkeypatch.chdir(tmp_path)
    text = GOOD.replace('set = ["total_steps=4096", "env.asymmetric=false"]',
                        'set = ["total_steps=4096", "leader.policy=ippo-leader"]').replace(
        '[params.annealing.options]\nnone = {}',
        '[params.annealing.options]\nnone = { "follower.init" = "source/latest.pt" }')
    path = write(tmp_path, text)
    assert load_sweep(path).missing_files() == ["follower.init=source/latest.pt"]
    partner = write(tmp_path, text.replace("leader.policy=ippo-leader", "leader.policy=frozen/leader.pt"))
    assert load_sweep(partner).missing_files() == ["leader.policy=frozen/leader.pt", "follower.init=source/latest.pt"]
    assert main(["sweep", "check", str(partner)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "leader.policy=frozen/leader.pt, follower.init=source/latest.pt" in err
    assert "do not exist (read from " + str(tmp_path) in err
    for made in ("source/latest.pt", "frozen/leader.pt"):
        (tmp_path / made).parent.mkdir()
        (tmp_path / made).write_bytes(b"")
    assert main(["sweep", "check", str(partner)]) == 0


def test_a_pinned_file_must_be_there_and_be_the_one_pinned(tmp_path, capsys, monkeypatch):
    """``[pinned]`` names a file the trials read with the sha256 the verdicts are about: ``sweep check`` (and every
    start of the trials, which checks the same) refuses in one line, exit code 2, while it is missing or differs, and
    a value that is not a sha256 is refused as the file is read."""
    monkeypatch.chdir(tmp_path)
    warm = tmp_path / "warm" / "latest.pt"
    warm.parent.mkdir()
    warm.write_bytes(b"the checkpoint the verdicts are about")
    pinned = hashlib.sha256(warm.read_bytes()).hexdigest()
    text = GOOD.replace('[params.annealing.options]\nnone = {}',
                        '[params.annealing.options]\nnone = { "follower.init" = "warm/latest.pt" }')
    path = write(tmp_path, text + f'\n[pinned]\n"warm/latest.pt" = "{pinned}"\n')
    assert load_sweep(path).pinned == {"warm/latest.pt": pinned}
    assert main(["sweep", "check", str(path)]) == 0
    capsys.readouterr()
    warm.write_bytes(b"another checkpoint, made on another CPU")
    assert main(["sweep", "check", str(path)]) == 2
    err = capsys.readouterr().err
    now = hashlib.sha256(warm.read_bytes()).hexdigest()
    assert err.count("\n") == 1 and f"[pinned] warm/latest.pt has sha256 {now}, not the {pinned} the file pins" in err
    warm.unlink()
    assert main(["sweep", "check", str(path)]) == 2  # (the init is missing too: named first)
    assert "follower.init=warm/latest.pt" in capsys.readouterr().err
    bare = write(tmp_path, GOOD + f'\n[pinned]\n"warm/latest.pt" = "{pinned}"\n', "bare.toml")
    assert main(["sweep", "check", str(bare)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"[pinned] warm/latest.pt does not exist (read from {tmp_path})" in err
    assert f"its sha256 must be {pinned}" in err
    with pytest.raises(SweepError, match=r"pinned=\{'warm/latest.pt': 'not a digest'\} is invalid: a table of "
                                         r'"PATH" = "SHA256" \(64 lowercase hexadecimal digits'):
        load_sweep(write(tmp_path, GOOD + '\n[pinned]\n"warm/latest.pt" = "not a digest"\n', "bad.toml"))


def test_files_named_inside_a_partner_must_exist_too(tmp_path, monkeypatch):
    """A person leader's base checkpoint, a population file, and the checkpoints its members name are read when
    the partner is built: a missing one is named as a checkpoint named directly is."""
    monkeypatch.chdir(tmp_path)

    def missing(partner: str) -> list[str]:
        text = GOOD.replace('set = ["total_steps=4096", "env.asymmetric=false"]',
                            f'set = ["total_steps=4096", {json.dumps("leader.policy=" + partner)}]')
        return load_sweep(write(tmp_path, text)).missing_files()

    assert missing("person:base=frozen/base.pt,slip=0.1") == ["leader.policy=frozen/base.pt"]
    assert missing("person:base=ippo-leader,slip=0.1") == []
    assert missing("mine.json#training") == ["leader.policy=mine.json"]
    (tmp_path / "mine.json").write_text(json.dumps({"training": {"a": "astar", "b": "gone.pt",
                                                                 "c": "person:base=away/leader.pt,slip=0.1"},
                                                    "held_out": {"d": "astar"}}))
    assert missing("mine.json#training") == ["leader.policy=gone.pt", "leader.policy=away/leader.pt"]
    assert missing("mine.json#held_out") == []
    assert missing("population:people#training") == []
    # a population that names itself, or a member whose parameters cannot be read: refused when built, not here
    (tmp_path / "self.json").write_text(json.dumps({"training": {"me": "self.json", "bad": "person:slip"}}))
    assert missing("self.json") == []


def test_eval_address_needs_a_population_matrix(capsys):
    assert main(["eval", "--address", "auto", "--episodes", "1"]) == 2
    err = capsys.readouterr().err
    assert err == ("colorgrid eval: error: --address runs the cells of a --leaders matrix on Ray; add --leaders "
                   "POPULATION\n")


def flat(data: dict, prefix: str = "") -> dict:
    out = {}
    for key, value in data.items():
        if isinstance(value, dict):
            out.update(flat(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


ABLATED = {
    "no memory": {"follower.net.lstm", "follower.net.extra_inputs", "follower.net.belief_input"},
    "LSTM without last-step inputs": {"follower.net.extra_inputs", "follower.net.belief_input"},
    "goal as a vector": {"follower.net.goal_fusion", "follower.net.belief_input"},
    "team reward": {"follower.train_reward"},
    "auxiliary loss 0": {"follower.aux_coef"},
    "no annealing": {"schedule.penalty_start", "schedule.penalty_end"},
    "ippo-leader partner": {"leader.policy"},
}


@pytest.mark.parametrize("name", ["assistant_recipe", "assistant_recipe_small"])
def test_each_recipe_arm_takes_exactly_one_ingredient_away(name):
    import dataclasses

    spec = load_sweep(ROOT / "sweeps" / f"{name}.toml")
    recipe = flat(dataclasses.asdict(spec.config({"arm": "recipe"}, 0)))
    assert recipe["follower.net.lstm"] and recipe["follower.net.belief_input"] and recipe["leader.policy"] == "astar"
    assert (recipe["follower.train_reward"], recipe["follower.aux_coef"], recipe["schedule.penalty_start"]) == \
        ("own", 0.5, 300_000)
    arms = [v for v in spec.params[0].values if v != "recipe"]
    assert sorted(arms) == sorted(ABLATED)
    for arm in arms:
        config = flat(dataclasses.asdict(spec.config({"arm": arm}, 0)))
        assert {k for k in recipe if recipe[k] != config[k]} == ABLATED[arm], arm
    needed = [c for c in spec.claims if c.b == {"arm": "recipe"} and c.direction.value == "<"]
    assert sorted(c.a["arm"] for c in needed) == sorted(arms)  # one claim per ingredient, beside A* ...
    assert all(c.metric in ("", spec.metric) for c in needed)
    beside_ippo = [(c.metric, c.b) for c in spec.claims if c.a == {"arm": "ippo-leader partner"}
                   and isinstance(c.b, Baseline)]  # ... and the paper's setting, beside its own partner, paired by seed
    assert beside_ippo == [("eval/follower_net_pickups", Baseline("ippo-leader/copy"))]
    judged = {c.metric for c in spec.claims if isinstance(c.b, Baseline) and c.a == {"arm": "recipe"}}
    assert judged == {"eval_astar/follower_net_pickups", "eval_population_people_held_out/follower_net_pickups"}
    config = spec.config({"arm": "ippo-leader partner"}, 0)  # ... and every arm judged beside the same partners
    assert config.eval_partners == ("astar", "population:people#held_out") and spec.metric.startswith("eval_astar/")


def test_the_unannealed_preset_is_the_ablations_no_annealing_arm():
    """The simpler recipe ships as a preset that trains exactly the ablation's 'no annealing' trial (its
    checkpoint, checkpoints/follower_unannealed.pt, is that trial's seed 0)."""
    from train.config import load_preset

    spec = load_sweep(ROOT / "sweeps" / "assistant_recipe.toml")
    preset = from_dict(merge(load_preset("follower_astar_unannealed"), parse_override("seed=0")))
    assert preset == spec.config({"arm": "no annealing"}, 0)
    assert preset != spec.config({"arm": "recipe"}, 0)
