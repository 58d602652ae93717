"""A policy describes itself (``colorgrid.policies.PolicyCard``): the server's menus, the release and the docs read
its card. A toy follower added the way docs/ARCHITECTURE.md says is offered by the server and played by
``colorgrid eval``."""

import asyncio
import json
import re
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest

from colorgrid.config import ROLES
from colorgrid.policies import SCRIPTED, Part, PolicyCard, offered_followers, policy_card, scripted
from colorgrid.policies.base import AgentInput, PolicyOutput
from colorgrid.policies.scripted import Seeker
from tests.conftest import ROOT

TOY = "toy-red"


class RedFollower(Seeker):
    """Walks to the nearest red block, whatever the goal."""

    name = TOY

    def act(self, inp: AgentInput, rows=None) -> PolicyOutput:
        block_color, me, other = self.positions(inp)
        wanted = np.zeros((len(me), self.config.num_colors), dtype=bool)
        wanted[:, 0] = True
        actions, _ = self.seek(wanted, block_color, me, other)
        return PolicyOutput(actions)


@pytest.fixture
def toy(monkeypatch):
    """``RedFollower`` registered as docs/ARCHITECTURE.md says, for this test only."""
    monkeypatch.setitem(SCRIPTED, TOY, None)  # taken out again when the test ends
    scripted(PolicyCard(follow=Part("Red seeker", "collects red, whatever the goal"), summary="collects red",
                        menu=85))(RedFollower)
    return TOY


def test_a_toy_follower_is_offered_by_the_server_and_played_by_eval(toy, tmp_path):
    from colorgrid_apps.cli import main
    from server.play.offer import Offer
    from server.protocol import Team
    from server.routes.play import options
    from server.settings import ServerSettings

    settings = ServerSettings()
    assert settings.followers.index("copy") < settings.followers.index(toy) < settings.followers.index("oracle")
    menu = asyncio.run(options(SimpleNamespace(settings=settings, hub=Offer(settings))))
    assert toy in menu["followers"]
    assert {"value": toy, "label": "Red seeker", "description": "collects red, whatever the goal",
            "has_belief": False} in menu["follower_info"]
    assert all(toy in team["followers"] for team in menu["teams"] if team["ai_followers"])  # any team

    report = tmp_path / "report.json"
    assert main(["eval", "--follower", toy, "--episodes", "2", "--set", "horizon=24", "--json", str(report)]) == 0
    played = json.loads(report.read_text())
    assert played["follower"]["policy"] == toy and played["episodes"] == 2


def test_a_scripted_policy_must_name_itself():
    class Nameless(Seeker):
        pass

    with pytest.raises(TypeError, match="Nameless must set its own name"):
        scripted(PolicyCard())(Nameless)
    assert "policy" not in SCRIPTED


def test_the_docs_table_has_a_row_per_scripted_policy_with_its_roles():
    """docs/EVALUATION.md's table of scripted policies: one row each; ``any`` for one offered in both roles."""
    text = (ROOT / "docs" / "EVALUATION.md").read_text()
    rows = dict(re.findall(r"^\| `([a-z-]+)` \| (any|leader|follower) \|", text, flags=re.M))
    assert set(rows) == set(SCRIPTED)
    for name, kind in SCRIPTED.items():
        roles = kind.card.roles
        assert rows[name] == ("any" if roles == ROLES else "leader" if roles == ("leader",) else "follower"), name


def test_cards_say_belief_and_roles_and_the_menu_reads_them():
    assert policy_card("bayes:lapse=0.2") is SCRIPTED["bayes"].card and policy_card("bayes").belief
    assert policy_card("astar").roles == ("leader",) and not policy_card("copy").belief
    assert policy_card("population:people#held_out").lead is not None
    assert policy_card("populations/people.json") is None and policy_card("no-such-policy") is None
    assert offered_followers()[:2] == ("ippo-shielded", "bayes-people") and "astar" not in offered_followers()
    assert "bayes-limit" not in offered_followers()  # it needs its leader's model, which only eval gives


def test_the_release_describes_each_follower_by_its_card():
    from colorgrid_apps.release import FOLLOWERS

    assert [policy_card(name).summary for name in FOLLOWERS] == [
        "copies the color of the leader's last paying pickup", "knows the true goal (upper bound)",
        "infers the goal with a hidden Markov model"]


