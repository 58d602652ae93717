"""The fixed sets of names a game's record uses, each declared once: an agent's role, how a game ended, what
became of a key, the kind of a study's game and how an AI leader fits a leader seat. The play server, the study's
export, the replay format and the tests import them from here; the pages get the lists they need from the server.

Each is a ``StrEnum``: a member is equal to its value (``Ending.COMPLETE == "complete"``), so records written
before stay valid and JSON holds the plain string."""

from __future__ import annotations

from enum import StrEnum


class Role(StrEnum):
    """An agent's role in its team (``EnvConfig.roles``): a leader knows the goal, a follower works it out."""

    LEADER = "leader"
    FOLLOWER = "follower"


class Ending(StrEnum):
    """How a game ended: ``complete`` (all its steps), or why it stopped early."""

    COMPLETE = "complete"
    IDLE = "idle"  # no key for the idle limit
    QUIT = "quit"  # the player ended it
    LEFT = "left"  # told to a person who left a game others play on (a stand-in takes their seat)
    DISCONNECTED = "disconnected"  # the connection was lost for longer than the rejoin grace
    SERVER_SHUTDOWN = "server_shutdown"  # the server stopped; the game was saved
    STAND_IN_FAILED = "stand_in_failed"  # a person left, and no stand-in could be loaded for their seat
    SERVER_LOST = "server_lost"  # its backend died; a study plays it again as a new attempt

    @classmethod
    def lost(cls) -> frozenset[Ending]:
        """Endings that are no one's doing: a study plays such a game again and does not count it."""
        return frozenset({cls.DISCONNECTED, cls.SERVER_SHUTDOWN, cls.SERVER_LOST})


class KeyStatus(StrEnum):
    """What became of a key a person pressed (one row of a game's key log)."""

    APPLIED = "applied"  # moved the seat at ``applied_step``
    SUPERSEDED = "superseded"  # replaced by a later key before a step took it (real time)
    IGNORED = "ignored"  # not a move the seat could make then
    UNAPPLIED = "unapplied"  # pressed after the game's last step
    STATED = "stated"  # a stated belief (the follower seat), not a move


class GameKind(StrEnum):
    """A study's game: a practice game or a counted trial."""

    PRACTICE = "practice"
    TRIAL = "trial"


class GoalView(StrEnum):
    """Whether a person in the follower seat sees the goal: ``hidden`` (the assistant's problem, the default) or
    ``shown`` (a control). A leader always sees it. A replay records it (``meta.goal_view``)."""

    HIDDEN = "hidden"
    SHOWN = "shown"

    @property
    def label(self) -> str:
        """How a page names it."""
        return {GoalView.HIDDEN: "hidden from you (work it out)", GoalView.SHOWN: "shown to you (a control)"}[self]


class SetApart(StrEnum):
    """A kind of recorded game that measures something else, reported apart by rescore (``colorgrid.replay.apart``):
    a study's practice game, or a game that showed the person in the follower seat the goal."""

    PRACTICE = "practice"
    GOAL_SHOWN = "goal_shown"


class SeatFit(StrEnum):
    """How an AI leader plays a leader seat of a team: ``direct`` (a scripted policy, or a network trained in that
    team) or ``1:1`` (a network trained in the 1:1 team, seeing the seat's game as a pair)."""

    DIRECT = "direct"
    PAIR_VIEW = "1:1"
