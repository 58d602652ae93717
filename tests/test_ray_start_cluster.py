"""A Ray cluster started as people start one, with the commands of docs/SWEEPS.md: ``ray get-auth-token
--generate`` on the head, its token copied to the other node, ``RAY_AUTH_MODE=token`` everywhere, ``ray start
--head`` and ``ray start --address``. The two nodes run on this machine, each with a home (``~/.ray``) and a temp
folder of its own and in a process group of its own, so that nothing reads or writes this user's ``~/.ray`` or
their Ray processes. ``colorgrid sweep run --address`` runs its trials on both nodes; a driver without the
cluster's token, or with another, is refused in one line."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import grpc
import pytest
from ray.core.generated import gcs_pb2, gcs_service_pb2, gcs_service_pb2_grpc

from tests.conftest import RAY_WORKER_NICENESS, ROOT, free_port
from tests.test_sweep_cluster import SWEEP
from train.sweep.results import read_tables

RAY = Path(sys.executable).with_name("ray")


@dataclass
class RayStartCluster:
    """Two nodes started with ``ray start``; ``env``: the environment of the node that got a copy of the token."""

    address: str
    node_ids: set[str]
    env: dict[str, str]


def node_env(home: Path) -> dict[str, str]:
    """This environment without Ray's settings, a home of the node's own and token authentication on; a node
    that is stopped leaves at once (Ray 2.60 drains one for up to 30 s on SIGTERM), and its workers run at the
    tests' priority (``tests.conftest.RAY_WORKER_NICENESS``)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAY_")}
    return {**env, "HOME": str(home), "RAY_AUTH_MODE": "token", "RAY_GRACEFUL_SHUTDOWN_DRAIN_TIMEOUT_S": "0",
            "RAY_worker_niceness": RAY_WORKER_NICENESS}


def start_node(folder: Path, env: dict[str, str], *flags: str) -> subprocess.Popen:
    """``ray start ... --block`` with one CPU, its own temp folder and free ports, in a process group of its own."""
    (folder / "tmp").mkdir(parents=True)
    return subprocess.Popen(
        [str(RAY), "start", *flags, "--num-cpus", "1", "--block", "--disable-usage-stats", "--temp-dir",
         str(folder / "tmp"), "--dashboard-agent-listen-port", str(free_port())],
        env=env, stdout=open(folder / "ray_start.log", "w"), stderr=subprocess.STDOUT, start_new_session=True)


def alive_nodes(address: str, token: str) -> set[str]:
    """The ids of the cluster's live nodes, asked of its GCS with the token."""
    with grpc.insecure_channel(address) as channel:
        reply = gcs_service_pb2_grpc.NodeInfoGcsServiceStub(channel).GetAllNodeInfo(
            gcs_service_pb2.GetAllNodeInfoRequest(), timeout=10, metadata=[("authorization", f"Bearer {token}")])
    return {n.node_id.hex() for n in reply.node_info_list if n.state == gcs_pb2.GcsNodeInfo.ALIVE}


def wait_until(condition, node: subprocess.Popen, log: Path, seconds: float = 120) -> None:
    """Until ``condition()`` holds, while ``node``'s ``ray start`` runs (its ``log`` otherwise)."""
    deadline = time.monotonic() + seconds
    while not condition():
        assert node.poll() is None and time.monotonic() < deadline, log.read_text()
        time.sleep(0.2)


def node_processes(root: Path) -> list[int]:
    """The live processes (not zombies) of the nodes whose homes are under ``root``: every process a node starts
    inherits its ``HOME``, whatever process group or session it moves to."""
    found = []
    for proc in Path("/proc").glob("[0-9]*"):
        try:
            home = any(v.startswith(f"HOME={root}/".encode()) for v in (proc / "environ").read_bytes().split(b"\0"))
            if home and (proc / "stat").read_text().rsplit(")", 1)[1].split()[0] != "Z":
                found.append(int(proc.name))
        except OSError:  # it ended meanwhile
            pass
    return found


def stop_nodes(nodes: list[subprocess.Popen], root: Path) -> list[str]:
    """SIGTERM to each node's process group, the head's last; the processes still there 30 s later (then
    killed), as ``pid: command``."""
    for node in reversed(nodes):
        os.killpg(node.pid, signal.SIGTERM)
        try:
            node.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(node.pid, signal.SIGKILL)
            node.wait()
    deadline = time.monotonic() + 30
    while node_processes(root) and time.monotonic() < deadline:
        time.sleep(0.2)
    left = []
    for pid in node_processes(root):
        left.append(f"{pid}: {Path(f'/proc/{pid}/cmdline').read_bytes()[:120]!r}")
        os.kill(pid, signal.SIGKILL)
    return left


