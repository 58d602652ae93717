"""The config toolkit: one way to validate, build, override and expose frozen dataclass configs.

Every config of the project (``EnvConfig``, the training configs, ``BayesConfig``,
``ServerSettings``) is a frozen dataclass with a docstring per field, validated in
``__post_init__`` with the checks below, built from plain data by ``from_dict`` (nested
dataclasses included), changed with ``KEY=VALUE`` overrides (``parse_override``,
``apply_overrides``), named in presets (``Presets``), and turned into command-line flags
(``add_arguments``, ``from_args``). ``resolve`` is the one way a config is resolved from a preset, a file
and overrides. Each class says how its errors read with ``ERROR_STYLE`` (and unknown keys with ``UNKNOWN_STYLE``).
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import inspect
import json
import math
import textwrap
import types
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

FIELD_FIRST = "{name}={value!r} is invalid: {allowed}"
"""The default error style: the field, its value, what is allowed (``ppo.lr=-1 is invalid: ...``)."""


class ConfigError(ValueError):
    """A setting is invalid; the message names the field, the value and what is allowed.

    ``field`` is the setting's name within the dataclass that raised it (None for errors not
    about one field); ``within`` names it from the config's root.
    """

    def __init__(self, message: str, field: str | None = None, detail: str = ""):
        super().__init__(message)
        self.field, self.detail = field, detail

    def within(self, section: str) -> "ConfigError":
        """The same error with the field named from its section: ``aux_coef`` -> ``follower.aux_coef``."""
        if self.field is None or not section:
            return self
        name = f"{section}.{self.field}"
        return type(self)(name + self.detail, name, self.detail)


# ------------------------------------------------------------------ checks
def fail(owner, name: str, allowed: str, value: Any = dataclasses.MISSING) -> typing.NoReturn:
    """Raise ``ConfigError`` for ``owner.name`` in the owner's ``ERROR_STYLE``."""
    value = getattr(owner, name) if value is dataclasses.MISSING else value
    style = getattr(owner, "ERROR_STYLE", FIELD_FIRST)
    message = style.format(name=name, value=value, allowed=allowed)
    if style.startswith("{name}"):  # the field leads: it can be renamed from the root (``within``)
        raise ConfigError(message, name, message[len(name):])
    raise ConfigError(message)


def is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def check_int(owner, name: str, lo: int, hi: int | None = None, *, optional: bool = False,
              allowed: str | None = None) -> None:
    """``owner.name`` is an int (not a bool) in ``[lo, hi]``; ``optional``: or None."""
    value = getattr(owner, name)
    if optional and value is None:
        return
    if not is_int(value) or value < lo or (hi is not None and value > hi):
        text = allowed or (f"an integer in [{lo}, {hi}]" if hi is not None else f"an integer >= {lo}")
        fail(owner, name, text + (" or null" if optional and allowed is None else ""))


def check_number(owner, name: str, allowed: str, within: Callable[[float], bool] = lambda v: True, *,
                 optional: bool = False) -> None:
    """``owner.name`` is a finite int or float (not a bool) for which ``within`` holds; ``optional``: or None."""
    value = getattr(owner, name)
    if optional and value is None:
        return
    if not is_number(value) or not within(value):
        fail(owner, name, allowed)


def check_bool(owner, name: str, allowed: str = "true or false") -> None:
    if not isinstance(getattr(owner, name), bool):
        fail(owner, name, allowed)


def check_choice(owner, name: str, choices, allowed: str | None = None) -> None:
    if getattr(owner, name) not in choices:
        fail(owner, name, allowed or f"one of {list(choices)}")


def check_strings(owner, name: str, choices=None, *, distinct: bool = False, allowed: str | None = None) -> None:
    """``owner.name`` is a tuple of non-empty strings (from ``choices``; all different if ``distinct``)."""
    value = getattr(owner, name)
    ok = isinstance(value, tuple) and all(isinstance(v, str) and v for v in value)
    if ok and choices is not None:
        ok = set(value) <= set(choices)
    if ok and distinct:
        ok = len(set(value)) == len(value)
    if not ok:
        what = "distinct names" if distinct else "non-empty strings"
        fail(owner, name, allowed or f"a tuple of {what}" + (f" from {list(choices)}" if choices else ""))


# ---------------------------------------------------------------- building
UNKNOWN_FIELDS = "unknown {label}field(s) {unknown}{place}; allowed: {allowed}"
"""How ``from_dict`` names unknown keys unless the class says otherwise with ``UNKNOWN_STYLE`` (fields:
``where``, ``label``, ``place`` (`` in where``), ``unknown`` (the sorted list), ``first`` (its first), ``allowed``)."""


