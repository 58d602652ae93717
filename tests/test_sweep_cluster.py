"""A sweep on a two-node Ray cluster on loopback (``ray.cluster_utils.Cluster``): its trials run on both
nodes, and the sweep's tables say which node ran each."""

from pathlib import Path

import pytest
import ray
from ray.cluster_utils import Cluster

from train.sweep.results import read_tables
from train.sweep.runner import run_sweep
from train.sweep.spec import load_sweep

SWEEP = """
description = "two trials, one per node"
preset = "default"
set = ["total_steps=256", "ppo.num_envs=2", "ppo.num_steps=32", "env.horizon=32", "eval_every=0", "save_every=2",
       "ppo.num_minibatches=2", "ppo.update_epochs=1", "leader.net.hidden=16", "follower.net.hidden=16"]
seeds = [0, 1]

[resources]
cpus_per_trial = 1
"""


@pytest.fixture(scope="module")
def two_nodes():
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
    worker = cluster.add_node(num_cpus=1)
    cluster.wait_for_nodes()
    ray.init(address=cluster.address, logging_level="WARNING", log_to_driver=False)
    yield cluster, {cluster.head_node.node_id, worker.node_id}
    ray.shutdown()
    cluster.shutdown()


def test_trials_run_on_both_nodes(tmp_path: Path, two_nodes):
    _, nodes = two_nodes
    assert len({n["NodeID"] for n in ray.nodes() if n["Alive"]}) == 2
    path = tmp_path / "two.toml"
    path.write_text(SWEEP)
    # one CPU a node and one a trial: the two trials can only run at once on different nodes
    assert run_sweep(load_sweep(path, out=tmp_path / "out")) == 0
    trials, _ = read_tables(tmp_path / "out")
    assert trials["finished"].all() and len(trials) == 2
    assert set(trials["node"]) == nodes


def test_population_matrix_cells_as_ray_tasks_equal_local_ones(two_nodes):
    """``colorgrid eval --leaders ... --address``: the cells run as Ray tasks on the cluster; the report is the
    one the local processes make."""
    from colorgrid.config import EnvConfig
    from colorgrid_apps.matrix import evaluate_matrix

    cluster, _ = two_nodes
    config, leaders = EnvConfig(horizon=32), {"astar": "astar", "slips": "person:slip=0.2"}
    on_ray = evaluate_matrix(config, leaders, ["copy", "bayes"], episodes=4, seed=5, address=cluster.address)
    local = evaluate_matrix(config, leaders, ["copy", "bayes"], episodes=4, seed=5, workers=1)
    assert on_ray["ray_address"] == cluster.address and on_ray["workers"] is None
    for key in ("cells", "paired_difference", "mean_over_leaders"):
        assert on_ray[key] == local[key]