class StickFollower(RedFollower):
    """A toy yardstick: collects red, as the toy follower does."""

    name = "toy-stick"


def test_a_yardstick_is_refused_wherever_a_person_chooses_a_partner_saying_why(monkeypatch):
    """``bayes-limit``'s card says it is a yardstick (``PolicyCard.yardstick``): the play server's ``--follower`` and
    ``--followers``, a page's ``new_game`` and a study's follower refuse it in one line saying why, and so they do any
    policy whose card says so (a toy's), whatever its name."""
    from colorgrid.configkit import ConfigError
    from server.play.offer import Offer
    from server.protocol import GameRequest
    from server.settings import ServerSettings
    from server.study.config import GameSettings

    monkeypatch.setitem(SCRIPTED, StickFollower.name, None)  # taken out again when the test ends
    scripted(PolicyCard(follow=Part("Stick", "a toy yardstick"), yardstick="it is a toy"))(StickFollower)
    why = {"bayes-limit": "bayes-limit is a yardstick for evaluation: it is given its leader's true model, which "
                          "only colorgrid eval gives it",
           "toy-stick": "toy-stick is a yardstick for evaluation: it is a toy"}
    for name, reason in why.items():
        with pytest.raises(ConfigError) as refused:
            ServerSettings(follower=name)
        assert str(refused.value) == f"follower must be a follower a person may play beside ({reason}), got {name!r}"
        with pytest.raises(ConfigError, match=re.escape(f"followers must be a follower a person may play beside "
                                                        f"({reason}), got '{name}:lapse=0.2'")):
            ServerSettings(followers=("copy", f"{name}:lapse=0.2"))
        with pytest.raises(ValueError, match=re.escape(f"follower {name!r} is not offered ({reason}); choose one of")):
            Offer(ServerSettings()).choose(GameRequest(follower=name))
        with pytest.raises(ConfigError) as refused:
            GameSettings(follower=name)
        assert str(refused.value) == f"follower={name!r} is invalid: a follower a person may play beside ({reason})"
        assert "\n" not in str(refused.value)
    with pytest.raises(ValueError, match="a yardstick .* has no place in the play server's follower menu"):
        PolicyCard(yardstick="it reads the goal", menu=10)


@pytest.mark.parametrize("command", [["play"], ["study", "run", "studies/human_follower.toml"]])
@pytest.mark.parametrize("followers, words", [
    ("copy,bayes-limit", "--followers 'copy,bayes-limit' is no policy: give one of ['astar', "),
    ("copy,bayes", "ending in .pt (one name a flag: --followers copy --followers bayes)"),
    ("bayes,x.pt", "--followers 'bayes,x.pt' is no policy"),
    ("nosuch", "--followers 'nosuch' is no policy: give one of ["),
])
def test_the_play_server_refuses_a_follower_that_is_no_policy_in_one_line(command, followers, words, tmp_path):
    """Each ``--followers`` gives one name: names joined by a comma, or a name that is no policy, are refused
    before the server starts (they were taken as one follower that no game could build, a yardstick among them
    unseen), by ``colorgrid play`` and ``study run`` alike."""
    done = subprocess.run([sys.executable, "-m", "colorgrid_apps", *command, "--followers", followers, "--port", "0",
                           "--replays-dir", str(tmp_path / "rec")], cwd=ROOT, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 2, done.stdout + done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and words in lines[0], done.stderr


def test_a_follower_whose_parameters_hold_commas_is_one_follower():
    """A comma among a name's parameters is a parameter's, not a second follower; the menu's list, given as one
    setting, keeps such a name whole in parentheses."""
    from colorgrid.configkit.build import resolve
    from server.cli import check_follower_names
    from server.settings import ServerSettings

    nested = "shielded:mover=ippo-people,reader=(bayes:rationality=3,lapse=0.05),min_belief=0.8"
    check_follower_names(("bayes:lapse=0.2,rationality=3", nested))
    with pytest.raises(ValueError, match="one name a flag"):
        check_follower_names(("copy,bayes",))
    settings = resolve(ServerSettings, overrides=[f"followers=copy,({nested}),(bayes:lapse=0.2,rationality=3)"])
    assert settings.followers == ("copy", nested, "bayes:lapse=0.2,rationality=3")
