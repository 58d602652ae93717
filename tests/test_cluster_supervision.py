"""The launcher's care of its children, without HAProxy: a backend whose launcher is gone stops, one child
that cannot be started again does not take the others down, and the cluster file is private from its start."""

from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from server.cluster import launcher
from server.cluster.launcher import Child
from server.cluster.plan import RESTARTS_ENV, ClusterPlan, Membership
from server.cluster.process import BackendSpec
from server.settings import ServerSettings
from tests.conftest import ROOT, free_port


def test_a_backend_whose_launcher_died_before_it_read_its_spec_stops(tmp_path: Path):
    # The launcher named in the spec is not this process's parent: it died while the backend loaded (its parent
    # is now another process), so the backend stops instead of serving with no launcher.
    plan = ClusterPlan.local("127.0.0.1", free_port(), 1)
    plan.write(tmp_path / "cluster.json")
    member = plan.members[0]
    spec = BackendSpec(ServerSettings(host=member.host, port=member.port, replays_dir=tmp_path),
                       Membership(tmp_path / "cluster.json", member.name), "warning", launcher_pid=os.getpid() + 10**6)
    result = subprocess.run([sys.executable, "-m", "server.cluster.process"], input=pickle.dumps(spec), cwd=ROOT,
                            capture_output=True, timeout=20)  # a backend watching the wrong parent never stops
    assert result.returncode in (0, -15), result.stderr[-500:]


def test_a_child_that_cannot_be_started_again_is_tried_again_later_and_the_watch_goes_on(capsys):
    child = Child("b1", [sys.executable, "-c", "pass"])
    child.start()
    child.process.wait()
    child.wait_s = 0.01
    child.check()  # noticed: started again after its wait
    assert "starting it again in 0.01 s" in capsys.readouterr().out
    child.argv = [str(ROOT / "no-such-program")]
    child.check(now=child.restart_at - 0.001)  # its wait is not over: nothing yet
    assert capsys.readouterr().out == "" and child.restarts == 0
    child.check(now=child.restart_at)  # the start fails: said in one line, tried again after a longer wait
    assert "b1 could not be started again" in capsys.readouterr().out
    assert child.restart_at is not None and child.wait_s == 0.04
    child.argv = [sys.executable, "-c", "pass"]
    child.check(now=child.restart_at)
    assert "b1 started again (restart 2" in capsys.readouterr().out
    child.process.wait()


def test_a_backend_started_again_is_told_how_many_times_for_its_health_to_report(tmp_path):
    said = tmp_path / "restarts"
    write = f"import os; open({str(said)!r}, 'a').write(os.environ[{RESTARTS_ENV!r}])"
    child = Child("b1", [sys.executable, "-c", write], env=dict(os.environ))
    child.start()
    child.process.wait()
    child.wait_s = 0.01
    child.check()  # noticed: started again after its wait
    child.check(now=child.restart_at)
    child.process.wait()
    assert said.read_text() == "01", "0 at its first start, 1 once started again"


def test_the_launcher_stops_its_children_whatever_ends_its_watch(monkeypatch, tmp_path):
    monkeypatch.setattr(launcher, "haproxy_binary", lambda: "haproxy")
    cluster = launcher.Cluster(ClusterPlan.local("127.0.0.1", free_port(), 1), ServerSettings(), tmp_path)
    stopped = []
    monkeypatch.setattr(cluster, "start", lambda: None)
    monkeypatch.setattr(cluster, "poll", lambda: 1 / 0)
    monkeypatch.setattr(cluster, "stop", lambda: stopped.append(True))
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        with pytest.raises(ZeroDivisionError):
            cluster.run()
    finally:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
    assert stopped == [True]


def test_the_cluster_file_is_private_before_the_secret_is_written_into_it(monkeypatch, tmp_path):
    modes = []
    write_text = Path.write_text

    def recording(self, *args, **kwargs):
        modes.append(self.stat().st_mode & 0o777)
        return write_text(self, *args, **kwargs)

    monkeypatch.setattr(Path, "write_text", recording)
    ClusterPlan.local("127.0.0.1", free_port(), 1).write(tmp_path / "cluster.json")
    assert modes == [0o600] and (tmp_path / "cluster.json").stat().st_mode & 0o777 == 0o600
