"""Bad input to the command line: one line on stderr, ``colorgrid COMMAND: error: ...``, never a traceback.

The replay files are damaged the ways files get damaged (cut short, emptied, re-encoded, nested,
given impossible numbers or fields of the wrong type); ``load()`` must turn each into a
``ReplayError``, which the commands print as one line.
"""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from colorgrid import files
from colorgrid.replay import ReplayError, load
from colorgrid.replay.format import Replay, checksum
from train.config import TrainConfigError, from_dict

ROOT = Path(__file__).resolve().parents[1]
GOOD_REPLAY = ROOT / "replays" / "default" / "astar+bayes_seed2026.replay.json"


def rechecksummed(doc: dict) -> str:
    """The document as a file would hold it, with a checksum that matches its (changed) content."""
    body = {k: v for k, v in doc.items() if k != "checksum"}
    return json.dumps({**body, "checksum": checksum(body)})


def changed(**fields) -> str:
    """The good replay with top-level fields (or ``steps__name`` fields) replaced, checksummed again."""
    doc = json.loads(GOOD_REPLAY.read_text())
    for name, value in fields.items():
        if name.startswith("steps__"):
            doc["steps"][name[len("steps__"):]] = value
        else:
            doc[name] = value
    return rechecksummed(doc)


@pytest.fixture(scope="module")
def bad(tmp_path_factory) -> dict[str, Path]:
    """Every damaged input the tests feed the commands, by name."""
    folder = tmp_path_factory.mktemp("bad")
    raw = GOOD_REPLAY.read_text()
    assert '"penalty_coef":1.0' in raw
    contents = {
        # configs
        "list.json": "[1, 2]",
        "nonutf.json": b"\xff\xfe{}",
        # checkpoints
        "junk.pt": os.urandom(4000),
        "empty.pt": b"",
        # replays
        "deep.replay.json": "[" * 100_000,
        "wrapped.replay.json": "[" * 5000 + raw + "]" * 5000,
        "nested.replay.json": "[" * 100 + raw + "]" * 100,  # within the parser's reach, beyond the format's
        "truncated.replay.json": raw[: len(raw) // 2],
        "empty.replay.json": "",
        "nonutf.replay.json": b"\xff\xfe\x00{",
        "huge.replay.json": raw.replace('"penalty_coef":1.0', '"penalty_coef":1e400'),
        "nan.replay.json": raw.replace('"penalty_coef":1.0', '"penalty_coef":NaN'),
        "steps5.replay.json": changed(steps=5),
        "config_list.replay.json": changed(config=[]),
        "goal_x.replay.json": changed(steps__goal="x"),
    }
    paths = {}
    for name, content in contents.items():
        path = folder / name
        path.write_bytes(content if isinstance(content, bytes) else content.encode())
        paths[name] = path
    for name in ("x.pt", "x.replay.json"):
        paths[name] = folder / name
        paths[name].mkdir()
    for run, config in (("run_broken", '{"ppo": '), ("run_list", "[1]"), ("run_invalid", '{"ppo": {"lr": "fast"}}')):
        (folder / run).mkdir()
        (folder / run / "config.json").write_text(config)
        paths[run] = folder / run
    paths["missing.json"] = folder / "missing.json"
    paths["out"] = folder / "out"
    return paths


def run_cli(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "colorgrid_apps", *map(str, args)], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)


def error_line(result: subprocess.CompletedProcess, command: str, code: int = 2) -> str:
    """The one stderr line of a failed command, after checking its exit code and prefix."""
    assert result.returncode == code, (result.returncode, result.stderr)
    assert "Traceback" not in result.stderr, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith(f"colorgrid {command}: error: "), lines[0]
    return lines[0]


