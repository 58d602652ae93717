"""What the study adds to the ``colorgrid`` command line: ``colorgrid study run | export | power``.

Declared under the ``colorgrid.commands`` entry points (``pyproject.toml``); nothing of the study or the server is
imported here, so the command line lists the command, and names the extra it needs, where it is not installed.
"""

from __future__ import annotations

from colorgrid.extras import Commands

STUDY_COMMANDS = Commands(("study",), "study", "server.study.cli:add_study_commands")
"""``colorgrid study run | export | power``: human studies on the play server (the entry point ``study``)."""
