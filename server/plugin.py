"""What the play server adds to the ``colorgrid`` command line: ``colorgrid play`` and ``colorgrid study``.

Declared under the ``colorgrid.commands`` entry points (``pyproject.toml``); nothing of the server is imported
here, so the command line lists these commands, and names the extra they need, where it is not installed.
"""

from __future__ import annotations

from colorgrid.extras import Commands

PLAY_COMMANDS = Commands(("play",), "play", "server.cli:add_play_command")
"""``colorgrid play``: the play server (the ``colorgrid.commands`` entry point ``play``)."""
STUDY_COMMANDS = Commands(("study",), "study", "server.study.cli:add_study_commands")
"""``colorgrid study run | export``: human studies on the play server (the entry point ``study``)."""
