"""A real browser (Debian chromium, driven by playwright) plays a short game and finds its replay."""

import re
from urllib.parse import quote

from playwright.sync_api import expect

from colorgrid.config import COLOR_NAMES
from colorgrid.enums import Ending
from server.messages import ENDING_WORDS, ROOM_ERROR_WORDS, SEAT_WORDS
from server.protocol import ROOM_CODE_LENGTH, RoomErrorCode, RoomSeatStatus
from tests.helpers import js_fixed, js_round


BAR_COLORS = "els => els.map(e => getComputedStyle(e).backgroundColor)"


def pixel(page, x: int, y: int, canvas: str = "#board") -> str:
    """The ``#rrggbb`` color of one canvas pixel."""
    return page.locator(canvas).evaluate(
        f"c => '#' + [...c.getContext('2d').getImageData({x}, {y}, 1, 1).data.slice(0, 3)]"
        ".map(v => v.toString(16).padStart(2, '0')).join('')")


def css_rgb(hex_color: str) -> str:
    """``#rrggbb`` as the browser's computed style writes it."""
    return "rgb({}, {}, {})".format(*(int(hex_color[i:i + 2], 16) for i in (1, 3, 5)))


def test_play_a_short_game_in_the_browser(server, browser):
    page = browser.new_page()
    errors = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(server.url + "/")
    options = server.get("/api/options")[0]
    solo = next(t for t in options["teams"] if t["value"] == "1:1")["followers"]  # the team shown first
    expect(page.locator("#follower option")).to_have_count(len(solo))
    assert len(solo) < len(options["followers"])  # the team followers are offered in their own teams only
    expect(page.locator("#follower")).to_have_value(options["default_follower"])
    # the setup form is the server's: its modes, the horizon's limits, the chosen preset's rewards, the letters
    assert page.locator("#mode option").all_text_contents() == [m["label"] for m in options["modes"]]
    expect(page.locator("#horizon")).to_have_attribute("max", str(options["horizon"]["max"]))
    expect(page.locator("#horizon")).to_have_attribute("placeholder", str(options["horizon"]["default"]))
    expect(page.locator("#goal-reward")).to_have_text("+1")
    expect(page.locator("#wrong-penalty")).to_have_text("\u22121")
    page.select_option("#preset", "reward_4_1")
    expect(page.locator("#goal-reward")).to_have_text("+4")
    page.select_option("#preset", "default")
    assert page.locator("#who-is-who [data-symbol]").all_text_contents() == ["L", "F"]
    assert page.locator("#who-assists [data-symbol]").all_text_contents() == ["F", "L"]  # the follower seat's words
    page.select_option("#mode", "turn")
    page.fill("#horizon", "6")
    page.click("#start")
    expect(page.locator("#game")).to_be_visible()
    board = page.locator("#board")
    expect(board).to_have_attribute("data-step", "0")
    expect(page.locator("#step")).to_have_text("0 / 6")
    palette = options["look"]["palette"]
    goal = COLOR_NAMES.index(page.locator("#goal-name").text_content())
    assert pixel(page, 1, 1) == palette[goal], "the frame around the board is the goal color, in the server's palette"
    expect(page.locator("#goal-swatch")).to_have_css("background-color", css_rgb(palette[goal]))
    for t in range(6):
        before = int(board.get_attribute("data-leader"))
        follower = int(board.get_attribute("data-follower"))
        key, target = ("ArrowRight", before + 1) if before % 32 < 31 else ("ArrowLeft", before - 1)
        page.keyboard.press(key)
        if t < 5:
            expect(board).to_have_attribute("data-step", str(t + 1))
            expect(page.locator("#step")).to_have_text(f"{t + 1} / 6")
            after = int(board.get_attribute("data-leader"))
            assert after == (before if target == follower else target), "the leader moved, unless blocked"
            expect(page.locator(".belief-row")).to_have_count(3)
            widths = page.locator(".belief-fill").evaluate_all("els => els.map(e => parseFloat(e.style.width))")
            assert abs(sum(widths) - 100) < 1.0, "belief bars add up to 100%"
            fills = page.locator(".belief-fill").evaluate_all(BAR_COLORS)
            assert fills == [css_rgb(c) for c in palette[:3]], "bar k is drawn in the server's color k"
    expect(page.locator("#over")).to_be_visible()
    expect(page.locator("#over-scores")).to_contain_text("after 6 steps")
    link = page.locator("#replay-link")
    href = link.get_attribute("href")
    replay_id = href.split("id=")[1]
    link.click()
    expect(page.locator("#player")).to_be_visible(timeout=60_000)  # the game just played; its timeline is made by
    # a low-priority worker, which a busy machine serves last
    expect(page.locator("#step")).to_have_text("0 / 6")
    expect(page.locator("#keylog tbody tr")).to_have_count(6)
    expect(page.locator("#keylog tbody tr").first.locator("td").nth(3)).to_have_text("applied")
    reactions = page.locator("#keylog tbody tr td:nth-child(5)").all_text_contents()
    assert all(float(r) >= 0 for r in reactions), reactions  # from the state being sent to the key arriving
    page.goto(server.url + f"/replays?id={replay_id}")
    row = page.locator(f"tr[data-id='{replay_id}']")
    page.select_option("#source", "play")
    expect(row).to_be_visible()
    expect(row).to_have_class("highlight")
    expect(row.locator("td").nth(1)).to_have_text("play")
    assert (server.replays_dir / f"{replay_id}.replay.json").exists()
    assert errors == []
    page.close()


