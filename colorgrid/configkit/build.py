"""Building a config: from plain data (``from_dict``), with ``KEY=VALUE`` overrides (``split_override``,
``apply_overrides``), from layers (``resolve``: a preset, a file, overrides), and named bundles (``Presets``)."""

from __future__ import annotations

import dataclasses
import json
import types
import typing
from pathlib import Path
from typing import Any, Mapping

from colorgrid.configkit.checks import ConfigError, hooks


def from_dict(cls, data: Any, where: str = ""):
    """An instance of the frozen dataclass ``cls`` from plain data (e.g. JSON or TOML), nested dataclasses included
    (a field ``X``, ``X | None`` or ``tuple[X, ...]``: a table, or a list of tables); lists become tuples where the
    field is a tuple; unknown keys are an error naming the allowed ones (in the class's ``UNKNOWN_STYLE``), and so
    are missing required ones. Keys the class lists in ``NOTES`` (a preset's ``description``) are notes for people,
    dropped. ``where`` names the section in errors (``ppo``, ``follower.net``, ``pages[3].questions[0]``)."""
    config = hooks(cls)
    label = config.CONFIG_NAME
    if not isinstance(data, dict):
        what = label or where or "a config"
        raise ConfigError(f"{what} must be built from a dict (a JSON object), got {type(data).__name__}")
    data = {k: v for k, v in data.items() if k not in config.NOTES}
    fields = dataclasses.fields(cls)
    names = [f.name for f in fields]
    unknown = sorted(set(data) - set(names))
    if unknown:
        raise config.unknown(unknown, names, where)
    missing = [f.name for f in fields if f.name not in data and f.default is dataclasses.MISSING
               and f.default_factory is dataclasses.MISSING]
    if missing:
        raise ConfigError(f"{where or label or 'the ' + cls.__name__.lower()}: missing {', '.join(missing)} "
                          f"(fields: {names})")
    hints = typing.get_type_hints(cls)
    values = {}
    for name, value in data.items():
        kind, inner = plain_type(hints[name]), f"{where}.{name}" if where else name
        item = tuple_item(kind)
        if dataclasses.is_dataclass(kind) and isinstance(value, dict):
            value = from_dict(kind, value, inner)
        elif dataclasses.is_dataclass(item) and isinstance(value, list):
            value = tuple(from_dict(item, v, f"{inner}[{i}]") for i, v in enumerate(value))
        elif is_tuple(kind) and isinstance(value, list):
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


def is_tuple(kind) -> bool:
    return kind is tuple or typing.get_origin(kind) is tuple


def tuple_item(kind):
    """``tuple[X, ...]`` -> X; None for other types."""
    args = typing.get_args(kind) if typing.get_origin(kind) is tuple else ()
    return args[0] if len(args) == 2 and args[1] is Ellipsis else None


def plain_type(kind):
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
def split_override(text: str, flag: str = "--set", example: str = "ppo.lr=3e-4") -> tuple[list[str], Any]:
    """``a.b.c=value`` -> ``(["a", "b", "c"], value)``: the key split at its dots, the value JSON if it parses, else
    the string (``override_dict`` gives it as nested data, as ``train.config.parse_override`` does)."""
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
    path, value = split_override(text, **kwargs)
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
            label = hooks(cls).CONFIG_NAME or cls.__name__
            nested = keys_named(kind, part, prefix + "".join(f"{p}." for p in path[:i]))
            hint = f" (did you mean {' or '.join(nested)}?)" if nested else ""
            raise ConfigError(f"unknown {label} field {prefix + '.'.join(path[:i + 1])!r} in {text!r}{hint}; "
                              f"allowed: {sorted(fields)}")
        kind = plain_type(typing.get_type_hints(kind)[part])
    if is_tuple(kind) and isinstance(value, str):
        items = split_outside_brackets(value)
        if items is None:
            raise ConfigError(f"unbalanced brackets in {text!r}; give an item with commas of its own whole in "
                              "parentheses: a,(b:x=1,y=2)")
        return tuple(unwrap(v) for v in items)
    return value


def split_outside_brackets(text: str) -> list[str] | None:
    """The non-empty items of a comma-separated ``text``, split only at the commas outside ``()``, ``[]`` and
    ``{}`` (``"a,(b:x=1,y=2),[1,2]"`` -> ``["a", "(b:x=1,y=2)", "[1,2]"]``); None when its brackets do not balance."""
    items, depth, start = [], 0, 0
    for i, char in enumerate(text):
        if char in "([{":
            depth += 1
        elif char in ")]}":
            depth -= 1
            if depth < 0:
                return None
        elif char == "," and depth == 0:
            items.append(text[start:i])
            start = i + 1
    return None if depth else [item for item in items + [text[start:]] if item]


def unwrap(item: str) -> str:
    """``item`` without the parentheses that hold it whole (``"(b:x=1,y=2)"`` -> ``"b:x=1,y=2"``), stripped of
    spaces; anything else as it is (``"(a)(b)"``: its first parenthesis closes before its end)."""
    item = item.strip()
    if not (item.startswith("(") and item.endswith(")")):
        return item
    depth = 0
    for i, char in enumerate(item):
        depth += char == "("
        depth -= char == ")"
        if depth == 0:
            return item[1:-1] if i == len(item) - 1 else item
    return item


def keys_named(cls, name: str, prefix: str = "") -> list[str]:
    """The dotted keys of the fields called ``name`` inside the dataclass ``cls``'s nested sections:
    ``keys_named(TrainConfig, "block_density")`` is ``["env.block_density"]``."""
    if not dataclasses.is_dataclass(cls):
        return []
    found = []
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        section = plain_type(hints[f.name])
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
