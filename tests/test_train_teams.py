"""The trainer with teams of any shape: who learns, shared networks, exact resume, checkpoints as policies, errors."""

import json

import numpy as np
import pytest
import torch

from colorgrid import EnvConfig
from colorgrid.policies import make_policy
from colorgrid.rollout import run_team
from colorgrid.replay import load, verify
from colorgrid_apps.cli import main as colorgrid_main
from train.checkpoint import load_checkpoint
from train.config import TrainConfigError, from_dict, load_preset, merge, parse_override
from train.nets import ActorCritic
from train.policy import load_policy
from train.metrics import episode_columns
from train.trainer import Trainer

TINY = {"ppo": {"num_envs": 4, "num_steps": 16, "num_minibatches": 2, "update_epochs": 2},
        "eval_every": 0, "save_every": 2, "env": {"horizon": 12, "height": 16, "width": 16}}
SMALL_NET = {"hidden": 32, "lstm_size": 32}

TWO_LEADERS = {"env": {"num_leaders": 2, "num_followers": 1}}
TWO_FOLLOWERS = {"env": {"num_leaders": 1, "num_followers": 2}}

RUNS = {
    # 2:1, no sharing: each leader its own network, the follower a third one with an LSTM
    "2L1F": merge(TWO_LEADERS, {"leader": {"net": SMALL_NET},
                                "follower": {"net": {**SMALL_NET, "lstm": True, "extra_inputs": True}}}),
    # 2:1, the two leaders share one recurrent network; a scripted follower
    "2L1F_shared": merge(TWO_LEADERS, {"leader": {"share_network": True, "net": {**SMALL_NET, "lstm": True}},
                                       "follower": {"policy": "copy"}}),
    # 1:2, no sharing: the A* leader, one Bayesian follower and one learning follower
    "1L2F": merge(TWO_FOLLOWERS, {"leader": {"policy": "astar"},
                                  "follower": {"policies": ["bayes", "learn"], "net": SMALL_NET}}),
    # 1:2, the team_1L2F preset: two followers sharing the belief-planes network beside A*
    "1L2F_shared": merge(load_preset("team_1L2F"), {"follower": {"net": SMALL_NET}, "schedule": {
        "penalty_start": 0, "penalty_end": 200}, "threads": 0}),
}


def tiny(changes: dict, **more):
    return from_dict(merge(merge(TINY, changes), more))


def weights(model) -> dict:
    return {k: v.detach().clone() for k, v in model.state_dict().items()}


def rows(run_dir) -> list[dict]:
    timing = lambda k: "sps" in k or k == "wall_time_s"  # noqa: E731
    return [{k: v for k, v in json.loads(x).items() if not timing(k)}
            for x in (run_dir / "metrics.jsonl").read_text().splitlines()]


# ------------------------------------------------------------------ the config
def test_role_sections_give_every_agent_its_settings_and_name_the_networks():
    one = from_dict({})
    assert one.agents == (one.leader, one.follower)  # 1:1 as before: the sections themselves
    assert one.networks == (("leader", (0,)), ("follower", (1,)))
    config = tiny(RUNS["1L2F"])
    assert [a.policy for a in config.agents] == ["astar", "bayes", "learn"]
    assert config.agents[2].net.hidden == 32 and config.agents[1].init is None
    assert config.networks == (("follower_1", (2,)),)
    assert tiny(RUNS["2L1F"]).networks == (("leader_0", (0,)), ("leader_1", (1,)), ("follower_0", (2,)))
    assert tiny(RUNS["2L1F_shared"]).networks == (("leader", (0, 1)),)
    assert parse_override("leader.policies=astar,learn") == {"leader": {"policies": ("astar", "learn")}}


