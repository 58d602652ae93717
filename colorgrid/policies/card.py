"""What a policy says of itself: the roles it may take and how each is called, whether it holds a belief over the
goal, the teams it fits, whether the play page offers it and whether it is a yardstick no person plays beside.
Declared beside the policy (a scripted one with ``registry.scripted``, an application's with
``registry.register_policy``) and read by every application: the play server's menus, the release's descriptions,
the docs' table (a test checks it)."""

from __future__ import annotations

from dataclasses import dataclass

from colorgrid.config import ROLES


@dataclass(frozen=True)
class Part:
    """How a policy is called in one role, in the words the play page shows a person."""

    label: str
    """Its name in the menu (``"Bayesian assistant"``)."""
    description: str
    """One line under the menu, addressed to the person beside it."""


@dataclass(frozen=True)
class PolicyCard:
    """A policy's facts. A role without its ``Part`` is one the policy is not offered in; the page then names it
    by its policy name."""

    lead: Part | None = None
    """How it is called as an AI leader; None: it is offered as no leader."""
    follow: Part | None = None
    """How it is called as an AI follower; None: it is offered as no follower."""
    belief: bool = False
    """Whether it forms a belief over the goal (``PolicyOutput.goal_probs``) that a page may draw."""
    summary: str = ""
    """What it does in a researcher's words, for records (the release's index): ``"knows the true goal (upper
    bound)"``."""
    menu: int | None = None
    """Its place in the play server's follower menu when the server is not told which to offer (lower first);
    None: offered only when named (``colorgrid play --followers``)."""
    teams: tuple[str, ...] | None = None
    """The teams (``"LEADERS:FOLLOWERS"``) it plays; None: any (a scripted policy plays any agent of any team)."""
    yardstick: str | None = None
    """Why it is a yardstick for evaluation and no partner for a person, in a few words (``bayes-limit``: it is given
    its leader's true model, which only ``colorgrid eval`` gives it); None: a partner. A yardstick is refused, with
    this reason, wherever a person's partner is chosen (the play server's followers, a study's), and has no place in
    the menu."""

    def __post_init__(self):
        if self.yardstick is not None and self.menu is not None:
            raise ValueError(f"a yardstick ({self.yardstick}) has no place in the play server's follower menu: leave "
                             f"menu={self.menu} out")

    @property
    def roles(self) -> tuple[str, ...]:
        """The roles (``ROLES``) it may be offered in: those with a ``Part``."""
        return tuple(role for role in ROLES if self.part(role) is not None)

    def part(self, role: str) -> Part | None:
        """How it is called in ``role`` (``"leader"`` or ``"follower"``), None when it is not offered in it."""
        return dict(zip(ROLES, (self.lead, self.follow))).get(role)
