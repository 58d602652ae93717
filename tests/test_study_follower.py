"""A study in the follower seat (``studies/human_follower.toml``): a participant in chromium plays the assistant
beside the study's AI leaders, states beliefs and answers probes; the export carries the stated beliefs and the probe
answers with their declared types."""

import re
import subprocess
import sys
import tomllib

import pandas as pd
import pyarrow.parquet as pq
import pytest
from playwright.sync_api import expect

from colorgrid.replay import load, verify
from server.study.config import StudyError, load_study
from server.study.columns import check_arrow, check_frame, read_csv
from server.study.schema import export_schema
from tests.conftest import ROOT, start_server, stop_server
from tests.documented import documented_code
from tests.test_study import TOKEN, toml

EXAMPLE = ROOT / "studies" / "human_follower.toml"
HORIZON = 5


def fast_study(tmp) -> tuple:
    """The example with games of 5 turn-based steps, probes at steps 2 and 4 (and a practice of 5), and a trial
    excluded for any time away from the page (``away_s = 0``)."""
    data = tomllib.loads(EXAMPLE.read_text())
    data["defaults"]["horizon"] = HORIZON
    data["exclusions"]["away_s"] = 0
    data["factors"]["probes"] = ["none", "steps:2,4"]
    for page in data["pages"]:
        if page["kind"] == "practice":
            page["game"].update(horizon=HORIZON, probes="steps:2")
    path = tmp / "human_follower.toml"
    path.write_text(toml(data))
    return path, data


def test_the_example_study_loads_with_the_seat_the_leaders_and_the_probes_as_factors():
    study = load_study(EXAMPLE)
    assert len(study.conditions) == 4 and {c.seat for c in study.conditions} == {"follower"}
    assert study.leaders == {"astar", "person:slip=0.1,notice_delay=3"}
    assert {c.probes for c in study.conditions} == {"none", "steps:15,35,55,75"}
    practice = study.practice_game(next(p for p in study.pages if p.kind == "practice"))
    assert practice.goal == "shown" and practice.seat == "follower"


