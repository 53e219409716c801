"""The scene reader's validation kit, with no schema in it: values checked one by one against what the caller
expects, failing with one line that names the file and line (or the ``--set`` argument), the key and its value::

    scene.toml:14: camera.fov = 200: expected a number of degrees with 0 < fov < 180

:class:`Ctx` holds where each key came from and the checks (number, integer, boolean, choice, vector, path);
:class:`Table` reads one table's keys through them, an absent key giving the schema's default;
:func:`apply_override` writes a ``--set key=value`` into the TOML tree and records it for messages.
"""

from __future__ import annotations

import difflib
import math
import os
import re
import tomllib
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, NoReturn

from .errors import IsplatError

__all__ = ["Ctx", "Table", "apply_override", "dotted", "fmt", "kind"]

Vec3 = tuple[float, float, float]

# --------------------------------------------------------------------------------------------------------------------
# Formatting for messages

def dotted(path: Iterable) -> str:
    out = ""
    for part in path:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            name = part if re.fullmatch(r"[A-Za-z0-9_-]+", part) else '"' + part.replace('"', '\\"') + '"'
            out += ("." if out else "") + name
    return out


def fmt(value: Any, limit: int = 80) -> str:
    """A value as TOML-ish text for a message, shortened to ``limit`` characters."""
    def f(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, float):
            if math.isnan(v):
                return "nan"
            if math.isinf(v):
                return "inf" if v > 0 else "-inf"
            return repr(v)
        if isinstance(v, int):
            return str(v)
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(v, list):
            return "[" + ", ".join(f(x) for x in v) + "]"
        if isinstance(v, dict):
            return "{" + ", ".join(f"{dotted([k])} = {f(x)}" for k, x in v.items()) + "}"
        if hasattr(v, "isoformat"):
            return v.isoformat()
        return str(v)

    text = f(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def kind(value: Any) -> str:
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, (int, float)):
        return "a number"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, list):
        return "an array"
    if isinstance(value, dict):
        return "a table"
    return "a date/time"


# --------------------------------------------------------------------------------------------------------------------
# Validation context