@pytest.mark.parametrize("change, message", [
    (merge(TWO_LEADERS, {"leader": {"policies": ["astar"]}}),
     "leader.policies=('astar',) is invalid: one policy per leader (env.num_leaders=2), or []"),
    ({"follower": {"policies": ["learn", "nope"]}}, "follower.policies=('learn', 'nope') is invalid: 'nope' is not a "
                                                    "policy"),
    ({"follower": {"policies": "learn"}}, "follower.policies='learn' is invalid: a list of policies"),
    ({"follower": {"share_network": True}},
     "follower.share_network=True is invalid: false unless two or more followers learn (this team has 1 learning "
     "follower)"),
    (merge(TWO_FOLLOWERS, {"follower": {"share_network": True, "policies": ["learn", "idle"]}}),
     "follower.share_network=True is invalid: false unless two or more followers learn"),
    ({"leader": {"share_network": "yes"}}, "leader.share_network='yes' is invalid: true or false"),
    (merge(TWO_FOLLOWERS, {"leader": {"policy": "astar"}, "follower": {"policies": ["bayes", "idle"]}}),
     "leader.policy/follower.policy=('astar', 'bayes', 'idle') is invalid: at least one agent must have "
     "policy='learn'"),
    ({"follower": {"policies": ["idle"], "init": "x.pt"}}, "follower.init='x.pt' is invalid: warm-starting only"),
    ({"env": {"num_followers": 9}}, "EnvConfig.num_followers must be an integer in [1, 8], got 9"),
])
def test_team_config_errors_name_the_field_and_what_is_allowed(change, message):
    with pytest.raises(TrainConfigError) as err:
        from_dict(merge(TINY, change))
    assert str(err.value).startswith(message), str(err.value)


# ---------------------------------------------------------------- the networks
def test_a_shared_network_knows_which_agent_each_row_is():
    torch.manual_seed(0)
    env = EnvConfig(num_followers=2, height=16, width=16)
    model = ActorCritic(from_dict({}).follower.net, env, (1, 2))
    identity = model.identity((1, 2), batch=3)
    assert identity.shape == (1, 6, 2) and identity[0, :3, 0].all() and identity[0, 3:, 1].all()
    assert model.identity((2,), batch=1).tolist() == [[[0.0, 1.0]]]
    assert ActorCritic(from_dict({}).follower.net, env, 2).identity((2,), batch=3) is None
    obs = torch.zeros(1, 6, env.num_planes, 16, 16, dtype=torch.uint8)
    me = torch.full((1, 6, 2), 5)
    goal, extras, starts = torch.zeros(1, 6, 3), torch.zeros(1, 6, 0), torch.ones(1, 6, dtype=torch.bool)
    logits, _, _, _ = model(model.prepare(obs, me, identity), goal, extras, starts, None)
    assert torch.equal(logits[0, 0], logits[0, 2]) and not torch.equal(logits[0, 0], logits[0, 3])
    with pytest.raises(ValueError, match=r"shared by agents \[1, 2\]: say which one each row is"):
        model.prepare(obs, me)


def test_episode_totals_are_named_per_agent_and_per_role():
    env = EnvConfig(num_leaders=2)
    out = episode_columns(env, {"goal_pickups": np.array([[1, 2, 3], [0, 1, 5]])})
    assert list(out) == ["leader_0_goal_pickups", "leader_1_goal_pickups", "follower_0_goal_pickups",
                         "leaders_goal_pickups", "followers_goal_pickups"]
    assert out["leaders_goal_pickups"].tolist() == [3, 1] and out["followers_goal_pickups"].tolist() == [3, 5]
    assert list(episode_columns(EnvConfig(), {"goal_pickups": np.zeros((1, 2))})) == [
        "leader_goal_pickups", "follower_goal_pickups"]  # 1:1: the names of every earlier log