@pytest.mark.parametrize("change, words", [
    (lambda d: d["factors"].update(leader=["astar", "bayes"]),
     "factors.leader: level 'bayes' is invalid: a scripted leader (astar, idle, person, random)"),
    (lambda d: d["factors"].update(probes=["none", "steps:0"]),
     "factors.probes: level 'steps:0' is invalid: 'none', 'steps:T1,T2,...'"),
    (lambda d: d["defaults"].update(seat="judge"), "defaults.seat='judge' is invalid: 'leader' or 'follower'"),
    (lambda d: d["defaults"].update(goal="blurred"), "defaults.goal='blurred' is invalid: 'hidden' or 'shown'"),
])
def test_a_wrong_follower_seat_in_a_study_file_is_one_line_and_exit_code_2(change, words, tmp_path):
    data = tomllib.loads(EXAMPLE.read_text())
    change(data)
    path = tmp_path / "study.toml"
    path.write_text(toml(data))
    with pytest.raises(StudyError, match="is invalid"):
        load_study(path)
    done = subprocess.run([sys.executable, "-m", "colorgrid_apps", "study", "run", str(path), "--port", "0"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and done.stdout == "" and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert words in done.stderr


def play_game(page, goal: str, away: bool = False) -> int:
    """One study game in the follower seat: say green, move, answer each probe (blue, 70%); the goal row says
    ``goal``; ``away``: the window loses its focus and gets it back first. Returns the probes answered."""
    board = page.locator("#board")
    page.click("#play")
    expect(board).to_be_visible()
    expect(page.locator("#stated-panel")).to_be_visible()
    expect(page.locator("#goal-name")).to_have_text(re.compile(goal))
    if away:
        page.evaluate("window.dispatchEvent(new Event('blur')); window.dispatchEvent(new Event('focus'))")
    board.focus()
    page.keyboard.press("2")
    asked = 0
    for t in range(HORIZON):
        expect(board).to_have_attribute("data-step", str(t))
        if page.locator("#probe").is_visible():
            asked += 1
            page.click(".probe-color[data-color='2']")
            page.locator("#probe-confidence").evaluate("r => { r.value = 70; }")
            page.click("#probe-answer")
            expect(page.locator("#probe")).to_be_hidden()
            board.focus()
        page.keyboard.press("ArrowUp" if t % 2 else "ArrowLeft")
    return asked


def test_a_participant_plays_the_assistant_in_chromium_and_the_export_has_beliefs_and_probes(browser, tmp_path):
    path, _ = fast_study(tmp_path)
    server = start_server(tmp_path, command=("study", "run", str(path)), env={"COLORGRID_ADMIN_TOKEN": TOKEN})
    try:
        context = browser.new_context(viewport={"width": 1200, "height": 950})
        page = context.new_page()
        errors = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(f"{server.url}/study?PROLIFIC_PID=assist-1&STUDY_ID=st&SESSION_ID=se")
        expect(page.locator("#page-title")).to_have_text("Consent")
        page.click("#next")
        expect(page.locator("#page-title")).to_have_text("How to play")
        expect(page.locator("#legend [data-who=you]")).to_contain_text("You")
        expect(page.locator("#legend [data-who=partner]")).to_contain_text("The AI leader (it knows the goal)")
        expect(page.locator("#board-picture")).to_be_hidden()  # the picture is the leader's seat's
        # the comprehension checks: one answered wrong, the instructions shown again, then both right
        page.locator("fieldset[data-id=your_disc] input[value='the dark disc marked L']").check()
        page.locator("fieldset[data-id=what_to_say] input[value='which color I believe is the goal']").check()
        page.click("#next")
        expect(page.locator("#check-note")).to_contain_text("please read the instructions again")
        expect(page.locator("#page-title")).to_have_text("How to play")
        page.locator("fieldset[data-id=your_disc] input[value='the yellow disc marked F']").check()
        page.click("#next")
        expect(page.locator("#page-title")).to_have_text("Practice game")
        assert play_game(page, "^(red|green|blue)$") == 1  # the practice shows the goal: a control
        expect(page.locator("#next")).to_be_visible()
        page.click("#next")
        for trial in range(4):
            expect(page.locator("#page-title")).to_have_text(f"Game {trial + 1} of 4")
            assert play_game(page, "^hidden from you$", away=trial == 0) in (0, 2)
            expect(page.locator("#next")).to_be_visible()
            page.click("#next")
            page.locator("fieldset[data-id=sure] input[value='5']").check()
            page.locator("fieldset[data-id=readable] input[value='4']").check()
            page.click("#next")
        expect(page.locator("#page-title")).to_have_text("A few last questions")
        page.locator("fieldset[data-id=cue] input[value=\"the leader's path\"]").check()
        page.click("#next")
        expect(page.locator("#completion-code")).to_have_text("CGHF41")
        assert errors == []
        context.close()
    finally:
        stop_server(server)

    out = tmp_path / "export"
    done = subprocess.run([sys.executable, "-m", "colorgrid_apps", "study", "export", str(path), "--replays-dir",
                           str(server.replays_dir), "--out", str(out)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    study = load_study(path)
    declared = export_schema(study)
    tables = {}
    for name in ("trials", "steps", "keys", "probes", "statements", "exclusions", "focus", "answers"):
        parquet, csv = pd.read_parquet(out / f"{name}.parquet"), read_csv(out, name)
        assert check_frame(parquet, declared[name]) == [] and check_frame(csv, declared[name]) == [], name
        assert check_arrow(pq.read_table(out / f"{name}.parquet").schema, declared[name]) == [], name
        pd.testing.assert_frame_equal(csv, parquet)
        tables[name] = parquet
    trials, steps, probes = tables["trials"], tables["steps"], tables["probes"]
    assert len(trials) == 5 and set(trials.condition_seat) == {"follower"}
    assert set(trials[trials.kind == "trial"].condition_leader) == {"astar", "person:slip=0.1,notice_delay=3"}
    assert trials.stated_steps.dtype == "Int64" and (trials.stated_steps == HORIZON).all()
    assert trials.stated_accuracy.dtype == "float64" and trials.stated_accuracy.notna().all()
    assert trials.probes_asked.dtype == "Int64" and (trials[trials.condition_probes == "none"].probes_asked == 0).all()
    assert (trials[trials.condition_probes == "steps:2,4"].probes_answered == 2).all()
    assert steps.stated_belief.dtype == "Int64" and set(steps.stated_belief.dropna()) <= {1, 2}
    assert (steps[steps.t == 0].stated_belief == 1).all()  # "2" (green) before the first move
    assert len(probes) == 2 * 2 + 1 and (probes.status == "answered").all()
    assert probes.color.dtype == "Int64" and (probes.color == 2).all() and (probes.confidence == 0.7).all()
    assert str(probes.trigger.dtype) == "category" and probes.correct.dtype == "boolean"
    assert (probes.response_ms >= 0).all() and probes.log_loss.notna().all() and probes.brier.notna().all()
    assert probes.correct.tolist() == (probes.goal == 2).tolist()
    statements = tables["statements"]
    assert set(statements.via) == {"key", "probe"} and statements.color.dtype == "int64"
    assert (tables["keys"][tables["keys"].status == "stated"].color == 1).all()
    # the trial the window left is excluded, with the time away the server recorded; no other rule is broken
    exclusions, focus = tables["exclusions"], tables["focus"]
    first = trials[trials.trial_index == 0].game_id.item()
    away = exclusions.set_index("game_id").loc[first]
    assert away.rule == "away" and away.threshold == 0 and away.trial_index == 0
    assert away.value == pytest.approx(trials.set_index("game_id").loc[first, "away_s"]) and away.value > 0
    assert set(exclusions.rule) == {"away"}  # the checks were passed on a second try: no participant excluded
    blurred = focus[(focus.trial_index == 0) & (focus.event == "blur")]
    assert len(blurred) >= 1 and set(exclusions.trial_index) <= set(focus.trial_index.dropna())
    checks = tables["answers"][tables["answers"].question_kind == "check"]
    assert len(checks) == 2 and checks.correct.all()
    for replay_id in trials.replay_id:
        assert verify(load(server.replays_dir / f"{replay_id}.replay.json")).ok
    # the analysis of docs/STUDIES.md, as it stands there, on this export (games a test played, not people)
    (code,) = documented_code("docs/STUDIES.md", "tests/test_study_follower.py")
    code = code.replace("study_data", str(out)).replace("recordings/human_follower", str(server.replays_dir))
    namespace = {}
    exec(code, namespace)
    per_game = namespace["per_game"]
    assert len(per_game) == 3 * 3 and set(per_game.who) == {"person", "bayes-people", "ippo"}  # one trial excluded
    assert first not in set(trials[trials.replay_id.isin(per_game.replay_id)].game_id)
    assert set(per_game.condition_leader) == {"astar", "person:slip=0.1,notice_delay=3"}
    mine = per_game[per_game.who == "person"].set_index("replay_id").accuracy.to_dict()
    kept = trials[(trials.kind == "trial") & (trials.game_id != first)]
    exported = kept.set_index("replay_id").stated_accuracy.to_dict()
    assert mine == pytest.approx(exported)  # the export's trials columns are the same computation
