"""A config's error, the base class that says how its errors read, and the checks ``__post_init__`` calls.

Every check names the field, its value and what is allowed, in the owner's ``ERROR_STYLE``; ``ConfigBase``
declares that hook and the other three (``CONFIG_NAME``, ``UNKNOWN_STYLE``, ``NOTES``) with their defaults.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import typing
from enum import StrEnum
from typing import Any, Callable, ClassVar, Iterable

FIELD_FIRST = "{name}={value!r} is invalid: {allowed}"
"""The default error style: the field, its value, what is allowed (``ppo.lr=-1 is invalid: ...``)."""

UNKNOWN_FIELDS = "unknown {label}field(s) {unknown}{place}; allowed: {allowed}"
"""How ``from_dict`` names unknown keys unless the class says otherwise with ``UNKNOWN_STYLE`` (fields:
``where``, ``label``, ``place`` (`` in where``), ``unknown`` (the sorted list), ``first`` (its first), ``allowed``)."""


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


class ConfigBase:
    """The base class of a config dataclass: its name in messages, how its errors read, which keys are notes.

    A config overrides these class attributes; ``configkit`` reads a config through them and nothing else
    (``hooks``). The messages themselves are built here, by ``invalid`` and ``unknown``."""

    CONFIG_NAME: ClassVar[str] = ""
    """The config's name in messages (``unknown EnvConfig field(s) ...``); empty: the section's place names it."""
    ERROR_STYLE: ClassVar[str] = FIELD_FIRST
    """How an invalid field reads (``name``, ``value``, ``allowed``). A style that opens with ``{name}`` names the
    field first, so that a config holding this one in a section renames it from its root (``follower.aux_coef``);
    one that opens otherwise (``EnvConfig.{name} must be ...``) reads the same wherever the config sits."""
    UNKNOWN_STYLE: ClassVar[str] = UNKNOWN_FIELDS
    """How unknown keys read (see ``UNKNOWN_FIELDS`` for the fields it may use)."""
    NOTES: ClassVar[tuple[str, ...]] = ()
    """Keys that are notes for people, not settings (a preset's ``description``): ``from_dict`` drops them."""

    @classmethod
    def invalid(cls, name: str, value: Any, allowed: str) -> ConfigError:
        """The error for the field ``name`` holding ``value``, in this class's ``ERROR_STYLE``."""
        message = cls.ERROR_STYLE.format(name=name, value=value, allowed=allowed)
        if cls.ERROR_STYLE.startswith("{name}"):  # the field leads: a section renames it (``ConfigError.within``)
            return ConfigError(message, name, message[len(name):])
        return ConfigError(message)

    @classmethod
    def unknown(cls, unknown: list[str], allowed: list[str], where: str) -> ConfigError:
        """The error for the keys ``unknown`` (sorted) found in ``where``, in this class's ``UNKNOWN_STYLE``."""
        label = cls.CONFIG_NAME
        return ConfigError(cls.UNKNOWN_STYLE.format(
            where=where, label=label + " " if label else "", unknown=unknown, first=unknown[0], allowed=allowed,
            place=f" in {where}" if where and not label else "").lstrip(": "))


HOOKS = ("CONFIG_NAME", "ERROR_STYLE", "UNKNOWN_STYLE", "NOTES")


@functools.lru_cache(maxsize=None)
def hooks(cls: type) -> type[ConfigBase]:
    """``cls`` as a ``ConfigBase``: itself when it derives from it; else (a plain dataclass, or one that names some
    of the four attributes without deriving) a ``ConfigBase`` with those of its attributes, the defaults for the
    rest."""
    if issubclass(cls, ConfigBase):
        return cls
    own = {name: klass.__dict__[name] for klass in reversed(cls.__mro__) for name in HOOKS if name in klass.__dict__}
    return type(cls.__name__, (ConfigBase,), own)


# ------------------------------------------------------------------ checks
def fail(owner, name: str, allowed: str, value: Any = dataclasses.MISSING) -> typing.NoReturn:
    """Raise ``ConfigError`` for ``owner.name`` in the owner's ``ERROR_STYLE``."""
    value = getattr(owner, name) if value is dataclasses.MISSING else value
    raise hooks(type(owner)).invalid(name, value, allowed)


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


def check_member(owner, name: str, members: Iterable[StrEnum], allowed: str | None = None) -> None:
    """``owner.name`` is one of ``members`` (an enum, or some of its members in the order the message lists them),
    as the member or as its text (a file's), and is then kept as the member: the frozen dataclass's field is set in
    place."""
    members, value = tuple(members), getattr(owner, name)
    member = next((m for m in members if m == value), None)
    if member is None:
        fail(owner, name, allowed or " or ".join(repr(m.value) for m in members))
    object.__setattr__(owner, name, member)


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