class Ctx:
    """Where a scene's values came from (file and line, or ``--set``) and checks that fail with one line:
    ``FILE:LINE: key = value: what was expected``. Knows no schema: tables, keys and ranges are the caller's."""

    def __init__(self, source: str, loc: dict[tuple, int], base_dir: Path, set_args: dict[tuple, str]):
        self.source = source
        self.loc = loc            # key path -> line (isplat.scene_positions.locate_keys)
        self.base_dir = base_dir
        self.set_args = set_args  # key path -> the --set argument that wrote it

    def override_for(self, path: tuple) -> str | None:
        for k in range(len(path), 0, -1):
            if path[:k] in self.set_args:
                return self.set_args[path[:k]]
        return None

    def where(self, path: tuple | None, with_line: bool = True) -> str:
        if path:
            arg = self.override_for(path)
            if arg is not None:
                return f"--set {arg}"
            if with_line:
                for k in range(len(path), 0, -1):
                    if path[:k] in self.loc:
                        return f"{self.source}:{self.loc[path[:k]]}"
        return self.source

    def fail(self, path: tuple, value: Any, expected: str) -> NoReturn:
        raise IsplatError(f"{self.where(path)}: {dotted(path)} = {fmt(value)}: {expected}")

    def fail_msg(self, path: tuple | None, message: str, with_line: bool = True) -> NoReturn:
        raise IsplatError(f"{self.where(path, with_line)}: {message}")

    def missing(self, path: tuple, why: str = "") -> NoReturn:
        parent = path[:-1]
        arg = self.override_for(parent) if parent else None
        where = f"--set {arg}" if arg is not None else self.source
        raise IsplatError(f"{where}: missing required key '{dotted(path)}'{why}")

    # -- tables
    def table(self, tree: dict, path: tuple, known: Iterable[str], label: str | None = None) -> dict:
        """The sub-table at ``path`` of ``tree`` ({} when absent), with unknown keys refused."""
        value = tree.get(path[-1], {}) if path else tree
        if not isinstance(value, dict):
            self.fail(path, value, f"expected a table ([{dotted(path)}]), got {kind(value)}")
        self.check_keys(value, path, known, label)
        return value

    def check_keys(self, table: dict, path: tuple, known: Iterable[str], label: str | None = None) -> None:
        known = sorted(known)
        for key in table:
            if key not in known:
                where = f"[{label or dotted(path)}]" if path else "top-level keys"
                msg = (f"unknown key '{dotted(path + (key,))}' "
                       f"(known {'keys in ' + where if path else where}: {', '.join(known)})")
                close = difflib.get_close_matches(key, known, n=1, cutoff=0.6)
                if close:
                    msg += f"; did you mean '{close[0]}'?"
                self.fail_msg(path + (key,), msg)

    # -- scalars
    def number(self, path: tuple, value: Any, expected: str, lo: float | None = None, hi: float | None = None,
               lo_open: bool = False, hi_open: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(path, value, f"{expected} (got {kind(value)})")
        if not math.isfinite(value):
            self.fail(path, value, f"{expected} (got a non-finite number)")
        if lo is not None and (value < lo or (lo_open and value == lo)):
            self.fail(path, value, expected)
        if hi is not None and (value > hi or (hi_open and value == hi)):
            self.fail(path, value, expected)
        return float(value)

    def integer(self, path: tuple, value: Any, expected: str, lo: int | None = None, hi: int | None = None,
                allowed: Iterable[int] | None = None) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(path, value, f"{expected} (got {kind(value) if not isinstance(value, float) else 'a float'})")
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            self.fail(path, value, expected)
        if allowed is not None and value not in allowed:
            self.fail(path, value, expected)
        return int(value)

    def boolean(self, path: tuple, value: Any) -> bool:
        if not isinstance(value, bool):
            self.fail(path, value, f"expected true or false (got {kind(value)})")
        return value

    def choice(self, path: tuple, value: Any, options: tuple[str, ...]) -> str:
        if not isinstance(value, str) or value not in options:
            self.fail(path, value, "expected one of " + ", ".join(f'"{o}"' for o in options))
        return value

    def vector(self, path: tuple, value: Any, n: int = 3, expected: str | None = None,
               lo: float | None = None, hi: float | None = None, lo_open: bool = False,
               sizes: tuple[int, ...] | None = None) -> tuple[float, ...]:
        sizes = sizes or (n,)
        expected = expected or f"expected {n} numbers"
        if not isinstance(value, list) or len(value) not in sizes:
            self.fail(path, value, expected)
        out = []
        for x in value:
            if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
                self.fail(path, value, expected + " (finite numbers; true/false are not numbers)")
            if (lo is not None and (x < lo or (lo_open and x == lo))) or (hi is not None and x > hi):
                self.fail(path, value, expected)
            out.append(float(x))
        return tuple(out)

    def nonzero_unit(self, path: tuple, value: Any, what: str) -> Vec3:
        v = self.vector(path, value, expected=f"expected {what}: 3 numbers, not all zero")
        norm = math.sqrt(sum(x * x for x in v))
        if norm == 0.0 or not math.isfinite(norm):
            self.fail(path, value, f"expected {what}: 3 numbers, not all zero")
        return tuple(x / norm for x in v)

    def path_value(self, path: tuple, value: Any) -> Path:
        if not isinstance(value, str):
            self.fail(path, value, f"expected a file path string (got {kind(value)})")
        if value.strip() == "":
            self.fail(path, value, "expected a non-empty file path")
        p = Path(os.path.expanduser(value))
        # paths in the file are relative to the file's folder; paths given with --set to the working folder
        base = Path.cwd() if self.override_for(path) is not None else self.base_dir
        return Path(os.path.normpath(os.path.join(os.path.abspath(base), p)))


class Table:
    """One table's keys read through a :class:`Ctx`: a key the table has is checked, an absent one gives its
    default unchecked (defaults are the schema's, written once on its dataclasses: isplat.scene_schema).

    ``paths`` maps a key to where it came from when that is not ``path + (key,)`` (a camera of ``views.list``
    merged over ``[camera]``).
    """

    _NONE = object()

    def __init__(self, ctx: Ctx, raw: dict, path: tuple, defaults: Mapping[str, Any],
                 paths: Mapping[str, tuple] | None = None):
        self.ctx, self.raw, self.base, self.defaults, self.paths = ctx, raw, path, defaults, paths or {}

    def __contains__(self, key: str) -> bool:
        return key in self.raw

    def path(self, key: str) -> tuple:
        return self.paths.get(key, self.base + (key,))

    def read(self, key: str, check: Callable, *args, default: Any = _NONE, **kw) -> Any:
        """``check(path, value, *args, **kw)`` of the key's value, else ``default`` (else the schema's)."""
        if key in self.raw:
            return check(self.path(key), self.raw[key], *args, **kw)
        return self.defaults[key] if default is self._NONE else default

    def number(self, key: str, expected: str, **kw) -> float:
        return self.read(key, self.ctx.number, expected, **kw)

    def integer(self, key: str, expected: str, *args, **kw) -> int:
        return self.read(key, self.ctx.integer, expected, *args, **kw)

    def boolean(self, key: str) -> bool:
        return self.read(key, self.ctx.boolean)

    def choice(self, key: str, options: tuple[str, ...], **kw) -> str:
        return self.read(key, self.ctx.choice, options, **kw)

    def vector(self, key: str, **kw) -> tuple[float, ...]:
        return self.read(key, self.ctx.vector, **kw)

    def nonzero_unit(self, key: str, what: str) -> Vec3:
        return self.read(key, self.ctx.nonzero_unit, what)

    def fail(self, key: str, expected: str) -> NoReturn:
        self.ctx.fail(self.path(key), self.raw[key], expected)


# --------------------------------------------------------------------------------------------------------------------
# Overrides: --set key=value

_SET_PART = re.compile(r"^([A-Za-z0-9_-]+)(?:\[(\d+)\])?$")


def apply_override(tree: dict, arg: str, set_args: dict[tuple, str]) -> None:
    if not isinstance(arg, str) or "=" not in arg:
        raise IsplatError(f"--set {arg}: expected key=value, e.g. camera.azimuth=45")
    key, value_text = arg.split("=", 1)
    key = key.strip()
    if not key:
        raise IsplatError(f"--set {arg}: empty key before '='")
    try:
        value = tomllib.loads("v = " + value_text)["v"]
    except tomllib.TOMLDecodeError:
        value = value_text.strip()  # a bare word: render.method=full
    parts = key.split(".")
    path: tuple = ()
    node: Any = tree
    for n, part in enumerate(parts):
        m = _SET_PART.match(part.strip())
        if not m:
            raise IsplatError(f"--set {arg}: bad key '{key}' (expected dotted names such as camera.azimuth "
                              "or cut[0].normal)")
        name, index = m.group(1), m.group(2)
        last = n == len(parts) - 1
        if not isinstance(node, dict):
            raise IsplatError(f"--set {arg}: '{dotted(path)}' is not a table")
        path = path + (name,)
        if index is None:
            if last:
                node[name] = value
            else:
                node = node.setdefault(name, {})
            continue
        seq = node.setdefault(name, [])
        k = int(index)
        if not isinstance(seq, list):
            raise IsplatError(f"--set {arg}: '{dotted(path)}' is not an array")
        if k > len(seq):
            raise IsplatError(f"--set {arg}: '{dotted(path)}' has {len(seq)} elements; "
                              f"index {k} may be at most {len(seq)} (to append)")
        path = path + (k,)
        if last:
            if k == len(seq):
                seq.append(value)
            else:
                seq[k] = value
        else:
            if k == len(seq):
                seq.append({})
            node = seq[k]
    set_args[path] = arg