@pytest.fixture(scope="module")
def cluster():
    root = Path(tempfile.mkdtemp(prefix="ray", dir="/tmp"))  # short: a Ray socket's path must fit in 107 bytes
    head_home, worker_home = root / "head" / "home", root / "worker" / "home"
    head_home.mkdir(parents=True)
    # the head: a token, written to its ~/.ray/auth_token; the other node gets a copy, as scp would
    subprocess.run([str(RAY), "get-auth-token", "--generate"], env=node_env(head_home), check=True,
                   capture_output=True)
    (worker_home / ".ray").mkdir(parents=True)
    shutil.copy(head_home / ".ray" / "auth_token", worker_home / ".ray" / "auth_token")
    token = (head_home / ".ray" / "auth_token").read_text()
    address = f"127.0.0.1:{free_port()}"
    nodes = [start_node(root / "head", node_env(head_home), "--head", "--port", address.split(":")[1],
                        "--include-dashboard", "false", "--dashboard-port", str(free_port()),
                        "--ray-client-server-port", str(free_port()))]
    try:
        head_log = root / "head" / "ray_start.log"
        wait_until(lambda: "Ray runtime started" in head_log.read_text(), nodes[0], head_log)
        nodes.append(start_node(root / "worker", node_env(worker_home), "--address", address))
        wait_until(lambda: len(alive_nodes(address, token)) == 2, nodes[1], root / "worker" / "ray_start.log")
        node_ids = alive_nodes(address, token)
        yield RayStartCluster(address, node_ids, node_env(worker_home))
    finally:
        left = stop_nodes(nodes, root)
        shutil.rmtree(root, ignore_errors=True)
    assert not left, f"processes of the Ray nodes left after SIGTERM: {left}"


def sweep_run(tmp_path: Path, address: str, env: dict[str, str]) -> subprocess.CompletedProcess:
    """``colorgrid sweep run --address`` of a two-trial sweep, as a user types it, with ``env``."""
    path = tmp_path / "two.toml"
    path.write_text(SWEEP)
    return subprocess.run([sys.executable, "-m", "colorgrid_apps", "sweep", "run", str(path), "--out",
                           str(tmp_path / "out"), "--address", address], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=600)


def assert_one_line_error(done: subprocess.CompletedProcess, words: str) -> None:
    """Exit code 2 and one line, ``colorgrid sweep run: error: ...`` with ``words`` and where to read more; no
    lines of Ray's retries, and nothing started."""
    assert done.returncode == 2, done.stdout + done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("colorgrid sweep run: error: "), done.stderr
    assert words in lines[0] and "docs/SWEEPS.md" in lines[0], lines[0]
    assert done.stdout == ""


def test_no_cluster_at_the_address_is_one_line(tmp_path: Path):
    """Where nothing listens, Ray would retry for minutes."""
    done = sweep_run(tmp_path, f"127.0.0.1:{free_port()}", {**node_env(tmp_path), "RAY_AUTH_MODE": "disabled"})
    assert_one_line_error(done, "no Ray cluster answers at 127.0.0.1:")


def test_sweep_runs_trials_on_both_nodes(tmp_path: Path, cluster: RayStartCluster):
    # the driver on the node that got the copy of the token, with RAY_AUTH_MODE=token as on the nodes
    done = sweep_run(tmp_path, cluster.address, cluster.env)
    assert done.returncode == 0, done.stdout + done.stderr
    trials, _ = read_tables(tmp_path / "out")
    assert trials["finished"].all() and len(trials) == 2
    # one CPU a node and one a trial: the two trials can only run at once on different nodes
    assert set(trials["node"]) == cluster.node_ids


@pytest.mark.parametrize("changes, words", [
    # the driver on a node with the head's token, run without RAY_AUTH_MODE: Ray sends no token to HOST:PORT
    pytest.param({"RAY_AUTH_MODE": None}, "sends none (RAY_AUTH_MODE is not 'token'): run with RAY_AUTH_MODE=token",
                 id="no-auth-mode"),
    pytest.param({"RAY_AUTH_TOKEN": "0" * 32}, "refused this machine's token (from RAY_AUTH_TOKEN)",
                 id="another-token"),
    pytest.param({"HOME": "an empty home"}, "RAY_AUTH_MODE=token but this machine has no Ray token", id="no-token"),
])
def test_a_driver_without_the_clusters_token_is_refused_in_one_line(tmp_path: Path, cluster: RayStartCluster,
                                                                    changes: dict, words: str):
    env = {k: v for k, v in {**cluster.env, **changes}.items() if v is not None}
    if "HOME" in changes:
        env["HOME"] = str(tmp_path)
    assert_one_line_error(sweep_run(tmp_path, cluster.address, env), words)
