"""File helpers: atomic writes (a temporary file in the destination folder, renamed into place) and
JSON reading whose every failure is one line naming the file and the problem."""

from __future__ import annotations

import json
import math
import os
import secrets
import stat
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def atomic_path(path: str | os.PathLike, mode: int = 0o666):
    """Yield a temporary path beside ``path``; on success it replaces ``path``, on failure it is removed.

    A crash at any point leaves either the old file or no file under the final name,
    never a partial one. The temporary name keeps the suffix (writers pick formats by it).
    The file is created with ``mode`` less the umask (by default the mode ``open()`` would give); a private
    file (0o600) is private from its creation, before anything is written to it.
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = _create_temporary(path, mode)
    except OSError as err:
        raise ValueError(f"cannot write to {path}: {err.strerror}") from None
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _create_temporary(path: Path, mode: int = 0o666) -> Path:
    """A new, empty file beside ``path`` with a name of its own and ``mode`` (``mkstemp`` would make it private)."""
    for _ in range(100):
        tmp = path.with_name(f".{path.name}.{secrets.token_hex(4)}{path.suffix}")
        try:
            os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode))
        except FileExistsError:
            continue
        return tmp
    raise FileExistsError(f"no free temporary name beside {path}")


class JSONFileError(ValueError):
    """A JSON file that cannot be used: names the file and the problem, in one line."""

    def __init__(self, path: str | os.PathLike, problem: str):
        self.path, self.problem = str(path), problem
        super().__init__(f"{self.path}: {problem}")


class _NonFinite(ValueError):
    """Raised from the JSON parser's hooks on NaN, Infinity or a float too large for a double."""


def _reject_constant(token: str):
    raise _NonFinite(token)


def _finite_float(token: str) -> float:
    value = float(token)
    if not math.isfinite(value):
        raise _NonFinite(token)
    return value


def _megabytes(size: int) -> str:
    mb = size / 1e6
    return f"{mb:.1f}" if mb >= 0.1 else f"{mb:.6f}".rstrip("0").rstrip(".")


def _depth(doc) -> int:
    """Nesting depth of parsed JSON (a scalar is 0), without recursion."""
    deepest, stack = 0, [(doc, 1)]
    while stack:
        node, level = stack.pop()
        children = node.values() if isinstance(node, dict) else node if isinstance(node, list) else None
        if children is not None:
            deepest = max(deepest, level)
            stack.extend((child, level + 1) for child in children if isinstance(child, (dict, list)))
    return deepest


def read_json(path: str | os.PathLike, max_bytes: int | None = None, max_depth: int | None = None):
    """Parse a UTF-8 JSON file; every problem raises ``JSONFileError`` with a one-line reason.

    Only regular files are read (a folder or a FIFO is refused without opening it); with
    ``max_bytes`` a larger file is refused before it is read. NaN, Infinity and numbers that
    overflow a double are refused (standard JSON has none of them), as is nesting deeper
    than ``max_depth`` (or than the parser's recursion limit).
    """
    path = Path(path)
    try:
        info = path.stat()
    except FileNotFoundError:
        raise JSONFileError(path, "no such file") from None
    except OSError as err:
        raise JSONFileError(path, f"cannot be read: {err.strerror}") from None
    if stat.S_ISDIR(info.st_mode):
        raise JSONFileError(path, "is a directory, not a file")
    if not stat.S_ISREG(info.st_mode):
        raise JSONFileError(path, "is not a regular file")
    if max_bytes is not None and info.st_size > max_bytes:
        raise JSONFileError(path, f"file is {_megabytes(info.st_size)} MB; the limit is {_megabytes(max_bytes)} MB")
    try:
        with open(path, "rb") as f:
            raw = f.read() if max_bytes is None else f.read(max_bytes + 1)
    except OSError as err:
        raise JSONFileError(path, f"cannot be read: {err.strerror}") from None
    if max_bytes is not None and len(raw) > max_bytes:  # it grew since stat()
        raise JSONFileError(path, f"file is over the limit of {_megabytes(max_bytes)} MB")
    if not raw.strip():
        raise JSONFileError(path, "the file is empty")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        raise JSONFileError(path, f"not UTF-8 text (invalid byte at offset {err.start}); is it a JSON file?") from None
    try:
        doc = json.loads(text, parse_constant=_reject_constant, parse_float=_finite_float)
    except _NonFinite as err:
        raise JSONFileError(path, f"holds {str(err)[:40]}, which is not a finite number (NaN, Infinity and "
                                  f"numbers beyond 1.8e308 are not allowed)") from None
    except RecursionError:
        raise JSONFileError(path, "nested too deeply to be read (is it corrupt?)") from None
    except json.JSONDecodeError as err:
        raise JSONFileError(path, f"not valid JSON (truncated or corrupt?): {err}") from None
    except ValueError as err:  # e.g. an integer of more digits than Python converts
        raise JSONFileError(path, f"not valid JSON: {err}") from None
    if max_depth is not None and _depth(doc) > max_depth:
        raise JSONFileError(path, f"nested deeper than {max_depth} levels (is it corrupt?)")
    return doc


def read_json_object(path: str | os.PathLike, what: str) -> dict:
    """``read_json`` for a file that must hold one JSON object, e.g. ``what="a JSON object of EnvConfig fields"``."""
    doc = read_json(path)
    if not isinstance(doc, dict):
        raise JSONFileError(path, f"must hold {what}, but holds a JSON {_json_type(doc)}")
    return doc


def _json_type(value) -> str:
    names = {list: "array", str: "string", bool: "boolean", int: "number", float: "number", type(None): "null"}
    return names.get(type(value), type(value).__name__)