# ------------------------------------------------------------------------ runs
@pytest.mark.parametrize("run", sorted(RUNS))
def test_a_team_run_resumes_exactly_and_its_checkpoint_plays_each_learning_agent(tmp_path, run):
    """2 iterations straight, and 1 + 1 with a resume between them: the same metrics and weights; then every
    learning agent's network loads from the checkpoint as a policy for its agent index (and no other)."""
    changes = merge(RUNS[run], {"total_steps": 2 * 64})
    straight = Trainer(tiny(changes), tmp_path / "a", progress=False, tensorboard=False)
    straight.train()
    Trainer(tiny(changes, total_steps=64), tmp_path / "b", progress=False, tensorboard=False).train()
    resumed = Trainer(tiny(changes), tmp_path / "b", progress=False, tensorboard=False)
    resumed.restore(tmp_path / "b" / "checkpoints" / "latest.pt")
    resumed.train()
    assert rows(tmp_path / "a") == rows(tmp_path / "b")
    for key, learner in straight.learners.items():
        after = resumed.learners[key].model.state_dict()
        assert all(torch.equal(value, after[k]) for k, value in weights(learner.model).items()), learner.name

    config = straight.config
    names = config.env.agent_names
    last = rows(tmp_path / "a")[-1]
    assert "team_reward" in last and "followers_wrong_pickups" in last and "leaders_goal_pickups" in last
    for name in names:
        assert f"{name}_goal_pickups" in last and f"{name}_wrong_pickups" in last
    ckpt_path = tmp_path / "a" / "checkpoints" / "latest.pt"
    ckpt = load_checkpoint(ckpt_path)
    assert sorted(k for k, v in ckpt["agents"].items() if v is not None) == sorted(n for n, _ in config.networks)
    for network, agents in config.networks:
        assert f"{network}/policy_loss" in last
        for a in agents:
            assert f"{names[a]}/rollout_goal_accuracy" in last
            policies = [make_policy("idle") for _ in names]
            policies[a] = load_policy(ckpt_path, names[a])
            batch = run_team(config.env, policies, 2, seed=7)
            assert batch.actions.shape == (12, 2, config.env.num_agents)
            assert batch.goal_probs[a] is not None
        others = [i for i in range(config.env.num_agents) if i not in agents]
        with pytest.raises(ValueError, match="was trained as"):
            load_policy(ckpt_path, network).reset(config.env, 1, others[0])


def test_a_shared_network_plays_each_agent_as_in_training(tmp_path):
    """A policy loaded from a shared network acts for agent ``a`` as the learner's rows of ``a`` do."""
    config = tiny(RUNS["1L2F_shared"], total_steps=64)
    trainer = Trainer(config, tmp_path, progress=False, tensorboard=False)
    trainer.train()
    learner = trainer.learners[1]
    assert learner.agents == (1, 2) and learner.rows == 8
    x = trainer._learner_tensors(learner)
    with torch.no_grad():
        view = learner.model.prepare(x["obs"], x["me"], learner.identity)
        logits, _, goal_logits, _ = learner.model(view, x["goal"], x["extras"], x["starts"], learner.state)
    for k, a in enumerate(learner.agents):
        rows_of_a = slice(4 * k, 4 * (k + 1))
        policy = load_policy(tmp_path / "checkpoints" / "latest.pt", config.env.agent_names[a], temperature=0)
        policy.reset(config.env, 4, a)
        policy.state = tuple(s[:, rows_of_a].clone() for s in learner.state)
        out = policy.act(trainer._inputs(a))
        assert out.actions.tolist() == logits[0, rows_of_a].argmax(dim=1).tolist()
        np.testing.assert_allclose(out.goal_probs, torch.softmax(goal_logits[0, rows_of_a], dim=1).numpy(),
                                   atol=1e-6)


def test_team_evaluations_log_every_agent_and_save_replays_that_verify(tmp_path):
    config = tiny(RUNS["2L1F_shared"], total_steps=64, eval_every=1, eval_episodes=3, replay_episodes=1)
    Trainer(config, tmp_path, progress=False, tensorboard=False).train()
    evals = [r for r in rows(tmp_path) if r["stream"] == "eval"]
    assert len(evals) == 1
    for key in ("team_reward", "leader_0_net_pickups", "leader_1_goal_accuracy", "follower_0_wrong_pickups",
                "leaders_goal_pickups", "followers_net_pickups"):
        assert key in evals[0], key
    [path] = (tmp_path / "replays").rglob("*.replay.json")
    replay = load(path)
    assert list(replay.agents) == ["leader_0", "leader_1", "follower_0"] and verify(replay).ok
    # one network exported from the team checkpoint (named by either agent) is a small policy file for both
    small = tmp_path / "leaders.pt"
    assert colorgrid_main(["checkpoint", "export", str(tmp_path / "checkpoints" / "latest.pt"), "--agent",
                           "leader_1", "--out", str(small)]) == 0
    assert list(load_checkpoint(small)["agents"]) == ["leader", "follower_0"]
    for a in (0, 1):
        load_policy(small).reset(config.env, 2, a)