# ------------------------------------------------------------ the commands
CLI_CASES = {  # id: (arguments, {name} for a file of `bad`; the command as named in the error; words in the line)
    "eval-config-list": (["eval", "--config", "{list.json}"], "eval",
                         ["--config", "list.json", "JSON object of EnvConfig fields", "array"]),
    "eval-config-missing": (["eval", "--config", "{missing.json}"], "eval", ["missing.json", "no such file"]),
    "eval-config-not-utf8": (["eval", "--config", "{nonutf.json}"], "eval", ["nonutf.json", "not UTF-8"]),
    "train-set-not-a-number": (["train", "--set", "ppo.lr=abc"], "train", ["ppo.lr='abc'", "a number"]),
    "train-set-not-a-bool": (["train", "--set", "ppo.norm_adv=3"], "train", ["ppo.norm_adv=3", "true or false"]),
    "train-config-list": (["train", "--config", "{list.json}"], "train", ["list.json", "JSON object", "array"]),
    "train-resume-broken-json": (["train", "--resume", "{run_broken}"], "train",
                                 ["run_broken/config.json", "not valid JSON"]),
    "train-resume-list": (["train", "--resume", "{run_list}"], "train", ["run_list/config.json", "JSON object"]),
    "train-resume-invalid": (["train", "--resume", "{run_invalid}"], "train",
                             ["run_invalid/config.json", "ppo.lr='fast'", "a number"]),
    "eval-follower-junk": (["eval", "--follower", "{junk.pt}", "--episodes", "1"], "eval",
                           ["junk.pt is not a readable ColorGrid checkpoint"]),
    "checkpoint-info-junk": (["checkpoint", "info", "{junk.pt}"], "checkpoint info",
                             ["junk.pt is not a readable ColorGrid checkpoint"]),
    "checkpoint-export-empty": (["checkpoint", "export", "{empty.pt}", "--agent", "leader", "--out", "{out}/a.pt"],
                                "checkpoint export", ["empty.pt is not a readable ColorGrid checkpoint", "empty"]),
    "checkpoint-card-directory": (["checkpoint", "card", "{x.pt}", "--agent", "leader", "--out", "{out}/c.md"],
                                  "checkpoint card", ["x.pt is not a readable ColorGrid checkpoint", "directory"]),
    "replay-info-deep": (["replay", "info", "{deep.replay.json}"], "replay info",
                         ["deep.replay.json", "nested too deeply"]),
    "export-nan": (["export", "{nan.replay.json}", "--format", "gif"], "export", ["nan.replay.json", "NaN"]),
    "export-directory": (["export", "{x.replay.json}", "--format", "gif", "--out", "{out}"], "export",
                         ["x.replay.json", "is a directory"]),
    "view-export-wrapped": (["view", "{wrapped.replay.json}", "--export", "{out}/r.html"], "view",
                            ["wrapped.replay.json", "nested too deeply"]),
    "eval-temperature-negative": (["eval", "--follower", "ippo:temperature=-1", "--episodes", "1"], "eval",
                                  ["temperature=-1 is invalid", "0 (greedy) or a finite number >= 0.01"]),
    "eval-unknown-parameter": (["eval", "--follower", "ippo:temp=0", "--episodes", "1"], "eval",
                               ["'ippo:temp=0'", "unknown parameter(s) ['temp']",
                                "allowed: ['temperature', 'min_belief']"]),
}


@pytest.mark.parametrize("case", list(CLI_CASES))
def test_a_bad_invocation_gives_one_error_line(case, bad):
    args, command, words = CLI_CASES[case]
    result = run_cli(*(re.sub(r"\{([^}]+)\}", lambda m: str(bad[m.group(1)]), a) for a in args))
    line = error_line(result, command)
    for word in words:
        assert word in line, (word, line)
    assert "weights_only" not in line  # torch's advice to unpickle arbitrary code is never passed on


def test_replay_verify_reports_each_damaged_file_on_one_line(bad):
    names = ["deep.replay.json", "wrapped.replay.json", "nested.replay.json", "truncated.replay.json",
             "empty.replay.json", "nonutf.replay.json", "huge.replay.json", "nan.replay.json", "steps5.replay.json",
             "config_list.replay.json", "goal_x.replay.json", "x.replay.json"]
    result = run_cli("replay", "verify", GOOD_REPLAY, *(bad[n] for n in names))
    assert result.returncode == 1 and result.stderr == "", result.stderr
    lines = result.stdout.strip().splitlines()
    assert lines[0] == f"{GOOD_REPLAY}: ok"
    expected = ["nested too deeply", "nested too deeply", "nested deeper than 32 levels", "not valid JSON",
                "the file is empty", "not UTF-8", "1e400, which is not a finite number", "NaN",
                "steps must be an object", "config must be an object", "steps.goal must be a list",
                "is a directory"]
    assert len(lines) == 1 + len(names), result.stdout
    for line, name, problem in zip(lines[1:], names, expected):
        assert line.startswith(f"{bad[name]}: error: ") and problem in line, (name, line)


