"""What a game records of its people's pages, each record capped: every key pressed, with what became of it
(``KeyStatus``), and the pages' focus and visibility changes."""

from __future__ import annotations

import time

from colorgrid.enums import KeyStatus

PENDING = "pending"
"""A key's status while it waits for the next step: it becomes ``applied`` or ``superseded``, or ``unapplied`` when
the game ends first (``KeyLog.close``), so no record holds it. Not a ``KeyStatus`` member for that reason: a key has it
only until the next step takes it, and ``KeyStatus`` lists what a saved record may say."""


class BadSeq(ValueError):
    """A key whose ``seq`` is not after the last one of its person in this game: refused, so that ``(game, seq)``
    names one key (per person in a team) across reloads and reconnects."""


def now_ms() -> float:
    """The server's wall clock in milliseconds (what the records' ``t_server`` say)."""
    return time.time() * 1000.0


class CappedLog:
    """Entries recorded up to ``limit``; later ones are only counted (``dropped``)."""

    def __init__(self, limit: int):
        self.limit = limit
        self.entries: list[dict] = []
        self.dropped = 0

    def add(self, entry: dict) -> None:
        """Record ``entry``, or count it once the log is full."""
        if len(self.entries) < self.limit:
            self.entries.append(entry)
        else:
            self.dropped += 1


class KeyLog(CappedLog):
    """Every key of a game's people (``max_key_log`` of them; later ones still move their leader and are counted)."""

    @staticmethod
    def entry(seat, key: str, seq: int, t_client: float, tagged: bool) -> dict:
        """A new entry for a key of the person in ``seat`` (a ``server.seats.Seat``), named by agent when ``tagged``
        (a team game); a ``seq`` not after this person's last one raises ``BadSeq``."""
        if seat.last_seq is not None and seq <= seat.last_seq:
            raise BadSeq(f"key seq {seq} is not after your last key in this game ({seat.last_seq}): number keys on "
                         f"from {seat.next_seq} (the welcome's next_seq)")
        seat.last_seq = seq
        entry = {"seq": seq, "key": key, "t_client": t_client, "t_server": now_ms(), "applied_step": None}
        return {"agent": seat.name, **entry} if tagged else entry

    def close(self) -> None:
        """The game made its last step: keys still pending were pressed after it (``unapplied``)."""
        for entry in self.entries:
            if entry["status"] == PENDING:
                entry["status"] = KeyStatus.UNAPPLIED
