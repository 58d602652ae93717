"""The launcher's care of its children, without HAProxy: a backend whose launcher is gone stops, and one child
that cannot be started again does not take the others down."""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
from pathlib import Path

from server.cluster.plan import ClusterPlan, Membership
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