# ------------------------------------------------------------ load() on damaged files
@pytest.mark.parametrize("name, problem", [
    ("deep.replay.json", "nested too deeply"), ("wrapped.replay.json", "nested too deeply"),
    ("nested.replay.json", "nested deeper than 32 levels"), ("truncated.replay.json", r"not valid JSON \(truncated"),
    ("empty.replay.json", "the file is empty"), ("nonutf.replay.json", "not UTF-8 text"),
    ("huge.replay.json", "1e400, which is not a finite number"), ("nan.replay.json", "NaN, which is not a finite"),
    ("x.replay.json", "is a directory, not a file"),
])
def test_load_turns_damaged_files_into_replay_errors(bad, name, problem):
    with pytest.raises(ReplayError, match=problem) as err:
        load(bad[name])
    assert err.value.path == str(bad[name]) and "\n" not in str(err.value)


@pytest.mark.parametrize("fields, problem", [
    ({"steps": 5}, "steps must be an object, got 5"),
    ({"config": []}, "config must be an object, got list"),
    ({"steps__goal": "x"}, "steps.goal must be a list, got 'x'"),
    ({"agents": []}, "agents must be an object"),
    ({"agents": {"leader": "astar"}}, "agents must map each agent name to an object"),
    ({"meta": [1]}, "meta must be an object or null"),
    ({"seed": "7"}, "seed must be an integer or null"),
    ({"seed": 10**30}, r"integer seed in \[0, 2\*\*63 - 1\]"),
    ({"penalty_coef": "1"}, "penalty_coef must be a number"),
    ({"penalty_coef": 10**400}, "penalty_coef must be a number"),
    ({"source": 3}, "source must be a string"),
    ({"frames": 5}, "frames must be an object or null"),
    ({"key_events": {"a": 1}}, "key_events must be a list or null"),
    ({"key_events": [1]}, "key_events must be a list of objects"),
    ({"meta": {"state_sent_ms": "x"}}, "meta.state_sent_ms must be a list of numbers"),
    ({"kind": "frames"}, "kind is 'frames'"),
    ({"steps__goal_probs": []}, "steps.goal_probs must be an object or null"),
    ({"steps__goal_probs": {"follower": [["a"]]}}, "steps.goal_probs.follower must be"),
    ({"steps__block_reward": [["x", 0]] * 128}, r"steps.block_reward must be \[T\]\[2\] numbers"),
    ({"steps__picked_color": [[0, 9]] * 128}, r"steps.picked_color must be \[T\]\[2\] integers"),
    ({"steps__goal_switched": [0] * 128}, "steps.goal_switched must be"),
    ({"steps__state_hash": [1] * 129}, "steps.state_hash must have 129 entries"),
    ({"steps__actions": 4}, "steps.actions must be a list or null"),
    ({"config": {"distance_penalty_agents": [[1]]}}, "invalid config: EnvConfig.distance_penalty_agents"),
])
def test_fields_of_the_wrong_type_are_replay_errors(tmp_path, fields, problem):
    path = tmp_path / "typed.replay.json"
    path.write_text(changed(**fields))
    with pytest.raises(ReplayError, match=problem):
        load(path)


def test_the_good_replay_still_loads():
    assert len(json.loads(GOOD_REPLAY.read_text())["steps"]["goal"]) == 128  # the cases above assume T = 128
    assert load(GOOD_REPLAY, max_bytes=10_000_000).num_steps == 128


def test_documents_built_in_code_are_checked_too():
    doc = json.loads(GOOD_REPLAY.read_text())
    doc["penalty_coef"] = float("nan")
    with pytest.raises(ReplayError, match="cannot be checksummed"):
        Replay.from_document(doc)
    with pytest.raises(ReplayError, match="not a ColorGrid replay"):
        Replay.from_document([doc])