def test_belief_can_be_hidden(server, browser):
    page = browser.new_page()
    page.goto(server.url + "/")
    page.fill("#horizon", "3")
    page.click("#start")
    expect(page.locator("#game")).to_be_visible()
    page.keyboard.press("ArrowUp")
    expect(page.locator(".belief-row")).to_have_count(3)
    page.uncheck("#belief-toggle")
    expect(page.locator(".belief-row")).to_have_count(0)
    page.keyboard.press("ArrowDown")
    expect(page.locator("#board")).to_have_attribute("data-step", "2")
    expect(page.locator(".belief-row")).to_have_count(0)
    page.click("#quit")
    expect(page.locator("#over")).to_be_visible()
    page.close()


def board_pixels(page) -> str:
    return page.locator("#board").evaluate("c => c.toDataURL()")


def test_replay_list_shows_the_latest_filters_answer_when_an_older_one_comes_back_last(server, browser):
    """A filter changed while the list's earlier request is still out: the earlier answer, held back on its way to
    the page until the new one is shown, must not replace it (the real server answers both)."""
    page = browser.new_page()
    held, asked = [], []
    # every answer to the list's requests, counted once the page's script has read it (web/replays.js awaits
    # response.json(), then shows the list or drops an answer to an older filter, in the same turn of its loop)
    page.add_init_script("""
        window.__listAnswers = 0;
        const json = Response.prototype.json;
        Response.prototype.json = function () {
            return json.call(this).then((data) => {
                if (this.url.includes("/api/replays?")) window.__listAnswers += 1;
                return data;
            });
        };""")

    def hold_unfiltered(route):
        asked.append(route.request.url)
        if "setting=" in route.request.url:
            route.continue_()
        else:  # every request before the setting is chosen reaches the page last
            held.append(route)

    page.route("**/api/replays?*", hold_unfiltered)
    page.goto(server.url + "/replays")
    page.select_option("#collection", "released")
    page.select_option("#setting", "default")
    expect(page.locator("#list tbody tr")).to_have_count(6)
    assert len(held) >= 2  # the first load and the collection's
    for route in held:
        route.continue_()
    page.wait_for_function(f"() => window.__listAnswers === {len(asked)}")  # the held answers reached the script
    expect(page.locator("#list tbody tr")).to_have_count(6)
    assert set(page.locator("#list tbody tr td:nth-child(3)").all_text_contents()) == {"default"}
    page.close()


