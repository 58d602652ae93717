"""The command line's parser: usage errors in one line (``colorgrid play: error: ...``, exit code 2), the command
as typed recorded for error lines. The ``colorgrid`` command and ``python -m train`` both parse with it."""

from __future__ import annotations

import argparse


class OneLineParser(argparse.ArgumentParser):
    """A parser whose usage errors are one line (``colorgrid play: error: ...``, exit code 2); ``-h`` has the rest.

    ``needs``: the extra this command needs and that is not installed; whatever follows the command
    (``--help`` too) then ends in one line saying how to install it, exit code 2.

    The parsed arguments' ``command_words`` are the command as typed (``["checkpoint", "export"]``), for error
    lines: the words of the innermost sub-parser that ran (its ``prog`` after ``colorgrid``), then the value of each
    of its positional arguments with fixed choices (a sub-command written as a choice: ``checkpoint export``).
    """

    def __init__(self, *args, needs: str | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self.needs = needs
        self.word_dests: list[str] = []

    def add_argument(self, *args, **kwargs):
        action = super().add_argument(*args, **kwargs)
        if not action.option_strings and action.choices is not None:
            self.word_dests.append(action.dest)
        return action

    def parse_known_args(self, args=None, namespace=None):
        if self.needs is not None:
            from colorgrid.extras import missing

            self.exit(2, f"{self.prog}: error: this command needs the {self.needs!r} extra "
                         f"({', '.join(missing(self.needs))} not installed): pip install 'colorgrid[{self.needs}]'\n")
        namespace, rest = super().parse_known_args(args, namespace)
        if not hasattr(namespace, "command_words"):  # a sub-parser, which finishes first, has set them
            chosen = [getattr(namespace, dest, None) for dest in self.word_dests]
            namespace.command_words = self.prog.split()[1:] + [word for word in chosen if isinstance(word, str)]
        return namespace, rest

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} -h)\n")