def test_max_bytes_refuses_a_large_file_without_reading_it(tmp_path, monkeypatch):
    big = tmp_path / "big.replay.json"
    with open(big, "wb") as f:
        f.truncate(120_000_000)  # sparse: costs no disk

    def no_reading(*args, **kwargs):
        raise AssertionError("the file was opened")

    monkeypatch.setattr(files, "open", no_reading, raising=False)
    with pytest.raises(ReplayError, match=r"big.replay.json: file is 120.0 MB; the limit is 50.0 MB"):
        load(big, max_bytes=50_000_000)


def test_only_regular_files_are_read(tmp_path):
    fifo = tmp_path / "pipe.replay.json"
    os.mkfifo(fifo)  # opening it would block until a writer came
    with pytest.raises(ReplayError, match="is not a regular file"):
        load(fifo)
    with pytest.raises(ReplayError, match="no such file"):
        load(tmp_path / "nowhere.replay.json")


# ------------------------------------------------------------ training settings of the wrong type
@pytest.mark.parametrize("data, message", [
    ({"ppo": {"lr": "abc"}}, "ppo.lr='abc' is invalid: a number in (0, 1)"),
    ({"ppo": {"gamma": None}}, "ppo.gamma=None is invalid: a number in [0, 1]"),
    ({"ppo": {"ent_coef": True}}, "ppo.ent_coef=True is invalid: a non-negative number"),
    ({"ppo": {"target_kl": "x"}}, "ppo.target_kl='x' is invalid: a positive number, or null"),
    ({"ppo": {"clip_vloss": "yes"}}, "ppo.clip_vloss='yes' is invalid: true or false"),
    ({"ppo": {"norm_adv": 1}}, "ppo.norm_adv=1 is invalid: true or false"),
    ({"follower": {"aux_coef": "x"}}, "follower.aux_coef='x' is invalid: a number in [0, 100]"),
    ({"leader": {"lr": [1]}}, "leader.lr=[1] is invalid: a number in (0, 1), or null"),
    ({"leader": {"init": 5}}, "leader.init=5 is invalid: a checkpoint path"),
    ({"follower": {"net": {"lstm": "x"}}}, "follower.net.lstm='x' is invalid: true or false"),
    ({"follower": {"net": {"hidden": 1.5}}}, "follower.net.hidden=1.5 is invalid: an integer in [1, 4096]"),
    ({"schedule": {"penalty_start": "x", "penalty_end": 5}}, "schedule.penalty_start='x' is invalid: an integer"),
    ({"schedule": {"shaping_steps": -1}}, "schedule.shaping_steps=-1 is invalid: an integer >= 0 or null"),
    ({"seed": "1"}, "seed='1' is invalid: an integer >= 0"),
])
def test_training_settings_of_the_wrong_type_name_field_value_and_type(data, message):
    with pytest.raises(TrainConfigError) as err:
        from_dict(data)
    assert str(err.value) == message or str(err.value).startswith(message), str(err.value)


def test_an_install_whose_command_list_names_what_the_code_no_longer_has_says_so_in_one_line(tmp_path):
    # As after pulling new code into a checkout installed before: the installed metadata's entry points name a
    # function where this code declares a record (colorgrid.extras.Commands), or a name the code no longer has.
    root = Path(__file__).resolve().parents[1]
    for value in ("server.cli:add_play_command", "server.plugin:NO_SUCH_RECORD"):
        info = tmp_path / value.replace(":", "_") / "colorgrid-0.1.0.dist-info"
        info.mkdir(parents=True)
        (info / "METADATA").write_text("Metadata-Version: 2.1\nName: colorgrid\nVersion: 0.1.0\n")
        (info / "entry_points.txt").write_text(f"[colorgrid.commands]\nplay = {value}\n")
        env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(info.parent), str(root)])}
        run = subprocess.run([sys.executable, "-m", "colorgrid_apps", "eval", "--help"], capture_output=True,
                             text=True, env=env, cwd=tmp_path)
        assert run.returncode == 2, run.stderr
        lines = run.stderr.strip().splitlines()
        assert len(lines) == 1 and f"play = {value} does not match this code" in lines[0], run.stderr
