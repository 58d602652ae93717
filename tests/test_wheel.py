"""The package as a user installs it: ``python -m build`` makes the sdist and, from it, the wheel; the wheel is
installed (not editable) into fresh virtualenvs outside the repository and run from another folder.

* With the ``all`` extra: the play server serves its page, its options and a whole game with a trained
  follower; the population matrix runs with trained followers; the shipped example study starts; a released
  replay exports to GIF. Its dependencies come from this test environment's own site-packages, put under
  the fresh virtualenv with a ``.pth`` file, so that ``pip install WHEEL[all]`` resolves every requirement
  of the extra offline (it would fail on one that is missing there) and installs only the wheel.
* The core alone, installed by pip with its own dependencies (the versions this environment has, from the
  package index or pip's cache): the env and its PettingZoo and Gymnasium views and ``colorgrid eval`` work,
  the documents' core examples run, a released replay exports to GIF in the current folder, and the
  commands and policies of the other extras (MP4 export too) say in one line which extra to install.
"""

from __future__ import annotations

import hashlib
import json
import re
import subprocess
import sys
import sysconfig
from importlib.metadata import distributions
from pathlib import Path

import pytest

from tests.conftest import ROOT, start_server, stop_server
from tests.test_server import MOVES, Client

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


def run(args: list, cwd: Path, check: bool = True, timeout: float = 300) -> subprocess.CompletedProcess:
    done = subprocess.run([str(a) for a in args], cwd=cwd, capture_output=True, text=True, timeout=timeout)
    if check and done.returncode != 0:
        raise AssertionError(f"{args} failed ({done.returncode}):\n{done.stdout}\n{done.stderr}")
    return done


