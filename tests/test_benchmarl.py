"""BenchMARL as docs/ECOSYSTEM.md installs and runs it: its one pinned ``pip install`` command in a fresh virtualenv
keeps torch on the CPU build, and the documented task trains IPPO on ColorGrid for one iteration.

BenchMARL 1.5.2 needs torchrl < 0.12, so it cannot live in the test environment (torchrl 0.14.1); the virtualenv
is made here, with the machine's pip settings (torch 2.13.0's CPU build, the rest from the package index or pip's
cache), and removed after the test (1.4 GB)."""

from __future__ import annotations

import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import ROOT
from tests.documented import documented_code

(INSTALL,) = documented_code("docs/ECOSYSTEM.md", "tests/test_benchmarl.py", language="bash")
(SCRIPT,) = documented_code("docs/ECOSYSTEM.md", "tests/test_benchmarl.py")
DOCUMENTED_WHEEL = "dist/colorgrid-0.1.0-py3-none-any.whl"


def run(args: list, cwd: Path, timeout: float) -> str:
    done = subprocess.run([str(a) for a in args], cwd=cwd, capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, f"{args} failed ({done.returncode}):\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    return done.stdout


@pytest.fixture
def benchmarl_venv(tmp_path) -> Path:
    """The python of a fresh virtualenv installed by the documented command, the wheel built from this checkout."""
    wheels = tmp_path / "dist"
    run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", wheels, ROOT], cwd=tmp_path, timeout=300)
    (wheel,) = wheels.glob("colorgrid-*.whl")
    assert wheel.name == Path(DOCUMENTED_WHEEL).name, "the documented wheel name is this version's"
    command = shlex.split(INSTALL)
    assert command[:2] == ["pip", "install"] and command[-1] == DOCUMENTED_WHEEL
    venv = tmp_path / "venv"
    run([sys.executable, "-m", "venv", venv], cwd=tmp_path, timeout=120)
    python = venv / "bin" / "python"
    try:
        run([python, "-m", "pip", "install", "-q", "--upgrade", "pip"], cwd=tmp_path, timeout=300)
        run([python, "-m", *command[:-1], "-q", wheel], cwd=tmp_path, timeout=900)
        yield python
    finally:
        shutil.rmtree(venv, ignore_errors=True)


def test_the_documented_benchmarl_install_keeps_the_cpu_torch_and_trains_an_iteration(benchmarl_venv, tmp_path):
    python = benchmarl_venv
    versions = run([python, "-c", "import importlib.metadata as m, torch; "
                                  "print(torch.__version__, torch.version.cuda, m.version('torchvision'), "
                                  "m.version('torchrl'), m.version('benchmarl')); "
                                  "print(sorted(d.metadata['Name'] for d in m.distributions() "
                                  "if d.metadata['Name'].lower().startswith(('nvidia', 'triton'))))"],
                   cwd=tmp_path, timeout=300).splitlines()
    assert versions == ["2.13.0+cpu None 0.28.0 0.11.1 1.5.2", "[]"], "torch stays the CPU build, no CUDA package"

    work = tmp_path / "work"
    work.mkdir()
    (work / "benchmarl_colorgrid.py").write_text(SCRIPT + "\n")
    printed = run([python, "benchmarl_colorgrid.py"], cwd=work, timeout=600).splitlines()
    assert printed[-1] == "1 256", printed[-5:]
    (scalars,) = work.glob("out/*/*/scalars")
    assert (scalars / "counters_total_frames.csv").read_text().split() == ["0,256.0"]
    for logged in ("collection_follower_info_goal_pickup", "collection_leader_info_team_reward",
                   "train_leader_loss_objective", "train_follower_loss_objective"):
        assert len((scalars / f"{logged}.csv").read_text().split()) == 1, logged  # one row: the one iteration