def test_three_learners_updating_side_by_side_match_one_after_the_other(tmp_path):
    """On two torch threads three learners update on two threads; on three, two of them in processes of their own;
    either way as one after the other on one thread, bit for bit."""
    threads = torch.get_num_threads()
    config = tiny(RUNS["2L1F"], ppo={"num_steps": 8})
    trainers = {n: Trainer(config, tmp_path / str(n), progress=False, tensorboard=False) for n in (2, 3, 1)}
    try:
        results = {}
        for n, trainer in trainers.items():
            trainer.collect_rollout()
            torch.set_num_threads(n)
            results[n] = trainer._update_learners()  # 2: two threads for three learners; 3: two processes
        assert trainers[2]._pool is not None and not trainers[2]._processes
        assert sorted(trainers[3]._processes) == sorted(trainers[3].learners)[1:] and trainers[3]._pool is None
        assert trainers[1]._pool is None and not trainers[1]._processes
    finally:
        torch.set_num_threads(threads)
        for trainer in trainers.values():
            trainer.close()
    for n in (2, 3):
        assert results[n] == results[1], n
        for i in trainers[n].learners:
            after = trainers[1].learners[i].model.state_dict()
            assert all(torch.equal(v, after[k]) for k, v in weights(trainers[n].learners[i].model).items()), (n, i)


def test_checkpoints_name_what_they_hold(tmp_path):
    Trainer(tiny(RUNS["2L1F"], total_steps=64), tmp_path / "run", progress=False, tensorboard=False).train()
    ckpt = tmp_path / "run" / "checkpoints" / "latest.pt"
    with pytest.raises(ValueError, match=r"holds several trained leaders \(leader_0, leader_1\); say which one"):
        load_policy(ckpt, "leader")
    with pytest.raises(ValueError, match=r"holds trained agents \['follower_0', 'leader_0', 'leader_1'\]"):
        load_policy(ckpt)
    with pytest.raises(ValueError, match=r"trained in a team of 2 leader\(s\) and 1 follower\(s\), whose agents are "
                                         r"\['leader_0', 'leader_1', 'follower_0'\]: it has no follower_1"):
        load_policy(ckpt, "follower_1")
    with pytest.raises(ValueError, match="does not fit this environment .*num_leaders: trained 2, requested 1"):
        load_policy(ckpt, "leader_0").reset(EnvConfig(horizon=12, height=16, width=16), 1, 0)
    one_to_one = tiny({"leader": {"init": str(ckpt), "net": SMALL_NET}, "follower": {"policy": "idle"}})
    with pytest.raises(ValueError, match="does not fit this environment .*num_leaders: trained 2, requested 1"):
        Trainer(one_to_one, tmp_path / "x", progress=False, tensorboard=False)
    shared = tiny(RUNS["2L1F"], leader={"init": str(ckpt), "net": SMALL_NET, "share_network": True})
    with pytest.raises(ValueError, match="leader.init='.*' holds several trained leaders"):
        Trainer(shared, tmp_path / "y", progress=False, tensorboard=False)
    warm = Trainer(tiny(RUNS["2L1F"], leader={"init": str(ckpt), "net": SMALL_NET}), tmp_path / "w",
                   progress=False, tensorboard=False)
    saved = load_checkpoint(ckpt)["agents"]["leader_1"]["state_dict"]
    assert all(torch.equal(v, warm.learners[1].model.state_dict()[k]) for k, v in saved.items())
    # frozen partners from a team checkpoint: each agent plays the network it had
    frozen = Trainer(tiny(RUNS["2L1F"], leader={"policy": str(ckpt)}), tmp_path / "f", progress=False,
                     tensorboard=False)
    for a in (0, 1):
        saved = load_checkpoint(ckpt)["agents"][f"leader_{a}"]["state_dict"]
        assert all(torch.equal(v, frozen.partners[a].model.state_dict()[k]) for k, v in saved.items())


