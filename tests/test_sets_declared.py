"""A fixed set is an enum, declared once: no role, game mode, seat status or room-closed reason is compared as a
string literal in the Python packages. Each is compared as its member (``colorgrid.enums.Role``,
``server.protocol.Mode``, ``SeatStatus``, ``RoomSeatStatus``, ``RoomClosedReason``); their values are written only
where they are declared (``colorgrid/enums.py``, ``server/protocol.py``)."""

from __future__ import annotations

import ast
import re

import pytest

from colorgrid.enums import Role
from server.protocol import GoalView, Mode, RoomClosedReason, RoomSeatStatus, SeatStatus
from tests.conftest import ROOT

PACKAGES = ("colorgrid", "colorgrid_apps", "server", "train")
DECLARED = {Role: "colorgrid/enums.py", Mode: "server/protocol.py", SeatStatus: "server/protocol.py",
            RoomSeatStatus: "server/protocol.py", RoomClosedReason: "server/protocol.py"}
WORDS = {member.value: enum.__name__ for enum in DECLARED for member in enum} | {"lead a person": "Role"}
"""Each value of the sets (and the role once spelled ``"lead a person"``), with the enum to compare it as."""


def literal_comparisons(tree: ast.AST) -> list[tuple[int, str]]:
    """``(line, value)`` of each ``==``, ``!=``, ``in`` or ``not in`` comparison of a set's value as a string literal:
    ``role == "leader"``, ``"turn" != mode``, ``status in ("open", "ready")``."""
    found = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Compare):
            continue
        sides = [node.left, *node.comparators]
        for op, (left, right) in zip(node.ops, zip(sides, sides[1:])):
            if isinstance(op, (ast.Eq, ast.NotEq)):
                literals = [side for side in (left, right) if isinstance(side, ast.Constant)]
            elif isinstance(op, (ast.In, ast.NotIn)) and isinstance(right, (ast.Tuple, ast.List, ast.Set)):
                literals = [item for item in right.elts if isinstance(item, ast.Constant)]
            else:
                continue
            found += [(node.lineno, side.value) for side in literals if side.value in WORDS]
    return found


def package_modules():
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            yield path.relative_to(ROOT).as_posix(), path


def test_no_role_mode_seat_status_or_room_closed_reason_is_compared_as_a_string_literal():
    found = [f"{where}:{line}: {value!r} (compare as {WORDS[value]})"
             for where, path in package_modules() for line, value in literal_comparisons(ast.parse(path.read_text()))]
    assert not found, "compared as string literals:\n" + "\n".join(found)


@pytest.mark.parametrize("source, expected", [
    ('role == "leader"', [(1, "leader")]),
    ('"turn" != mode', [(1, "turn")]),
    ('status in ("open", "ready", "other")', [(1, "open"), (1, "ready")]),
    ('kind == "lead a person"', [(1, "lead a person")]),
    ('role == Role.LEADER', []),
    ('"leader" in factors', []),  # a factor's name, not a role
    ('name == "bayes"', []),
])
def test_the_check_finds_literal_comparisons_and_only_those(source, expected):
    assert literal_comparisons(ast.parse(source)) == expected


PAGE_SETS = {"ROLE": Role, "MODE": Mode, "GOAL_VIEW": GoalView, "SEAT_STATUS": SeatStatus,
             "ROOM_SEAT_STATUS": RoomSeatStatus}
"""The sets the pages compare with (``web/sets.js``), by their name there, and the server's enum each spells."""
JS_COMPARISON = re.compile(r'(?:===|!==)\s*"([a-z_ ]+)"|"([a-z_ ]+)"\s*(?:===|!==)')


def page_sets() -> dict[str, dict[str, str]]:
    """``web/sets.js``'s frozen objects: ``{"ROLE": {"LEADER": "leader", ...}, ...}``."""
    text = (ROOT / "web" / "sets.js").read_text()
    return {name: dict(re.findall(r'(\w+): "([^"]*)"', body))
            for name, body in re.findall(r"export const (\w+) = Object\.freeze\(\{([^}]*)\}\)", text)}


def test_the_pages_sets_are_the_servers_enums():
    assert page_sets() == {name: {m.name: m.value for m in enum} for name, enum in PAGE_SETS.items()}


def js_literal_comparisons(text: str) -> list[tuple[int, str]]:
    """``(line, value)`` of each ``===`` or ``!==`` comparison of a set's value as a string literal in page code."""
    words = {m.value for enum in PAGE_SETS.values() for m in enum}
    return [(text.count("\n", 0, m.start()) + 1, value) for m in JS_COMPARISON.finditer(text)
            for value in m.groups() if value in words]


def test_no_page_compares_a_sets_value_as_a_string_literal():
    found = [f"web/{path.name}:{line}: {value!r}" for path in sorted((ROOT / "web").glob("*.js"))
             if path.name != "sets.js" for line, value in js_literal_comparisons(path.read_text())]
    assert not found, "compared as string literals (import it from web/sets.js):\n" + "\n".join(found)


@pytest.mark.parametrize("source, expected", [
    ('if (game.mode === "turn") {', [(1, "turn")]),
    ('x;\nconst a = "follower" !== seat;', [(2, "follower")]),
    ('if (game.mode === MODE.TURN) {', []),
    ('if (msg.type === "state") {', []),
])
def test_the_page_check_finds_literal_comparisons_and_only_those(source, expected):
    assert js_literal_comparisons(source) == expected
