"""A config on the command line: one flag per field (``add_arguments``), its help from the field's docstring,
and the config the parsed flags describe (``from_args``)."""

from __future__ import annotations

import argparse
import ast
import dataclasses
import inspect
import textwrap
import typing
from dataclasses import dataclass
from typing import Mapping

from colorgrid.configkit.build import is_tuple, plain_type


def field_docs(cls) -> dict[str, str]:
    """The docstring under each field of a dataclass (Python keeps none at run time; read from the source)."""
    out: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if not dataclasses.is_dataclass(klass):
            continue
        try:
            tree = ast.parse(textwrap.dedent(inspect.getsource(klass)))
        except (OSError, TypeError):
            continue
        body = tree.body[0].body
        for node, after in zip(body, body[1:]):
            if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) \
                    and isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant) \
                    and isinstance(after.value.value, str):
                out[node.target.id] = " ".join(after.value.value.split())
    return out


@dataclass(frozen=True)
class Flag:
    """How one field appears on the command line, where the generated flag is not what users type."""

    name: str | None = None
    """The flag (default: ``--field-name``)."""
    invert: bool = False
    """A bool field set to False by the flag (``--hide-belief`` for ``show_belief``)."""
    extend_default: bool = False
    """A tuple field whose repeated flag adds to the default (``--allowed-host``) instead of replacing it."""
    help: str | None = None
    choices: tuple | None = None


def add_arguments(parser: argparse.ArgumentParser, cls, flags: Mapping[str, Flag] | None = None,
                  skip=()) -> None:
    """One flag per field of ``cls``: the type and default from the field, the help from its docstring."""
    flags, docs = dict(flags or {}), field_docs(cls)
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if f.name in skip:
            continue
        flag = flags.get(f.name, Flag())
        option = flag.name or "--" + f.name.replace("_", "-")
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
        kind = plain_type(hints[f.name])
        help_text = (flag.help or docs.get(f.name, "")).replace("%", "%%")
        if kind is bool:
            parser.add_argument(option, dest=f.name, action="store_false" if flag.invert else "store_true",
                                default=default, help=help_text)
        elif is_tuple(kind):
            item = (typing.get_args(kind) or (str,))[0]
            parser.add_argument(option, dest=f.name, action="append", type=item, default=None,
                                metavar=f.name.rstrip("s").upper(), help=help_text + (
                                    " (repeatable; adds to " if flag.extend_default else " (repeatable; default ")
                                + f"{list(default)})")
        else:
            parser.add_argument(option, dest=f.name, type=kind, default=default, choices=flag.choices,
                                help=help_text + f" (default: {default})")


def from_args(cls, args: argparse.Namespace, flags: Mapping[str, Flag] | None = None, skip=(), **fixed):
    """The ``cls`` instance the flags of ``add_arguments`` describe (validated as usual)."""
    flags, hints = dict(flags or {}), typing.get_type_hints(cls)
    values = dict(fixed)
    for f in dataclasses.fields(cls):
        if f.name in skip or f.name in values:
            continue
        value = getattr(args, f.name)
        if is_tuple(plain_type(hints[f.name])):
            default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
            if value is None:  # not given
                value = default
            else:
                value = (*default, *value) if flags.get(f.name, Flag()).extend_default else tuple(value)
        values[f.name] = value
    return cls(**values)
