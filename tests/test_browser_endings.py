"""The play page says how a game ended in the server's words (``/api/options``' ``endings``, from
``server.messages.ENDING_WORDS``): a real browser (Debian chromium, driven by playwright) on a real server. A person who
leaves a room's game reads its words in test_browser.py's room test."""

from playwright.sync_api import expect

from colorgrid.enums import Ending
from server.messages import ENDING_WORDS


def test_every_ending_the_server_declares_has_its_words_on_the_page(server, browser):
    """Endings the page once had no words for (``left``, ``stand_in_failed``) included: the page's own
    ``plainEnding``, once it has the server's options, gives each ending the server's words."""
    page = browser.new_page()
    page.goto(server.url + "/")
    expect(page.locator("#follower option").first).to_be_attached()  # the options are in
    shown = page.evaluate("""async endings => {
        const { plainEnding } = await import("/static/messages.js");
        return Object.fromEntries(endings.map(e => [e, plainEnding(e)]));
    }""", [e.value for e in Ending])
    assert shown == {e.value: ENDING_WORDS[e] for e in Ending}
    assert shown[Ending.STAND_IN_FAILED] != f"The game ended ({Ending.STAND_IN_FAILED})."
    page.close()
