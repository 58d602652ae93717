"""Stacked acting (train/stacked.py): every learner's rollout step in one set of batched operations computes what
each learner's own network computes, draws the same samples, and keeps the rollout its update reads."""

import copy

import numpy as np
import pytest
import torch

from train.config import from_dict, merge
from train.stacked import StackedActing, can_stack
from train.trainer import Trainer

TINY = {"ppo": {"num_envs": 4, "num_steps": 16, "num_minibatches": 2, "update_epochs": 2},
        "eval_every": 0, "save_every": 2, "env": {"horizon": 12}}
TWO_FOLLOWERS = {"env": {"num_leaders": 1, "num_followers": 2}}

STACKABLE = {
    "default": {},
    "goal_at_the_heads_with_extras": {"leader": {"net": {"goal_fusion": "heads", "extra_inputs": True}},
                                      "follower": {"net": {"goal_fusion": "heads", "extra_inputs": True}}},
    "three_learners": TWO_FOLLOWERS,
    "two_followers_sharing_one_network": merge(TWO_FOLLOWERS, {"follower": {"share_network": True},
                                                              "leader": {"share_network": False}}),
    "one_shared_network_beside_a_scripted_leader": merge(TWO_FOLLOWERS, {"leader": {"policy": "astar"},
                                                                         "follower": {"share_network": True}}),
    "two_shared_networks": {"env": {"num_leaders": 2, "num_followers": 2}, "leader": {"share_network": True},
                            "follower": {"share_network": True}},
}


def trainer(tmp_path, changes: dict) -> Trainer:
    return Trainer(from_dict(merge(TINY, changes)), tmp_path, progress=False, tensorboard=False)


def one_step_each_way(t: Trainer):
    """One rollout step of every learner, acted stacked and each on its own (``Learner.act``) from copies of the
    same learners: the two results and the two sets of learners."""
    goal = t.env.state.goal.copy()
    own = {i: copy.deepcopy(lr) for i, lr in t.learners.items()}
    stacked = [copy.deepcopy(lr) for lr in t.learners.values()]
    for learner in [*own.values(), *stacked]:
        learner.start_rollout()
    acting = StackedActing(stacked)
    acting.refresh()
    inputs = [t._learner_tensors(lr, goal) for lr in t.learners.values()]
    together = acting.act(inputs)
    alone = [lr.act(x) for lr, x in zip(own.values(), inputs)]
    return together, alone, stacked, list(own.values())


@pytest.mark.parametrize("name", sorted(STACKABLE))
def test_stacked_acting_computes_what_each_network_does(tmp_path, name):
    t = trainer(tmp_path, STACKABLE[name])
    if name == "two_followers_sharing_one_network":
        assert not can_stack(list(t.learners.values()))  # the shared network has twice the rows: not stacked
        return
    assert can_stack(list(t.learners.values()))
    t.collect_rollout()
    t._update_learners()  # trained weights, not only their initialisation
    together, alone, stacked, own = one_step_each_way(t)
    for (actions, goal_probs), (actions_own, goal_probs_own) in zip(together, alone):
        np.testing.assert_array_equal(actions, actions_own)  # the same uniforms from each learner's generator
        np.testing.assert_allclose(goal_probs, goal_probs_own, atol=1e-6)
    for a, b in zip(stacked, own):
        assert a.steps == b.steps == 1
        for key in b.views:  # the view the update reads: cut the same way, exactly
            torch.testing.assert_close(a.views[key][:1], b.views[key][:1], atol=0, rtol=0)
        for key in ("logp", "values"):
            torch.testing.assert_close(a.buffer[key][0], b.buffer[key][0], atol=1e-5, rtol=0)
        for key in ("goal", "extras", "starts", "actions"):
            torch.testing.assert_close(a.buffer[key][0], b.buffer[key][0], atol=0, rtol=0)
        assert a.generator.get_state().equal(b.generator.get_state())


@pytest.mark.parametrize("name", ["default", "one_shared_network_beside_a_scripted_leader", "two_shared_networks"])
def test_stacked_learners_update_from_what_they_kept(tmp_path, name):
    """Every key the update reads is kept, a shared network's row identity too, and the weights move."""
    t = trainer(tmp_path, STACKABLE[name])
    before = [{k: v.clone() for k, v in lr.model.state_dict().items()} for lr in t.learners.values()]
    t.collect_rollout()
    assert t._stacked is not None
    t._update_learners()
    for learner, old in zip(t.learners.values(), before):
        assert set(learner.views) == set(learner.model.prepare(torch.zeros(1, 1, 5 + len(t.names) - 2, 32, 32,
                                                                            dtype=torch.uint8),
                                                               torch.zeros(1, 1, 2, dtype=torch.int64),
                                                               learner.model.identity(learner.agents, 1)))
        assert any(not torch.equal(v, old[k]) for k, v in learner.model.state_dict().items())


def test_a_stacked_rollout_is_recomputed_by_the_update_s_networks(tmp_path):
    """The log-probabilities and values kept while acting stacked are what each learner's network gives on the
    rollout it kept, so PPO's ratios start at 1."""
    t = trainer(tmp_path, {})
    t.collect_rollout()
    t._update_learners()
    t.collect_rollout()
    assert t._stacked is not None
    for learner in t.learners.values():
        b = learner.stacked()
        with torch.no_grad():
            logits, values, _, _ = learner.model(b["view"], b["goal"], b["extras"], b["starts"], None)
        logp = torch.log_softmax(logits, dim=2).gather(2, b["actions"][..., None])[..., 0]
        torch.testing.assert_close(logp, b["logp"], atol=1e-5, rtol=0)
        torch.testing.assert_close(values, b["values"], atol=1e-5, rtol=0)


def test_networks_that_cannot_stack_act_on_their_own(tmp_path):
    t = trainer(tmp_path, {"follower": {"net": {"lstm": True}}})
    assert not can_stack(list(t.learners.values()))
    t.collect_rollout()
    assert t._stacked is None and all(lr.steps == 16 for lr in t.learners.values())
    with pytest.raises(ValueError, match="cannot act stacked"):
        StackedActing(list(t.learners.values()))