def test_replay_player_scrubs_plays_links_and_downloads(server, browser, tmp_path):
    page = browser.new_page(accept_downloads=True)
    errors = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(server.url + "/replays")
    page.select_option("#collection", "released")
    page.select_option("#setting", "default")
    expect(page.locator("#list tbody tr")).to_have_count(6)
    page.fill("#follower", "bayes")
    expect(page.locator("#list tbody tr")).to_have_count(2)
    assert page.locator("#list tbody tr td:nth-child(6)").all_text_contents() == ["bayes", "bayes"]
    first = page.locator("#list tbody tr a.open").first
    replay_id = first.text_content()
    first.click()
    expect(page.locator("#player")).to_be_visible(timeout=60_000)  # the timeline is made by a low-priority worker
    assert page.locator("body").get_attribute("data-verified") == "true"
    timeline = server.get(f"/api/replays/{replay_id}/timeline")[0]
    board, chart = page.locator("#board"), page.locator("#chart")
    expect(board).to_have_attribute("data-step", "0")
    before, cursor_before = board_pixels(page), float(chart.get_attribute("data-cursor-x"))
    page.locator("#scrub").evaluate("el => { el.value = 40; el.dispatchEvent(new Event('input')); }")
    expect(board).to_have_attribute("data-step", "40")
    expect(chart).to_have_attribute("data-cursor", "40")
    assert float(chart.get_attribute("data-cursor-x")) > cursor_before
    assert board_pixels(page) != before
    assert int(board.get_attribute("data-leader")) == timeline["boards"][40]["leader"]
    assert int(board.get_attribute("data-follower")) == timeline["boards"][40]["follower"]
    expect(page.locator("#step")).to_have_text(f"40 / {timeline['steps']}")
    page.keyboard.press("ArrowRight")
    expect(board).to_have_attribute("data-step", "41")
    page.keyboard.press("ArrowLeft")
    page.keyboard.press("ArrowLeft")
    expect(board).to_have_attribute("data-step", "39")
    expect(page.locator(".belief-row")).to_have_count(3)
    # the belief bars show the recorded probabilities of this step
    shown = page.locator(".belief-value").all_text_contents()
    assert shown == [js_fixed(p, 2) for p in timeline["goal_probs"]["follower"][39]]
    # trails draw over the same board
    plain = board_pixels(page)
    page.check("#trails")
    assert board_pixels(page) != plain
    # play at 8x and pause
    page.select_option("#speed", "8")
    page.keyboard.press(" ")
    page.wait_for_function("() => Number(document.getElementById('board').dataset.step) >= 50")
    page.keyboard.press(" ")
    expect(page.locator("#play")).to_have_text("play")  # paused
    stopped = int(board.get_attribute("data-step"))
    # twenty frames drawn later (at 8x a step is drawn every 16 ms) the board still shows the step it stopped at
    shown = page.evaluate("""() => new Promise((done) => {
        let frames = 0;
        const frame = () => (++frames < 20 ? requestAnimationFrame(frame)
                                            : done(Number(document.getElementById("board").dataset.step)));
        requestAnimationFrame(frame);
    })""")
    assert shown == stopped
    # clicking the chart jumps there
    box = chart.bounding_box()
    chart.click(position={"x": box["width"] - 9, "y": box["height"] / 2})
    expect(board).to_have_attribute("data-step", str(timeline["steps"]))
    # the step link reopens the replay at that step
    page.locator("#scrub").evaluate("el => { el.value = 17; el.dispatchEvent(new Event('input')); }")
    href = page.locator("#step-link").get_attribute("href")
    assert href.endswith("step=17")
    page.goto(server.url + href)
    expect(page.locator("#board")).to_have_attribute("data-step", "17")
    expect(page.locator("#chart")).to_have_attribute("data-cursor", "17")
    # download the GIF made on the server and read it back
    with page.expect_download() as info:
        page.click("#gif")
    path = tmp_path / "replay.gif"
    info.value.save_as(path)
    import imageio.v3 as iio

    frames = iio.imread(path, index=None)
    assert frames.ndim == 4 and frames.shape[0] >= timeline["steps"] and frames.shape[-1] in (3, 4)
    assert errors == []
    page.close()


def test_a_replay_that_fails_verification_is_shown_as_such(server, browser):
    import glob

    from colorgrid.replay import load, save

    replay = load(sorted(glob.glob("replays/default/*.replay.json"))[0])
    replay.actions[5] = [(replay.actions[5][0] + 1) % 4, replay.actions[5][1]]  # a valid file, a different game
    save(replay, server.replays_dir / "tampered.replay.json")
    (server.replays_dir / "garbled.replay.json").write_text('{"format": "colorgrid-replay", "ver')
    page = browser.new_page()
    for replay_id, message in (("tampered", "state hash mismatch"), ("garbled", "not valid JSON")):
        page.goto(server.url + f"/replay?id={replay_id}")
        expect(page.locator("#status")).to_contain_text("failed verification")
        expect(page.locator("#status")).to_contain_text(message)
        expect(page.locator("#player")).to_be_hidden()
        assert page.locator("body").get_attribute("data-verified") == "false"
    page.goto(server.url + "/replays?id=garbled")
    page.select_option("#collection", "recorded")
    expect(page.locator("tr[data-id='garbled'] td").nth(8)).to_contain_text("invalid")
    page.close()


