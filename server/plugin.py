"""What the play server adds to the ``colorgrid`` command line: ``colorgrid play`` (the study's command is declared
in ``server.study.commands``).

Declared under the ``colorgrid.commands`` entry points (``pyproject.toml``); nothing of the server is imported
here, so the command line lists the command, and names the extra it needs, where it is not installed.
"""

from __future__ import annotations

from colorgrid.extras import Commands

PLAY_COMMANDS = Commands(("play",), "play", "server.cli:add_play_command")
"""``colorgrid play``: the play server (the ``colorgrid.commands`` entry point ``play``)."""