def test_one_to_one_checkpoints_keep_their_layout(tmp_path):
    Trainer(tiny({"leader": {"policy": "astar"}, "follower": {"net": SMALL_NET}}, total_steps=64), tmp_path,
            progress=False, tensorboard=False).train()
    ckpt = load_checkpoint(tmp_path / "checkpoints" / "latest.pt")
    assert list(ckpt["agents"]) == ["leader", "follower"] and ckpt["agents"]["leader"] is None
    assert "agents" not in ckpt["agents"]["follower"] and ckpt["agents"]["follower"]["agent_index"] == 1
    assert list(ckpt["trainer_state"]["learners"]) == ["follower"]
    assert list(ckpt["trainer_state"]["partners"]) == ["leader"]


def test_a_team_followers_card_compares_it_with_the_baselines_in_its_team(tmp_path):
    """The card of a 1:2 shared follower network: a row per baseline and one for the checkpoint, every figure
    the same as ``colorgrid eval`` gives in that team on the same seeds, and the command that reproduces them."""
    from colorgrid.evaluate import evaluate
    from train.card import TEAM_BASELINES, model_card

    changes = merge(RUNS["1L2F_shared"], {"total_steps": 64})
    Trainer(tiny(changes), tmp_path, progress=False, tensorboard=False).train()
    ckpt = str(tmp_path / "checkpoints" / "latest.pt")
    text, data = model_card(ckpt, "follower", str(tmp_path), "colorgrid train --preset team_1L2F", episodes=3)
    assert data["followers"] == [*TEAM_BASELINES, ckpt]
    config = EnvConfig.from_dict(load_checkpoint(ckpt)["env_config"])
    again = evaluate(config, "astar", ckpt, 3, 0)["roles"]["follower"]["net_pickups"]
    table = [line for line in text.splitlines() if line.startswith("| `")]
    assert [line.split("`")[1] for line in table] == [*TEAM_BASELINES, "latest.pt"]
    assert f"{again['mean']:+.2f} ± {again['ci95']:.2f}" in table[-1]
    assert "one network shared by the followers" in text
    assert f"colorgrid eval --team 1:2 --leader astar --compare copy bayes-people oracle {ckpt}" in text


def test_each_policy_says_which_teams_it_plays(tmp_path):
    """Scripted policies play any team; a trained network the team it was trained in; a population what all its
    members play (``people#training`` holds the 1:1 IPPO leader)."""
    from colorgrid.policies import policy_teams

    changes = merge(RUNS["1L2F_shared"], {"total_steps": 64})
    Trainer(tiny(changes), tmp_path, progress=False, tensorboard=False).train()
    assert policy_teams(str(tmp_path / "checkpoints" / "latest.pt")) == ("1:2",)
    assert policy_teams("ippo") == policy_teams("ippo-cautious:temperature=0") == ("1:1",)
    assert policy_teams("astar") is None and policy_teams("person:slip=0.1") is None
    assert policy_teams("population:people#training") == ("1:1",)
    assert policy_teams("population:people#held_out") is None


def test_a_checkpoint_that_names_roles_by_their_enum_loads_with_weights_only(tmp_path):
    """Roles are ``Role`` members in the configs; torch's ``weights_only`` loader refuses any class, so a checkpoint
    that kept one as a key or a value could not be read back: they are saved as their plain names."""
    from colorgrid.enums import Role
    from train.checkpoint import save_checkpoint

    path = save_checkpoint(tmp_path / "roles.pt", {"plays": {Role.LEADER: [Role.FOLLOWER]}, "pair": (Role.LEADER, 1)})
    raw = torch.load(path, map_location="cpu", weights_only=True)
    assert raw["plays"] == {"leader": ["follower"]} and type(next(iter(raw["plays"]))) is str
    assert raw["pair"] == ("leader", 1)