@pytest.fixture(scope="module")
def dist(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("dist")
    run([sys.executable, "-m", "build", "--outdir", out, ROOT], cwd=out, timeout=600)
    return out


@pytest.fixture(scope="module")
def wheel(dist) -> Path:
    (found,) = dist.glob("colorgrid-*.whl")
    return found


def new_venv(path: Path, underlay: str | None = None) -> Path:
    """A fresh virtualenv at ``path``; ``underlay``: a site-packages folder whose packages it sees (a .pth line)."""
    run([sys.executable, "-m", "venv", path], cwd=path.parent)
    if underlay is not None:  # the underlay's own setuptools (torch needs a newer one than venv's)
        run([path / "bin" / "python", "-m", "pip", "uninstall", "-q", "-y", "setuptools"], cwd=path.parent)
        site = run([path / "bin" / "python", "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                   cwd=path.parent).stdout.strip()
        Path(site, "underlay.pth").write_text(underlay + "\n")
    return path / "bin" / "python"


@pytest.fixture(scope="module")
def full(tmp_path_factory, wheel) -> tuple[Path, Path]:
    """(python, working folder) of a virtualenv with the wheel and its ``all`` extra."""
    root = tmp_path_factory.mktemp("full")
    python = new_venv(root / "venv", underlay=sysconfig.get_paths()["purelib"])
    run([python, "-m", "pip", "install", "--no-index", f"{wheel}[all]"], cwd=root)
    work = root / "work"
    work.mkdir()
    return python, work


@pytest.fixture(scope="module")
def core(tmp_path_factory, wheel) -> tuple[Path, Path]:
    """(python, working folder) of a virtualenv with the wheel alone (the core)."""
    root = tmp_path_factory.mktemp("core")
    python = new_venv(root / "venv")
    versions = sorted(f"{d.metadata['Name']}=={d.version}" for d in distributions()
                      if d.metadata["Name"] and d.metadata["Name"].lower() != "colorgrid")
    constraints = root / "constraints.txt"
    constraints.write_text("\n".join(versions) + "\n")
    run([python, "-m", "pip", "install", "-q", "-c", constraints, wheel], cwd=root, timeout=600)
    work = root / "work"
    work.mkdir()
    return python, work


def test_the_sdist_and_wheel_carry_every_subpackage_and_the_shipped_folders(dist, wheel):
    import tarfile
    import zipfile

    names = set(zipfile.ZipFile(wheel).namelist())
    for module in ("server/study/cli.py", "train/sweep/runner.py", "colorgrid/policies/bayes.py",
                   "colorgrid_apps/cli.py", "train/presets/default.json"):
        assert module in names, module
    for shipped in ("web/index.html", "checkpoints/follower.pt", "checkpoints/follower.md",
                    "populations/people.json", "studies/belief_display.toml", "sweeps/paper_table1_small.toml",
                    "replays/index.json"):
        assert f"colorgrid/_data/{shipped}" in names, shipped
        assert Path(ROOT, shipped).read_bytes() == zipfile.ZipFile(wheel).read(f"colorgrid/_data/{shipped}")
    (sdist,) = wheel.parent.glob("colorgrid-*.tar.gz")
    members = {m.split("/", 1)[1] for m in tarfile.open(sdist).getnames() if "/" in m}
    assert {"setup.py", "web/index.html", "checkpoints/follower.pt", "replays/index.json"} <= members


def test_installed_with_all_extras_the_play_server_plays_a_game_with_a_trained_follower(full, tmp_path):
    python, work = full
    assert run([python, "-m", "colorgrid_apps", "--version"], cwd=work).stdout.startswith("colorgrid ")
    where = run([python, "-c", "import colorgrid, server, train; print(colorgrid.__file__, server.__file__, "
                               "train.__file__)"], cwd=work).stdout.split()
    assert all(str(ROOT) not in path and "site-packages" in path for path in where)
    server = start_server(tmp_path, "--follower", "ippo", python=str(python), cwd=work)
    try:
        page, status, kind = server.get("/")
        assert status == 200 and "text/html" in kind and b"<script" in page
        options = server.get("/api/options")[0]
        assert options["default_follower"] == "ippo" and {"ippo", "ippo-people"} <= set(options["followers"])
        client = Client(server)
        welcome, state = client.new_game(mode="turn", horizon=8, follower="ippo")
        assert welcome["mode"] == "turn" and state["step"] == 0
        for t in range(8):
            client.key(MOVES[t % 4])
            assert client.recv("state")["step"] == t + 1
        over = client.recv("game_over")
        client.close()
        assert over["reason"] == "complete" and over["steps"] == 8
        replay = (server.replays_dir / f"{over['replay_id']}.replay.json").read_text()
        shipped = hashlib.sha256((ROOT / "checkpoints" / "follower.pt").read_bytes()).hexdigest()
        assert shipped in replay  # the follower that played is the shipped checkpoint, from the wheel
    finally:
        stop_server(server)


def test_installed_with_all_extras_the_population_matrix_runs_trained_followers(full):
    python, work = full
    run([python, "-m", "colorgrid_apps", "eval", "--leaders", "population:people#held_out", "--compare",
         "bayes-people", "ippo-cautious", "--episodes", "2", "--workers", "1", "--json", "matrix.json"], cwd=work)
    matrix = json.loads((work / "matrix.json").read_text())
    held_out = json.loads((ROOT / "populations" / "people.json").read_text())["held_out"]
    assert matrix["followers"] == ["bayes-people", "ippo-cautious"] and list(matrix["leaders"]) == list(held_out)
    assert set(matrix["cells"]) == set(held_out)


def test_installed_with_all_extras_the_shipped_study_starts_and_a_released_replay_exports(full, tmp_path):
    python, work = full
    server = start_server(tmp_path, command=("study", "run", "belief_display"), python=str(python), cwd=work)
    try:
        page, status, kind = server.get("/study?PROLIFIC_PID=wheel-test")
        assert status == 200 and "text/html" in kind
    finally:
        stop_server(server)
    listed = run([python, "-m", "colorgrid_apps", "replay", "list"], cwd=work).stdout
    assert "default/astar+bayes_seed2026" in listed
    run([python, "-m", "colorgrid_apps", "export", "default/astar+bayes_seed2026", "--format", "gif", "--out",
         "episode.gif"], cwd=work)
    assert (work / "episode.gif").read_bytes()[:6] in (b"GIF87a", b"GIF89a")
    run([python, "-m", "colorgrid_apps", "export", "default/astar+bayes_seed2026", "--format", "mp4", "--out",
         "episode.mp4", "--end", "8"], cwd=work)  # the video extra, in all
    assert (work / "episode.mp4").read_bytes()[4:8] == b"ftyp"


CORE_CHECK = """
import gymnasium, numpy as np, colorgrid
from gymnasium.utils.env_checker import check_env
from pettingzoo.test import parallel_api_test
parallel_api_test(colorgrid.parallel_env(), num_cycles=50)
check_env(colorgrid.gym_env(seat="follower", partners="population:people#held_out"))
vec = gymnasium.make_vec(colorgrid.GYM_ID, num_envs=4, vectorization_mode="vector_entry_point", flatten=True)
obs, _ = vec.reset(seed=0)
obs, reward, *_ = vec.step(np.zeros(4, dtype=np.int64))
assert obs.shape[0] == 4 and reward.shape == (4,)
for module in ("torch", "fastapi", "ray", "viser", "pandas"):
    try:
        __import__(module)
    except ImportError:
        continue
    raise SystemExit(f"the core installed {module}")
print("core ok")
"""


def test_the_core_alone_runs_the_env_its_views_and_scripted_evaluation(core):
    python, work = core
    assert "core ok" in run([python, "-c", CORE_CHECK], cwd=work).stdout
    done = run([python, "-m", "colorgrid_apps", "eval", "--compare", "copy", "bayes", "--episodes", "2"], cwd=work)
    assert "bayes" in done.stdout and "copy" in done.stdout


# A ```python block right after this marker in README.md or docs/ECOSYSTEM.md runs on the core alone.
CORE_EXAMPLE_MARK = "<!-- core example"
CORE_EXAMPLE = re.compile(re.escape(CORE_EXAMPLE_MARK) + r"[^\n]*-->\n```python\n(.*?)\n```\n", re.DOTALL)


@pytest.mark.parametrize("document", ["README.md", "docs/ECOSYSTEM.md"])
def test_the_core_alone_runs_the_documents_core_examples(core, document):
    python, work = core
    text = (ROOT / document).read_text()
    examples = CORE_EXAMPLE.findall(text)
    assert examples and len(examples) == text.count(CORE_EXAMPLE_MARK), \
        f"{document}: each '{CORE_EXAMPLE_MARK} ... -->' line must stand right above a ```python block"
    assert run([python, "-c", "import importlib.util; print(importlib.util.find_spec('torch'))"],
               cwd=work).stdout.strip() == "None"
    for i, code in enumerate(examples):
        script = work / f"{Path(document).stem}_core_example_{i}.py"
        script.write_text(code + "\nprint('example ran')\n")
        assert run([python, script], cwd=work).stdout.endswith("example ran\n")


def test_the_core_alone_exports_a_released_replay_to_gif_in_the_current_folder(core, tmp_path):
    python, _ = core
    done = run([python, "-m", "colorgrid_apps", "export", "default/astar+bayes_seed2026", "--format", "gif"],
               cwd=tmp_path)
    written = tmp_path / "astar+bayes_seed2026.gif"
    assert written.read_bytes()[:6] in (b"GIF87a", b"GIF89a")
    assert done.stdout.strip() == f"wrote {written.resolve()}"
    package = Path(run([python, "-c", "import colorgrid; print(colorgrid.__file__)"], cwd=tmp_path).stdout.strip())
    assert "site-packages" in str(package)
    assert (package.parent / "_data" / "replays" / "default" / "astar+bayes_seed2026.replay.json").is_file()
    assert not list(package.parent.rglob("*.gif"))  # the wheel ships none; the export left none beside the replay

    refused = run([python, "-m", "colorgrid_apps", "export", "default/astar+bayes_seed2026", "--format", "mp4"],
                  cwd=tmp_path, check=False)
    assert refused.returncode == 2 and refused.stdout == ""
    (line,) = refused.stderr.strip().splitlines()
    assert line.startswith("colorgrid export: error: MP4 export needs the 'video' extra (imageio")
    assert line.endswith("pip install 'colorgrid[video]'")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["astar+bayes_seed2026.gif"]


@pytest.mark.parametrize("args, extra", [
    (["train", "--help"], "train"),
    (["checkpoint", "info", "x.pt"], "train"),
    (["play"], "play"),
    (["study", "run", "belief_display"], "study"),
    (["sweep", "check", "paper_table1_small"], "sweep"),
    (["view"], "viewer"),
    (["eval", "--follower", "ippo", "--episodes", "1"], "train"),
    (["eval", "--leader", "population:people#training", "--episodes", "1"], "train"),  # a trained member
])
def test_the_core_alone_names_the_extra_a_command_needs(core, args, extra):
    python, work = core
    done = run([python, "-m", "colorgrid_apps", *args], cwd=work, check=False)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and f"pip install 'colorgrid[{extra}]'" in lines[0], done.stderr