def test_the_replay_player_draws_in_the_colors_its_timeline_sends(server, browser):
    """The timeline's ``look`` is swapped for colors no page could know: the board, the bars and the goal
    swatch come out in those."""
    listed = server.get("/api/replays?collection=released&setting=default&follower=bayes&limit=1")[0]
    replay_id = listed["items"][0]["id"]
    timeline = server.get(f"/api/replays/{replay_id}/timeline")[0]
    swapped = ["#010203", "#405060", "#708090"]

    def recolor(route):
        response = route.fetch()
        data = response.json()
        data["look"]["palette"] = swapped
        route.fulfill(response=response, json=data)

    page = browser.new_page()
    errors = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.route("**/timeline", recolor)
    page.goto(server.url + f"/replay?id={quote(replay_id)}")
    expect(page.locator("#board")).to_have_attribute("data-step", "0")
    first = timeline["boards"][0]
    assert pixel(page, 1, 1) == swapped[first["goal"]]
    cell = next(i for i, ch in enumerate(first["blocks"]) if ch != ".")
    r, c = divmod(cell, timeline["width"])
    size = (520 - 8) // timeline["width"]
    assert pixel(page, 4 + c * size + size // 2, 4 + r * size + size // 2) == swapped[int(first["blocks"][cell])]
    fills = page.locator(".belief-fill").evaluate_all(BAR_COLORS)
    assert fills == [css_rgb(c) for c in swapped]
    expect(page.locator("#goal-swatch")).to_have_css("background-color", css_rgb(swapped[first["goal"]]))
    assert errors == []
    page.close()


def test_an_id_with_a_plus_typed_into_the_address_bar_opens_its_replay(server, browser):
    page = browser.new_page()
    page.goto(server.url + "/replay?id=released--default--astar+bayes_seed2026&step=3")  # "+" as typed, not %2B
    expect(page.locator("#player")).to_be_visible(timeout=60_000)  # the timeline is made by a low-priority worker
    assert page.locator("body").get_attribute("data-verified") == "true"
    expect(page.locator("#step")).to_contain_text("3")
    page.close()


def test_the_replay_list_finds_followers_by_part_of_their_name(server):
    every = server.get("/api/replays?limit=500")[0]["items"]
    found = server.get("/api/replays?follower=AYE&limit=500")[0]["items"]  # part of "bayes", any case
    assert found and {i["id"] for i in found} == {i["id"] for i in every if "aye" in str(i.get("follower")).lower()}


def test_branch_here_draws_the_branch_beside_the_replay_on_one_cursor(server, browser):
    replay_id = "released--default--astar+bayes_seed2026"
    page = browser.new_page()
    errors = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(server.url + f"/replay?id={quote(replay_id)}&step=20")
    board = page.locator("#board")
    expect(board).to_have_attribute("data-step", "20", timeout=60_000)  # timelines come from a low-priority worker
    options = server.get("/api/options")[0]
    # the page fills the list from its own /api/options request, which may answer after the board's step: wait for it
    expect(page.locator("#branch-follower option")).to_have_text(options["followers"])
    expect(page.locator("#branch-panel")).to_be_hidden()
    page.select_option("#branch-follower", "copy")
    page.click("#branch-here")
    panel, branch_board = page.locator("#branch-panel"), page.locator("#branch-board")
    expect(panel).to_be_visible(timeout=120_000)
    expect(panel).to_have_attribute("data-id", f"branches--{replay_id}--branch20-copy")
    expect(page.locator("#branch-title")).to_contain_text("copy")
    expect(page.locator("#branch-title")).to_contain_text("20")
    expect(branch_board).to_have_attribute("data-step", "20")
    expect(page.locator("#branch-chart")).to_have_attribute("data-cursor", "20")
    assert branch_board.evaluate("c => c.toDataURL()") == board_pixels(page), "step 20 is the same state"
    diff = page.locator("#branch-diff")
    expect(diff).to_contain_text("at step 20")
    expect(diff).to_contain_text("at the end")
    assert float(diff.get_attribute("data-now")) == 0, "nothing differs yet at the branch step"
    # one cursor: scrubbing, stepping and the chart move both
    page.locator("#scrub").evaluate("el => { el.value = 60; el.dispatchEvent(new Event('input')); }")
    expect(board).to_have_attribute("data-step", "60")
    expect(branch_board).to_have_attribute("data-step", "60")
    expect(page.locator("#branch-chart")).to_have_attribute("data-cursor", "60")
    expect(page.locator("#branch-step")).to_have_text(page.locator("#step").text_content())
    expect(diff).to_contain_text("at step 60")
    page.keyboard.press("ArrowRight")
    expect(board).to_have_attribute("data-step", "61")
    expect(branch_board).to_have_attribute("data-step", "61")
    assert page.locator("#branch-step").text_content() == page.locator("#step").text_content()
    timeline = server.get(f"/api/replays/{quote(replay_id)}/timeline")[0]
    branch = server.get(f"/api/replays/{quote(panel.get_attribute('data-id'))}/timeline")[0]
    team = lambda b: sum(b["scores"])  # noqa: E731
    assert float(diff.get_attribute("data-now")) == team(branch["boards"][61]) - team(timeline["boards"][61])
    assert float(diff.get_attribute("data-end")) == team(branch["boards"][-1]) - team(timeline["boards"][-1])
    # the address keeps the branch: a reload shows it again; closing hides it
    assert "branch=" in page.url
    page.reload()
    expect(page.locator("#branch-panel")).to_be_visible(timeout=60_000)
    expect(page.locator("#branch-board")).to_have_attribute("data-step", "61")
    page.click("#branch-close")
    expect(page.locator("#branch-panel")).to_be_hidden()
    assert "branch=" not in page.url
    page.keyboard.press("ArrowRight")
    expect(board).to_have_attribute("data-step", "62")
    # a follower the server does not offer is refused with its reason
    page.locator("#branch-follower").evaluate("s => s.add(new Option('tests/x.pt', 'tests/x.pt'))")
    page.select_option("#branch-follower", "tests/x.pt")
    page.click("#branch-here")
    expect(page.locator("#branch-status")).to_contain_text("follower must be one of")
    expect(page.locator("#branch-panel")).to_be_hidden()
    assert errors == []
    page.close()


def test_a_newcomer_reads_how_to_play_and_what_each_follower_does_before_starting(server, browser):
    page = browser.new_page()
    page.goto(server.url + "/")
    options = server.get("/api/options")[0]
    how_to = page.locator("#how-to")
    expect(how_to).to_be_visible()
    expect(how_to).to_contain_text("↑ or W, ↓ or S, ← or A, → or D")  # from /api/options' keys
    expect(how_to).to_contain_text("frame around the board")
    expect(how_to).to_contain_text("goal color")
    page.select_option("#preset", "reward_4_1")  # the chosen preset's numbers
    expect(how_to.locator("#goal-reward")).to_have_text("+4")
    expect(how_to.locator("#wrong-penalty")).to_have_text("\u22121")
    page.select_option("#mode", "realtime")
    expect(page.locator("#mode-help")).to_contain_text("countdown")
    info = {f["value"]: f for f in options["follower_info"]}
    solo = next(t for t in options["teams"] if t["value"] == "1:1")["followers"]
    assert page.locator("#follower option").all_text_contents() == [info[name]["label"] for name in solo]
    expect(page.locator("#follower-description")).to_have_text(info[options["default_follower"]]["description"])
    page.select_option("#follower", "oracle")
    expect(page.locator("#follower-description")).to_have_text(info["oracle"]["description"])
    expect(page.locator("#follower option[value='oracle']")).to_have_attribute("title", info["oracle"]["description"])
    page.close()


def test_end_game_goes_once_the_game_is_over_and_the_belief_toggle_only_for_followers_with_one(server, browser):
    page = browser.new_page()
    page.goto(server.url + "/")
    page.select_option("#follower", "copy")  # no belief to show
    page.select_option("#mode", "turn")
    page.fill("#horizon", "2")
    page.click("#start")
    expect(page.locator("#game")).to_be_visible()
    expect(page.locator("#follower-label")).to_have_text("Copycat")
    expect(page.locator("#belief-toggle")).to_be_hidden()
    expect(page.locator("#quit")).to_be_visible()
    page.keyboard.press("ArrowUp")
    expect(page.locator("#board")).to_have_attribute("data-step", "1")
    page.keyboard.press("ArrowDown")
    expect(page.locator("#over")).to_be_visible()
    expect(page.locator("#quit")).to_be_hidden()
    expect(page.locator("#status")).to_have_text("Game over.")
    page.click("#again")
    page.select_option("#follower", "bayes")
    page.click("#start")
    expect(page.locator("#board")).to_have_attribute("data-step", "0")
    expect(page.locator("#belief-toggle")).to_be_visible()
    expect(page.locator("#quit")).to_be_visible()
    page.click("#quit")
    expect(page.locator("#quit")).to_be_hidden()
    expect(page.locator("#status")).to_have_text("You ended the game.")
    page.close()


def test_a_bad_number_of_steps_is_explained_in_plain_words(server, browser):
    page = browser.new_page()
    page.goto(server.url + "/")
    page.select_option("#mode", "turn")
    page.fill("#horizon", "5000")
    page.click("#start")
    expect(page.locator("#status")).to_have_text("Steps must be between 1 and 1000.")
    expect(page.locator("#setup")).to_be_visible()
    # the server's own refusal (a page whose limit is out of date) reads the same; its words stay in the title
    page.locator("#horizon").evaluate("el => el.removeAttribute('max')")
    page.click("#start")
    expect(page.locator("#status")).to_have_attribute("title", re.compile(r"^invalid_message: new_game: horizon"))
    expect(page.locator("#status")).to_have_text("Steps must be between 1 and 1000.")
    expect(page.locator("#setup")).to_be_visible()
    expect(page.locator("#game")).to_be_hidden()
    page.close()


def test_real_time_starts_after_a_3_2_1_countdown(server, browser):
    page = browser.new_page()
    page.goto(server.url + "/")
    page.select_option("#follower", "copy")
    page.select_option("#mode", "realtime")
    page.fill("#horizon", "200")
    before = server.get("/api/health")[0]["games"]  # games other pages of this server left going, if any
    page.click("#start")
    countdown = page.locator("#countdown")
    expect(countdown).to_have_text("3")
    expect(page.locator("#setup")).to_be_hidden()
    page.keyboard.press("ArrowUp")  # keys before "go" count for nothing
    expect(countdown).to_have_text("2")
    assert server.get("/api/health")[0]["games"] == before, "no world moves during the countdown"
    expect(countdown).to_have_text("1")
    expect(page.locator("#game")).to_be_hidden()
    expect(countdown).to_have_text("go")
    expect(page.locator("#game")).to_be_visible()
    expect(countdown).to_be_hidden()
    board = page.locator("#board")
    expect(board).not_to_have_attribute("data-step", "0")  # now the world moves on the server's clock
    page.click("#quit")
    expect(page.locator("#over")).to_be_visible()
    page.close()


def test_the_api_docs_render_without_internet(server, browser):
    page = browser.new_page()
    outside = []

    def local_only(route):
        if route.request.url.startswith(server.url):
            route.continue_()
        else:
            outside.append(route.request.url)
            route.abort()

    page.route("**/*", local_only)
    page.goto(server.url + "/docs")
    expect(page.locator(".swagger-ui .info .title")).to_contain_text("ColorGrid play server")
    expect(page.locator(".opblock-summary-path", has_text="/api/options")).to_be_visible()
    page.goto(server.url + "/redoc")
    expect(page.locator("h1", has_text="ColorGrid play server")).to_be_visible()
    expect(page.get_by_text("API docs by Redocly")).to_be_visible()  # its footer drew a logo from a CDN
    page.wait_for_load_state("networkidle")
    assert outside == []
    page.close()


RING = "#ffb000"  # the ring around this person's disc (web/room.js markYou, .you-badge in web/style.css)


def ringed(page, cell_index: int, width: int = 32) -> bool:
    """Whether the disc in ``cell_index`` has the "you" ring (a pixel just outside the disc)."""
    size = (520 - 8) // width
    r, c = divmod(cell_index, width)
    return pixel(page, 4 + c * size + size // 2 + size // 2 + 1, 4 + r * size + size // 2) == RING


def rows_apart(page) -> bool:
    """No agent's words run into its score: each row's two parts side by side, apart."""
    return page.locator("#agent-scores .row").evaluate_all("""rows => rows.every(row => {
        const [who, score] = [...row.children].map(e => e.getBoundingClientRect());
        return who.right <= score.left && who.top < score.bottom && score.top < who.bottom; })""")


def test_the_play_page_says_which_disc_is_yours_and_which_your_ai_partners(server, browser):
    page = browser.new_page()
    errors = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(server.url + "/")
    look = server.get("/api/options")[0]["look"]
    leader, follower = look["agents"]
    intro = page.locator("#who-is-who")
    expect(intro).to_contain_text("You are the disc L")
    expect(intro).to_contain_text("Your AI partner, the disc F")
    for agent in (leader, follower):  # the legend's discs in the board's colors
        badge = intro.locator(f"[data-symbol='{agent['name']}'] .agent-badge")
        expect(badge).to_have_css("background-color", css_rgb(agent["body"]))
        expect(badge).to_have_css("color", css_rgb(agent["ink"]))
    assert intro.locator(".you-badge").all_text_contents() == ["L"], "yours is ringed, as on the board"
    # no empty bullet in how to play (the team's line is for teams)
    assert all(t.strip() for t in page.locator("#how-to li:visible").all_text_contents())
    expect(page.locator("#team-help")).to_be_hidden()
    page.select_option("#team", "1:2")
    expect(page.locator("#team-help")).to_be_visible()
    page.select_option("#team", "1:1")
    page.select_option("#follower", "bayes-people")
    page.select_option("#mode", "turn")
    page.fill("#horizon", "4")
    page.click("#start")
    board = page.locator("#board")
    expect(board).to_have_attribute("data-step", "0")
    aside = page.locator("#game aside")
    width = aside.bounding_box()["width"]
    assert page.locator("#agent-scores .agent-badge").all_text_contents() == ["L", "F"]
    assert page.locator("#agent-scores .who").all_text_contents() == ["you", "your AI partner"]
    expect(page.locator("#you")).to_have_text("L")
    expect(page.locator("#you")).to_have_css("background-color", css_rgb(leader["body"]))
    expect(page.locator("#partner-note")).to_have_text("your AI partner: Bayesian assistant for people")
    expect(page.locator("#belief-whose")).to_have_text("your AI partner believes")
    assert rows_apart(page)
    assert not re.search(r"\b(leader|follower)\b", aside.inner_text()), "people are you and your AI partner"
    assert ringed(page, int(board.get_attribute("data-leader")))
    assert not ringed(page, int(board.get_attribute("data-follower")))
    for t, key in enumerate(["ArrowUp", "ArrowLeft", "ArrowDown"]):
        page.keyboard.press(key)
        expect(board).to_have_attribute("data-step", str(t + 1))
        assert aside.bounding_box()["width"] == width, "the panel keeps its width as its text changes"
        assert ringed(page, int(board.get_attribute("data-leader")))
    page.keyboard.press("ArrowRight")
    expect(page.locator("#over")).to_be_visible()
    expect(page.locator("#over-scores")).to_contain_text(re.compile(r"\(you [+-]?\d+, your AI partner [+-]?\d+\)"))
    assert aside.bounding_box()["width"] == width
    expect(page.locator("#status")).to_have_text("Game over.")
    page.click("#again")
    expect(page.locator("#status")).to_have_text("")  # the last game's end is not shown over the next
    page.click("#start")
    expect(board).to_have_attribute("data-step", "0")
    expect(page.locator("#events")).to_have_text("")
    expect(page.locator("#status")).not_to_contain_text("Game over")
    page.click("#quit")
    expect(page.locator("#over")).to_be_visible()
    assert errors == []
    page.close()


def test_in_a_room_each_person_is_you_in_their_own_seat_and_only_the_opener_shares_the_link(server, browser):
    contexts = [browser.new_context() for _ in range(2)]
    opener, guest = [c.new_page() for c in contexts]
    opener.goto(server.url + "/")
    opener.select_option("#team", "2:1")
    opener.select_option("#mode", "turn")
    opener.fill("#horizon", "5")
    opener.click("#start")
    expect(opener.locator("#room")).to_be_visible()
    expect(opener.locator("#share")).to_be_visible()
    expect(opener.locator("#status")).to_contain_text("send the link")
    guest.goto(server.url + "/")
    guest.fill("#join-code", opener.locator("#room-code").text_content())
    guest.click("#join")
    expect(guest.locator("#room")).to_be_visible()
    expect(guest.locator("#share")).to_be_hidden()
    expect(guest.locator("#joined")).to_be_visible()
    expect(guest.locator("#status")).not_to_contain_text("send the link")
    assert "Send this link" not in guest.locator("#room").inner_text()
    expect(opener.locator("#room-seats li")).to_have_count(2)
    expect(opener.locator("#share")).to_be_visible()  # still the opener's, once the guest is in
    for page in (opener, guest):
        page.click("#ready")
    for page, you, other in ((opener, "L1", "L2"), (guest, "L2", "L1")):
        expect(page.locator("#board")).to_have_attribute("data-step", "0")
        expect(page.locator("#you")).to_have_text(you)
        rows = page.locator("#agent-scores .row")
        expect(rows.filter(has_text=you)).to_contain_text("you")
        expect(rows.filter(has_text=other)).to_contain_text("the other person")
        expect(rows.filter(has_text="F1")).to_contain_text("your AI partner")
        assert rows_apart(page)
        board = page.locator("#board")
        seat = {"L1": "leader_0", "L2": "leader_1"}
        assert ringed(page, int(board.get_attribute(f"data-{seat[you]}")))
        assert not ringed(page, int(board.get_attribute(f"data-{seat[other]}")))
    guest.click("#quit")  # the guest leaves; a scripted leader plays on beside the opener
    expect(guest.locator("#status")).to_have_text(ENDING_WORDS[Ending.LEFT])  # the server's words for it
    opener.click("#quit")
    expect(opener.locator("#status")).to_have_text(ENDING_WORDS[Ending.QUIT])
    for context in contexts:
        context.close()


def test_the_page_says_room_errors_and_seats_in_the_servers_words(server, browser):
    """The room's words come from the server (``/api/options``' ``room_words``): the page holds none of its own."""
    page = browser.new_page()
    page.goto(server.url + "/?room=" + "A" * ROOM_CODE_LENGTH)  # a code no room has
    expect(page.locator("#status")).to_have_text(ROOM_ERROR_WORDS[RoomErrorCode.ROOM_NOT_FOUND])
    page.goto(server.url + "/?room=nope")
    expect(page.locator("#status")).to_have_text(ROOM_ERROR_WORDS[RoomErrorCode.BAD_ROOM_CODE])
    expect(page.locator("#setup")).to_be_visible()
    page.select_option("#team", "2:1")
    page.click("#start")
    seats = page.locator("#room-seats li")
    expect(seats).to_have_count(2)
    expect(seats.nth(1)).to_contain_text(SEAT_WORDS[RoomSeatStatus.OPEN])
    page.click("#leave-room")
    expect(page.locator("#setup")).to_be_visible()
    page.close()


def set_visibility(page, visible: bool) -> None:
    """The tab hidden or shown again, as the browser reports it to the page."""
    page.evaluate("""visible => {
        Object.defineProperty(document, "visibilityState", { value: visible ? "visible" : "hidden", configurable: true });
        Object.defineProperty(document, "hidden", { value: !visible, configurable: true });
        document.dispatchEvent(new Event("visibilitychange"));
    }""", visible)


def test_a_real_time_game_goes_on_through_the_tab_hidden_and_shown_again(server, browser):
    from colorgrid.replay import load

    page = browser.new_page()
    errors = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(server.url + "/")
    page.select_option("#follower", "copy")
    page.select_option("#mode", "realtime")
    page.fill("#horizon", "1000")  # 50 s at the test server's 20 steps/s: more than the test needs; it quits
    countdown, board = page.locator("#countdown"), page.locator("#board")
    page.evaluate("""() => {  // what the countdown shows, each time it changes, and whether the tab was hidden then
        const shown = document.getElementById("countdown");
        window.__countdown = [];
        new MutationObserver(() => window.__countdown.push([shown.textContent, document.hidden]))
            .observe(shown, { childList: true, characterData: true, subtree: true });
    }""")
    page.click("#start")
    expect(countdown).to_have_text("3")
    set_visibility(page, False)  # hidden during the countdown: it goes on
    page.wait_for_function("() => window.__countdown.some(([text, hidden]) => hidden && text !== '3')")
    set_visibility(page, True)
    expect(page.locator("#game")).to_be_visible()
    expect(board).not_to_have_attribute("data-step", "0")
    set_visibility(page, False)  # and during the game: the world goes on
    step = int(board.get_attribute("data-step"))
    page.wait_for_function(f"() => Number(document.getElementById('board').dataset.step) > {step + 5}")
    set_visibility(page, True)
    before = board.get_attribute("data-leader")
    for _ in range(10):  # a key, then two steps of the server's (its state after the key): a move may be blocked
        step = int(board.get_attribute("data-step"))
        page.keyboard.press("ArrowDown" if int(before) < 32 * 16 else "ArrowUp")
        page.wait_for_function(f"() => Number(document.getElementById('board').dataset.step) >= {step + 2}")
        if board.get_attribute("data-leader") != before:
            break
    assert board.get_attribute("data-leader") != before, "keys move the leader after the tab is back"
    page.click("#quit")
    expect(page.locator("#over")).to_be_visible()
    expect(page.locator("#status")).to_have_text(ENDING_WORDS[Ending.QUIT])
    expect(countdown).to_be_hidden()
    replay = load(server.replays_dir / f"{page.locator('#replay-link').get_attribute('href').split('id=')[1]}.replay.json")
    changes = [e["visible"] for e in replay.meta["page_events"] if e["event"] == "visibilitychange"]
    assert changes == [False, True], "the game's hiding and showing are recorded (the countdown's are before it)"
    assert any(e["status"] == "applied" for e in replay.key_events), "keys move the leader after the tab is back"
    assert errors == []
    page.close()


def test_the_replay_list_shows_a_branch_with_its_parent_and_step_and_filters_by_them(server, browser):
    from tests.test_server import post_json

    parent_id = "released--default--astar+bayes_seed2026"
    answer, status = post_json(server, f"/api/replays/{parent_id}/branch", {"step": 12, "follower": "copy"})
    assert status == 200
    page = browser.new_page()
    errors = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(server.url + f"/replays?branch_of={quote(parent_id)}")
    row = page.locator(f"tr[data-id='{answer['id']}']")
    expect(row).to_be_visible()
    expect(page.locator("#branch_of")).to_have_value(parent_id)
    cells = row.locator("td")
    expect(cells.nth(1)).to_have_text("branch")
    expect(cells.nth(3)).to_have_text(f"{parent_id} from step 12")
    expect(cells.nth(4)).to_have_text("astar (replayed)")
    # filters: a source of its own; the parent is no branch
    page.fill("#branch_of", "")
    page.select_option("#source", "branch")
    expect(row).to_be_visible()
    expect(page.locator(f"tr[data-id='{parent_id}']")).to_have_count(0)
    # waited on, not read at once: the list of the emptied branch_of filter (every source) may show first
    expect(page.locator("#list tbody tr td:nth-child(2)").filter(has_not_text="branch")).to_have_count(0)
    page.select_option("#source", "eval")
    expect(row).to_have_count(0)
    page.select_option("#source", "branch")
    # the parent's link opens the parent at the branch step; the branch's player says what it is
    row.locator("a.parent").click()
    expect(page.locator("#board")).to_have_attribute("data-step", "12", timeout=60_000)
    assert queryless(page.url) == f"{server.url}/replay"
    page.goto(server.url + f"/replay?id={quote(answer['id'])}")
    expect(page.locator("#facts")).to_contain_text("branch replay", timeout=60_000)
    expect(page.locator("#facts")).to_contain_text(f"a branch of {parent_id} from step 12: copy plays on")
    expect(page.locator("#parent-link")).to_have_attribute("href", f"/replay?id={quote(parent_id, safe='')}&step=12")
    assert errors == []
    page.close()


def queryless(url: str) -> str:
    return url.split("?")[0]


def test_one_person_with_two_ai_partners_may_give_each_its_own_kind(server, browser):
    page = browser.new_page()
    page.goto(server.url + "/")
    options = server.get("/api/options")[0]
    info = {f["value"]: f for f in options["follower_info"]}
    expect(page.locator("#second-follower")).to_be_hidden()
    page.select_option("#team", "1:2")
    expect(page.locator("#second-follower")).to_be_visible()
    expect(page.locator("#follower-heading")).to_have_text("First AI partner")
    assert "ippo" not in page.locator("#follower option").evaluate_all("os => os.map(o => o.value)")
    page.select_option("#follower", "ippo-1L2F")
    page.select_option("#follower-2", "copy")
    page.select_option("#mode", "turn")
    page.click("#start")
    expect(page.locator("#follower-label")).to_have_text(f"{info['ippo-1L2F']['label']} + {info['copy']['label']}")
    page.close()


def test_the_suites_copies_of_the_pages_number_formats_match_chromium(browser):
    """``js_fixed`` and ``js_round`` (tests/helpers.py) write a number as a page does, exact ties included: the
    tests that read a page's figures compare with them, not with Python's format, which sends ties the other way."""
    values = [6.25, 0.125, 2.675, -1.25, 12.5, 0.0, -0.0, -0.001, 0.49999999999999994, 1 / 3, 87.5, 0.005, 2.5,
              -2.5, 1e-7]
    page = browser.new_page()
    shown = page.evaluate("vs => vs.map(v => [v.toFixed(1), v.toFixed(2), Math.round(v)])", values)
    page.close()
    assert shown == [[js_fixed(v, 1), js_fixed(v, 2), js_round(v)] for v in values]
