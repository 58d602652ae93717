"""A study's factors: each is a field of ``GameSettings``, its fixed sets held as their enums' members (the file's and
the export's text unchanged), and a new one is added in ``server/study/config.py`` and ``server/study/schema.py``
alone, as docs/ARCHITECTURE.md says: a toy factor added so in a temporary copy of ``server/`` is taken by a study
file, varied by the conditions, refused at a bad level and exported."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
import sys

from colorgrid.enums import Role
from server.protocol import GoalView, Mode
from server.study.config import FACTORS, GameSettings
from tests.conftest import ROOT


def test_the_mode_seat_and_goal_are_members_written_as_their_text():
    settings = GameSettings(mode="turn", seat="follower", goal="shown")
    assert (settings.mode, settings.seat, settings.goal) == (Mode.TURN, Role.FOLLOWER, GoalView.SHOWN)
    assert type(settings.mode) is Mode and type(settings.seat) is Role and type(settings.goal) is GoalView
    written = json.loads(json.dumps(dataclasses.asdict(settings)))
    assert (written["mode"], written["seat"], written["goal"]) == ("turn", "follower", "shown")
    assert settings.label().startswith("follower=bayes-people, show_belief=True, mode=turn,")
    assert FACTORS == tuple(f.name for f in dataclasses.fields(GameSettings))


TOY_FIELD = '''    toy: int = 0
    """A toy factor: a whole number each game records."""
'''
TOY_CHECK = '''        check_int(self, "toy", 0, 9, allowed="a whole number in 0..9")
'''
TOY_COLUMN = '''        "toy": Column("condition_toy", "Int64", "level", "the toy factor"),
'''
PLAYED = """
import tomllib
from pathlib import Path

import server
from server.study.config import FACTORS, StudyError, parse_study
from server.study.power import measures
from server.study.schema import export_schema

assert Path(server.__file__).parent == Path.cwd() / "server", server.__file__  # the copy, not the checkout
data = tomllib.loads(Path(STUDY).read_text())
data["factors"]["toy"] = [1, 2]
study = parse_study(data)
assert "toy" in FACTORS
assert len(study.conditions) == 2 * len(parse_study({**data, "factors": {k: v for k, v in data["factors"].items()
                                                                          if k != "toy"}}).conditions)
assert [c.toy for c in study.conditions[:2]] == [1, 2] and study.conditions[1].played()["toy"] == 2
column = next(c for c in export_schema(study)["trials"].columns if c.name == "condition_toy")
assert column.type == "Int64" and "condition_toy" not in measures(study)
data["factors"]["toy"] = [1, 12]
try:
    parse_study(data)
    raise AssertionError("a bad level was taken")
except StudyError as err:
    assert str(err) == "factors.toy: level 12 is invalid: a whole number in 0..9", err
print("ok")
"""


def insert(path, before: str, text: str) -> None:
    """Put ``text`` in ``path`` just before ``before``, which it holds once."""
    source = path.read_text()
    assert source.count(before) == 1, f"{path.name} has changed: update this test and docs/ARCHITECTURE.md"
    path.write_text(source.replace(before, text + before))


def test_a_toy_factor_added_in_two_files_is_varied_checked_and_exported(tmp_path):
    shutil.copytree(ROOT / "server", tmp_path / "server", ignore=shutil.ignore_patterns("__pycache__"))
    config, schema = tmp_path / "server" / "study" / "config.py", tmp_path / "server" / "study" / "schema.py"
    # 1. its field, default, docstring and check in GameSettings
    insert(config, '\n    def __post_init__(self):\n        if not isinstance(self.follower, str)', TOY_FIELD)
    insert(config, '\n    def label(self) -> str:', TOY_CHECK)
    # 2. its exported column
    insert(schema, "    }\n    missing = {f.name for f in dataclasses.fields(GameSettings)}", TOY_COLUMN)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")])}
    script = f"STUDY = {str(ROOT / 'studies' / 'belief_display.toml')!r}\n" + PLAYED
    done = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr[-3000:]