def from_dict(cls, data: Any, where: str = ""):
    """An instance of the frozen dataclass ``cls`` from plain data (e.g. JSON or TOML), nested dataclasses included
    (a field ``X``, ``X | None`` or ``tuple[X, ...]``: a table, or a list of tables); lists become tuples where the
    field is a tuple; unknown keys are an error naming the allowed ones (in the class's ``UNKNOWN_STYLE``), and so
    are missing required ones. Keys the class lists in ``NOTES`` (a preset's ``description``) are notes for people,
    dropped. ``where`` names the section in errors (``ppo``, ``follower.net``, ``pages[3].questions[0]``)."""
    label = getattr(cls, "CONFIG_NAME", "")
    if not isinstance(data, dict):
        what = label or where or "a config"
        raise ConfigError(f"{what} must be built from a dict (a JSON object), got {type(data).__name__}")
    data = {k: v for k, v in data.items() if k not in getattr(cls, "NOTES", ())}
    fields = dataclasses.fields(cls)
    names = [f.name for f in fields]
    unknown = sorted(set(data) - set(names))
    if unknown:
        style = getattr(cls, "UNKNOWN_STYLE", UNKNOWN_FIELDS)
        raise ConfigError(style.format(where=where, label=label + " " if label else "", unknown=unknown,
                                       first=unknown[0], allowed=names,
                                       place=f" in {where}" if where and not label else "").lstrip(": "))
    missing = [f.name for f in fields if f.name not in data and f.default is dataclasses.MISSING
               and f.default_factory is dataclasses.MISSING]
    if missing:
        raise ConfigError(f"{where or label or 'the ' + cls.__name__.lower()}: missing {', '.join(missing)} "
                          f"(fields: {names})")
    hints = typing.get_type_hints(cls)
    values = {}
    for name, value in data.items():
        kind, inner = _plain_type(hints[name]), f"{where}.{name}" if where else name
        item = _tuple_item(kind)
        if dataclasses.is_dataclass(kind) and isinstance(value, dict):
            value = from_dict(kind, value, inner)
        elif dataclasses.is_dataclass(item) and isinstance(value, list):
            value = tuple(from_dict(item, v, f"{inner}[{i}]") for i, v in enumerate(value))
        elif _is_tuple(kind) and isinstance(value, list):
            value = tuple(value)
        elif kind is Path and isinstance(value, str):
            value = Path(value)
        values[name] = value
    try:
        return cls(**values)
    except ConfigError as err:
        raise err.within(where) from None


def read_toml(path: str | Path, what: str) -> dict:
    """The plain data of the TOML file ``path`` (a sweep file, a study file); ``ConfigError`` in one line saying why
    not (``no such sweep file``, ``not valid TOML (...)``), without the path: the caller names the file."""
    import tomllib

    try:
        return tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"no such {what}") from None
    except (OSError, UnicodeDecodeError) as err:
        raise ConfigError(f"cannot be read ({err})") from None
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"not valid TOML ({err})") from None


def to_dict(obj) -> dict:
    """Plain data of a (nested) dataclass: tuples become lists, paths strings, as JSON has them."""
    def plain(value):
        if dataclasses.is_dataclass(value):
            return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
        if isinstance(value, (tuple, list)):
            return [plain(v) for v in value]
        if isinstance(value, Path):
            return str(value)
        return value

    return plain(obj)


def _is_tuple(kind) -> bool:
    return kind is tuple or typing.get_origin(kind) is tuple


def _tuple_item(kind):
    """``tuple[X, ...]`` -> X; None for other types."""
    args = typing.get_args(kind) if typing.get_origin(kind) is tuple else ()
    return args[0] if len(args) == 2 and args[1] is Ellipsis else None


def _plain_type(kind):
    """``int | None`` -> int; other types as they are."""
    args = [a for a in typing.get_args(kind) if a is not type(None)]
    return args[0] if typing.get_origin(kind) in (typing.Union, types.UnionType) and len(args) == 1 else kind


def merge(base: dict, override: dict) -> dict:
    """Recursively merge plain dicts (override wins)."""
    out = dict(base)
    for key, value in override.items():
        out[key] = merge(out[key], value) if isinstance(value, dict) and isinstance(out.get(key), dict) else value
    return out


# --------------------------------------------------------------- overrides
def parse_override(text: str, flag: str = "--set", example: str = "ppo.lr=3e-4") -> tuple[list[str], Any]:
    """``a.b.c=value`` -> ``(["a", "b", "c"], value)``; the value is JSON if it parses, else the string."""
    if "=" not in text:
        raise ConfigError(f"{flag} {text!r}: expected KEY=VALUE, e.g. {example}")
    key, raw = text.split("=", 1)
    try:
        value = json.loads(raw)
    except json.JSONDecodeError:
        value = raw
    return key.strip().split("."), value


def override_dict(text: str, cls=None, section: str | None = None, **kwargs) -> dict:
    """One ``KEY=VALUE`` as nested plain data; with ``cls`` the keys are checked against its fields, and
    ``a,b`` becomes a tuple where the field is one. ``section``: the keys are named as a config holding ``cls``
    in its field ``section`` names them (``env.horizon=64`` for ``EnvConfig`` under ``env``), and a key without
    it is read as one under it; the data is ``cls``'s own."""
    path, value = parse_override(text, **kwargs)
    prefix = ""
    if section is not None and path[0] == section:
        path, prefix = path[1:], f"{section}."
        if not path:
            raise ConfigError(f"{kwargs.get('flag', '--set')} {text!r}: expected {section}.KEY=VALUE, e.g. "
                              f"{kwargs.get('example', section + '.KEY=1')}")
    if cls is not None:
        value = _coerce(cls, path, value, text, prefix)
    out: Any = value
    for part in reversed(path):
        out = {part: out}
    return out


