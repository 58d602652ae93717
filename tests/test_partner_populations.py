"""The training partners' populations: IPPO leaders at several skill levels and noisy versions of them
(``populations/leader_stages.json``), and every family mixed (``populations/partners.json``), judged beside the same
held-out people as ``people.json``; the sweep that trains beside each family is valid and its baselines are kept."""

import numpy as np

from colorgrid.config import EnvConfig
from colorgrid.policies import make_policy
from colorgrid.policies.population import load_population
from colorgrid.rollout import run_team


def test_every_partner_population_holds_out_the_people_populations_held_out_leaders():
    held_out = load_population("people#held_out")
    assert load_population("leader_stages#held_out") == held_out
    assert load_population("partners#held_out") == held_out


def test_the_mixture_is_the_people_training_part_and_the_leader_stages_training_part():
    people, stages = load_population("people#training"), load_population("leader_stages#training")
    assert not set(people) & set(stages)  # no member name means two things
    assert load_population("partners#training") == {**people, **stages}
    named = set(stages.values())
    assert {f"ippo-leader-{s}" for s in ("0.2M", "0.4M", "0.8M", "2.5M")} <= named  # each skill level, as itself
    assert any(v.startswith("person:base=ippo-leader-") for v in named)  # and noisy or slow versions of them
    held_out = set(load_population("people#held_out").values())
    assert not named & held_out


def test_every_member_of_the_mixture_leads_an_episode_beside_a_follower():
    """Each member is built by its name as a leader and plays (stages load their checkpoints; noisy versions wrap
    them), collecting goal blocks beside the Bayesian follower."""
    config = EnvConfig(horizon=64)
    for name, spec in load_population("partners#training").items():
        batch = run_team(config, [make_policy(spec, "leader"), make_policy("bayes", "follower")], 4, seed=7)
        picked_goal = (batch.picked_color[:, :, 0] == batch.goal) & (batch.picked_color[:, :, 0] >= 0)
        assert picked_goal.sum() > 0, name


def test_the_partner_sweep_is_valid_and_its_baselines_are_kept_for_its_seeds():
    import json
    from pathlib import Path

    from train.sweep.baselines import declared_baselines, evaluation_seed
    from train.sweep.spec import load_sweep

    spec = load_sweep(Path(__file__).parents[1] / "sweeps" / "assistant_partners_varied.toml")
    spec.check_files()
    arms = {values["partners"]: spec.config(values, 10).agents[0].policy for values in spec.configurations()}
    assert arms == {"A*": "astar", "people": "population:people#training",
                    "leader stages": "population:leader_stages#training", "mixture": "population:partners#training"}
    kept = json.loads((spec.results / "baselines.json").read_text())
    assert kept["seeds"] == [evaluation_seed(s) for s in spec.all_seeds]
    assert set(kept["baselines"]) == {b.name for b in declared_baselines(spec)}
    assert np.all(np.isfinite(kept["baselines"]["population_people_held_out/ippo-people"]["net_pickups_per_seed"]))