def apply_overrides(data: dict, items, cls=None, **kwargs) -> dict:
    """``data`` with every ``KEY=VALUE`` of ``items`` merged in (see ``override_dict``)."""
    for text in items:
        data = merge(data, override_dict(text, cls, **kwargs))
    return data


# --------------------------------------------------------------- resolving
def resolve_data(*layers: Mapping, overrides=(), cls=None, where: str | None = None, **kwargs) -> dict:
    """Plain data of settings given in layers, each on top of the last: plain dicts first (a preset's, a config
    file's, a saved run's, a table of changes), then every ``KEY=VALUE`` of ``overrides`` (checked against
    ``cls``'s fields: ``override_dict``). ``where``: an override's error names its place in a list of that name
    (``set[2]: ...``)."""
    data: dict = {}
    for layer in layers:
        data = merge(data, dict(layer))
    for i, text in enumerate(overrides):
        try:
            data = merge(data, override_dict(text, cls, **kwargs))
        except ConfigError as err:
            if where is None:
                raise
            raise ConfigError(f"{where}[{i}]: {err}") from None
    return data


def resolve(cls, *layers: Mapping, overrides=(), where: str | None = None, **kwargs):
    """The one way a config is resolved: the ``cls`` instance that a preset, then a file, then ``KEY=VALUE``
    overrides describe (``resolve_data``'s layers, built by ``from_dict``). ``colorgrid train`` (preset, ``--config``,
    ``--set``), the sweep file (preset, ``set``, each trial's parameters) and the study file (its tables) all
    resolve their configs here."""
    return from_dict(cls, resolve_data(*layers, overrides=overrides, cls=cls, where=where, **kwargs))


def _coerce(cls, path: list[str], value, text: str, prefix: str = ""):
    kind = cls
    for i, part in enumerate(path):
        fields = {f.name for f in dataclasses.fields(kind)} if dataclasses.is_dataclass(kind) else set()
        if part not in fields:
            label = getattr(cls, "CONFIG_NAME", "") or cls.__name__
            nested = keys_named(kind, part, prefix + "".join(f"{p}." for p in path[:i]))
            hint = f" (did you mean {' or '.join(nested)}?)" if nested else ""
            raise ConfigError(f"unknown {label} field {prefix + '.'.join(path[:i + 1])!r} in {text!r}{hint}; "
                              f"allowed: {sorted(fields)}")
        kind = _plain_type(typing.get_type_hints(kind)[part])
    if _is_tuple(kind) and isinstance(value, str):
        return tuple(v for v in value.split(",") if v)
    return value


def keys_named(cls, name: str, prefix: str = "") -> list[str]:
    """The dotted keys of the fields called ``name`` inside the dataclass ``cls``'s nested sections:
    ``keys_named(TrainConfig, "block_density")`` is ``["env.block_density"]``."""
    if not dataclasses.is_dataclass(cls):
        return []
    found = []
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        section = _plain_type(hints[f.name])
        if dataclasses.is_dataclass(section):
            key = f"{prefix}{f.name}."
            found += [key + name] if name in {g.name for g in dataclasses.fields(section)} else []
            found += keys_named(section, name, key)
    return found


# ----------------------------------------------------------------- presets
class Presets:
    """Named bundles of settings, one JSON file each in ``folder``."""

    def __init__(self, folder: Path, what: str = "preset"):
        self.folder, self.what = folder, what

    def names(self) -> list[str]:
        return sorted(p.stem for p in self.folder.glob("*.json"))

    def load(self, name: str) -> dict:
        """A preset's plain data by name, or a JSON file's by path."""
        from colorgrid.files import JSONFileError, read_json_object

        path = Path(name)
        if not path.suffix:
            path = self.folder / f"{name}.json"
        if not path.exists():
            raise ConfigError(f"unknown {self.what} {name!r}: no file {path}; presets: {self.names()}")
        try:
            return read_json_object(path, f"a JSON object of {self.what} settings")
        except JSONFileError as err:
            raise ConfigError(f"{self.what} {err}") from None


# --------------------------------------------------------------------- CLI
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
        kind = _plain_type(hints[f.name])
        help_text = (flag.help or docs.get(f.name, "")).replace("%", "%%")
        if kind is bool:
            parser.add_argument(option, dest=f.name, action="store_false" if flag.invert else "store_true",
                                default=default, help=help_text)
        elif _is_tuple(kind):
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
        if _is_tuple(_plain_type(hints[f.name])):
            default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
            if value is None:  # not given
                value = default
            else:
                value = (*default, *value) if flags.get(f.name, Flag()).extend_default else tuple(value)
        values[f.name] = value
    return cls(**values)
