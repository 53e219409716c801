"""Read a TOML scene into validated, frozen dataclasses; apply ``--set`` overrides; report errors by line.

The format is specified in ``formats/scene.md``. Every problem raises :class:`IsplatError` with one line naming
the file and line (or the ``--set`` argument), the key, its value and what was expected::

    scene.toml:14: camera.fov = 200: expected a number of degrees with 0 < fov < 180

``tomllib`` gives values but no positions, so :func:`locate_keys` scans the source text for the line where each
key (and each array element) starts. When it cannot place a key, the message leaves the line out.
"""

from __future__ import annotations

import difflib
import logging
import math
import os
import re
import tomllib
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Iterable

from . import units as _units
from .errors import IsplatError
from .fileio import check_regular
from .limits import MAX_SCENE_BYTES, MAX_VIEWS, check_scene_text

__all__ = [
    "SCENE_VERSION", "Scene", "Data", "Image", "Volume", "Camera", "Transfer", "Shading", "Light", "Cut",
    "RenderOptions", "load_scene", "parse_scene", "locate_keys", "scene_to_dict",
]

SCENE_VERSION = 4
# keys added by each version after 1: a file that says an older version must not use them
KEYS_SINCE = {("transfer", "units"): 2, ("transfer", "preset"): 2, ("views", "path"): 2, ("views", "frames"): 2,
              ("views", "fps"): 2, ("render", "sheets"): 3,
              ("render", "classification"): 4, ("render", "supersample"): 4}

Vec3 = tuple[float, float, float]
SUPERSAMPLE_MAX = 8


# --------------------------------------------------------------------------------------------------------------------
# Output dataclasses (the contract with the renderer)

@dataclass(frozen=True)
class Data:
    augmented: Path | None       # None: a scene for a volume in memory (parse_scene(data_required=False))
    index: Path | None

    @property
    def written(self) -> str:
        """The augmented path for messages: as written in the scene (set by the reader), else resolved."""
        return self.__dict__.get("_written", str(self.augmented))


@dataclass(frozen=True)
class Image:
    width: int
    height: int
    background: tuple[float, float, float, float]
    bit_depth: int


@dataclass(frozen=True)
class Volume:
    spacing: Vec3 | None
    origin: Vec3 | None
    axes: tuple[Vec3, Vec3, Vec3]


@dataclass(frozen=True)
class Camera:
    projection: str
    mode: str
    azimuth: float
    elevation: float
    distance: float | None
    roll: float
    target: Vec3 | None
    up: Vec3
    position: Vec3 | None
    look_at: Vec3 | None
    reference_point: Vec3 | None
    view_up: Vec3 | None
    view_plane_normal: Vec3 | None
    eye: Vec3 | None
    zoom: float
    fov: float
    near: float


@dataclass(frozen=True)
class Transfer:
    """Always in density codes (0..255) for the renderer; ``units``, ``preset`` and ``density_window`` record
    what the scene said and the window its data-unit points were converted through (None for codes only)."""

    opacity: tuple[tuple[float, float], ...]
    color: tuple[tuple[float, float, float, float], ...]
    gradient_opacity: tuple[tuple[float, float], ...]
    unit_distance: float
    units: str = "code"
    preset: str | None = None
    density_window: tuple[float, float] | None = None


@dataclass(frozen=True)
class Light:
    direction: Vec3
    intensity: float
    color: Vec3


@dataclass(frozen=True)
class Shading:
    enabled: bool
    ambient: float
    diffuse: float
    specular: float
    shininess: float
    two_sided: bool
    lights: tuple[Light, ...]


@dataclass(frozen=True)
class Cut:
    point: Vec3
    normal: Vec3


@dataclass(frozen=True)
class RenderOptions:
    method: str
    early_termination: float
    footprint_radius: float
    footprint_sigma: float
    footprint_table: int
    precision: str
    threads: int
    sheets: str = "axis"         # "axis": a sheet per slice; "image": slabs parallel to the image plane
    classification: str = "post"  # "pre": each voxel classified, then splatted; "post": density splatted,
                                  # then classified (isplat.splat.post)
    supersample: int = 1          # render at N times the width and height, box-filtered down


@dataclass(frozen=True)
class Scene:
    path: Path | None
    data: Data
    image: Image
    volume: Volume
    camera: Camera
    transfer: Transfer
    shading: Shading
    cuts: tuple[Cut, ...]
    render: RenderOptions
    views: tuple[Camera, ...]
    fps: float = 12.0            # frames per second of a GIF or MP4 of the views


# --------------------------------------------------------------------------------------------------------------------
# Schema: known keys per table

TOP_KEYS = ("version", "data", "image", "volume", "camera", "transfer", "shading", "cut", "render", "views")
DATA_KEYS = ("augmented", "index")
IMAGE_KEYS = ("width", "height", "background", "bit_depth")
VOLUME_KEYS = ("spacing", "origin", "axes")
CAMERA_COMMON_KEYS = ("projection", "mode", "up", "roll", "zoom", "fov", "near")
CAMERA_MODE_KEYS = {
    "orbit": ("azimuth", "elevation", "distance", "target"),
    "look_at": ("position", "look_at"),
    "paper": ("reference_point", "view_up", "view_plane_normal", "eye"),
}
CAMERA_KEYS = CAMERA_COMMON_KEYS + tuple(k for keys in CAMERA_MODE_KEYS.values() for k in keys)
TRANSFER_KEYS = ("opacity", "color", "gradient_opacity", "unit_distance", "units", "preset")
SHADING_KEYS = ("enabled", "ambient", "diffuse", "specular", "shininess", "two_sided", "light")
LIGHT_KEYS = ("direction", "intensity", "color")
CUT_KEYS = ("point", "normal")
RENDER_KEYS = ("method", "early_termination", "footprint_radius", "footprint_sigma", "footprint_table",
               "precision", "threads", "sheets", "classification", "supersample")
VIEWS_KEYS = ("orbit_steps", "list", "path", "frames", "fps")
DEFAULT_PATH_FRAMES = 60

DEFAULT_LIGHT_DIRECTION = (-0.4, 0.6, 1.0)
ORTHONORMAL_TOLERANCE = 1e-3
# sin of the smallest angle accepted between an up vector and the viewing direction
PARALLEL_TOLERANCE = 1e-6
MAX_SPACING_RATIO = 1e6       # beyond it the thin axis's voxels project to nothing (docs/reliability.md)
SPACING_RANGE = (1e-30, 1e30)  # beyond it world coordinates lose the precision the camera needs
FOV_MAX = 180.0 * (1 - 1e-3)  # a wider field of view (within 1e-3 of 180, relative) leaves nothing visible

# --------------------------------------------------------------------------------------------------------------------
# Locator: key path -> line number, by scanning the TOML source

class _Scanner:
    """A structural TOML scanner: it computes no values, only where each key and array element starts.

    It assumes the text already parsed with tomllib; on anything unexpected it stops, keeping what it found.
    """

    _BARE = re.compile(r"[A-Za-z0-9_-]+")

    def __init__(self, text: str):
        self.s = text
        self.n = len(text)
        self.i = 0
        self.line = 1
        self.loc: dict[tuple, int] = {}
        self.explicit: set[tuple] = set()
        self.aot: dict[tuple, int] = {}  # resolved path of an array of tables -> number of elements so far

    # -- positions
    def _advance_to(self, j: int) -> None:
        self.line += self.s.count("\n", self.i, j)
        self.i = j

    def _record(self, path: tuple, line: int, explicit: bool = True) -> None:
        if path not in self.loc or (explicit and path not in self.explicit):
            self.loc[path] = line
        if explicit:
            self.explicit.add(path)

    def _record_prefixes(self, path: tuple, line: int) -> None:
        for k in range(1, len(path)):
            self._record(path[:k], line, explicit=False)

    # -- lexing
    def _skip_ws(self) -> None:
        s, i = self.s, self.i
        while i < self.n and s[i] in " \t":
            i += 1
        self.i = i

    def _skip_ws_nl_comments(self) -> None:
        while self.i < self.n:
            c = self.s[self.i]
            if c in " \t\r":
                self.i += 1
            elif c == "\n":
                self.i += 1
                self.line += 1
            elif c == "#":
                j = self.s.find("\n", self.i)
                self.i = self.n if j < 0 else j
            else:
                return

    def _expect(self, token: str) -> None:
        if not self.s.startswith(token, self.i):
            raise ValueError(f"expected {token!r} at line {self.line}")
        self.i += len(token)

    def _key(self) -> tuple[str, ...]:
        parts = []
        while True:
            self._skip_ws()
            c = self.s[self.i] if self.i < self.n else ""
            if c == '"':
                start = self.i
                self._basic_string()
                parts.append(tomllib.loads("k = " + self.s[start:self.i])["k"])
            elif c == "'":
                j = self.s.index("'", self.i + 1)
                parts.append(self.s[self.i + 1:j])
                self.i = j + 1
            else:
                m = self._BARE.match(self.s, self.i)
                if not m:
                    raise ValueError(f"expected a key at line {self.line}")
                parts.append(m.group())
                self.i = m.end()
            self._skip_ws()
            if self.i < self.n and self.s[self.i] == ".":
                self.i += 1
                continue
            return tuple(parts)

    def _basic_string(self) -> None:
        s, i = self.s, self.i + 1
        while s[i] != '"':
            i += 2 if s[i] == "\\" else 1
        self._advance_to(i + 1)

    def _multiline(self, quote: str) -> None:
        s, i = self.s, self.i + 3
        while True:
            if quote == '"' and s[i] == "\\":
                i += 2
                continue
            if s.startswith(quote * 3, i):
                i += 3
                extra = 0
                while extra < 2 and i < self.n and s[i] == quote:  # up to two quotes may end the content
                    i += 1
                    extra += 1
                break
            i += 1
        self._advance_to(i)

    # -- grammar
    def _value(self, path: tuple) -> None:
        s = self.s
        if s.startswith('"""', self.i):
            self._multiline('"')
        elif s.startswith("'''", self.i):
            self._multiline("'")
        elif s[self.i] == '"':
            self._basic_string()
        elif s[self.i] == "'":
            self.i = s.index("'", self.i + 1) + 1
        elif s[self.i] == "[":
            self.i += 1
            k = 0
            while True:
                self._skip_ws_nl_comments()
                if s[self.i] == "]":
                    self.i += 1
                    return
                self._record(path + (k,), self.line)
                self._value(path + (k,))
                k += 1
                self._skip_ws_nl_comments()
                if s[self.i] == ",":
                    self.i += 1
        elif s[self.i] == "{":
            self.i += 1
            while True:
                self._skip_ws_nl_comments()
                if s[self.i] == "}":
                    self.i += 1
                    return
                self._keyval(path)
                self._skip_ws_nl_comments()
                if s[self.i] == ",":
                    self.i += 1
        else:
            m = re.compile(r"[^,\]}#\r\n]*").match(s, self.i)
            self.i = m.end()

    def _keyval(self, prefix: tuple) -> None:
        line = self.line
        path = prefix + self._key()
        self._record_prefixes(path, line)
        self._record(path, line)
        self._expect("=")
        self._skip_ws()
        self._value(path)

    def _resolve(self, key: tuple[str, ...]) -> tuple:
        """Insert the current element index after every array of tables the header key passes through."""
        out: tuple = ()
        for part in key:
            out = out + (part,)
            if out in self.aot:
                out = out + (self.aot[out] - 1,)
        return out

    def run(self) -> dict[tuple, int]:
        current: tuple = ()
        try:
            while True:
                self._skip_ws_nl_comments()
                if self.i >= self.n:
                    break
                line = self.line
                if self.s.startswith("[[", self.i):
                    self.i += 2
                    key = self._key()
                    self._expect("]]")
                    head = self._resolve(key[:-1]) + (key[-1],)
                    count = self.aot.get(head, 0)
                    self.aot[head] = count + 1
                    current = head + (count,)
                    self._record_prefixes(current, line)
                    self._record(head, line)
                    self._record(current, line)
                elif self.s[self.i] == "[":
                    self.i += 1
                    key = self._key()
                    self._expect("]")
                    current = self._resolve(key)
                    self._record_prefixes(current, line)
                    self._record(current, line)
                else:
                    self._keyval(current)
        except (ValueError, IndexError, tomllib.TOMLDecodeError):
            pass  # keep the positions found so far: a missing line is better than a wrong one
        return self.loc


def locate_keys(text: str) -> dict[tuple, int]:
    """Map each key path in the TOML ``text`` to the 1-based line where it starts.

    Paths are tuples of table keys (str) and array indices (int): ``("shading", "light", 0, "direction")``,
    ``("transfer", "opacity", 2)``. A table is placed at its header, or at the first key that creates it.
    """
    return _Scanner(text).run()


# --------------------------------------------------------------------------------------------------------------------
# Formatting for messages

def _dotted(path: Iterable) -> str:
    out = ""
    for part in path:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            name = part if re.fullmatch(r"[A-Za-z0-9_-]+", part) else '"' + part.replace('"', '\\"') + '"'
            out += ("." if out else "") + name
    return out


def _fmt(value: Any, limit: int = 80) -> str:
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
            return "{" + ", ".join(f"{_dotted([k])} = {f(x)}" for k, x in v.items()) + "}"
        if hasattr(v, "isoformat"):
            return v.isoformat()
        return str(v)

    text = f(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _kind(value: Any) -> str:
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

class _Ctx:
    def __init__(self, source: str, text: str, base_dir: Path, set_args: dict[tuple, str],
                 density_window: tuple[float, float] | None = None):
        self.source = source
        self.loc = locate_keys(text)
        self.base_dir = base_dir
        self.set_args = set_args  # key path -> the --set argument that wrote it
        self.window = density_window   # given by the caller, else read from data.augmented when needed
        self.window_from = "the given density window"
        self.aug_source = None         # the augmented file's source attribute, for the re-augment hint
        self.window_used = False
        self.aug_units = "HU"          # the file's density_units once read (given windows are trusted)

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

    def fail(self, path: tuple, value: Any, expected: str) -> "NoReturn":  # noqa: F821
        raise IsplatError(f"{self.where(path)}: {_dotted(path)} = {_fmt(value)}: {expected}")

    def fail_msg(self, path: tuple | None, message: str, with_line: bool = True) -> "NoReturn":  # noqa: F821
        raise IsplatError(f"{self.where(path, with_line)}: {message}")

    def missing(self, path: tuple, why: str = "") -> "NoReturn":  # noqa: F821
        parent = path[:-1]
        arg = self.override_for(parent) if parent else None
        where = f"--set {arg}" if arg is not None else self.source
        raise IsplatError(f"{where}: missing required key '{_dotted(path)}'{why}")

    # -- tables
    def table(self, tree: dict, path: tuple, known: Iterable[str], label: str | None = None) -> dict:
        """The sub-table at ``path`` of ``tree`` ({} when absent), with unknown keys refused."""
        value = tree.get(path[-1], {}) if path else tree
        if not isinstance(value, dict):
            self.fail(path, value, f"expected a table ([{_dotted(path)}]), got {_kind(value)}")
        self.check_keys(value, path, known, label)
        return value

    def check_keys(self, table: dict, path: tuple, known: Iterable[str], label: str | None = None) -> None:
        known = sorted(known)
        for key in table:
            if key not in known:
                where = f"[{label or _dotted(path)}]" if path else "top-level keys"
                msg = (f"unknown key '{_dotted(path + (key,))}' "
                       f"(known {'keys in ' + where if path else where}: {', '.join(known)})")
                close = difflib.get_close_matches(key, known, n=1, cutoff=0.6)
                if close:
                    msg += f"; did you mean '{close[0]}'?"
                self.fail_msg(path + (key,), msg)

    # -- scalars
    def number(self, path: tuple, value: Any, expected: str, lo: float | None = None, hi: float | None = None,
               lo_open: bool = False, hi_open: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(path, value, f"{expected} (got {_kind(value)})")
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
            self.fail(path, value, f"{expected} (got {_kind(value) if not isinstance(value, float) else 'a float'})")
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            self.fail(path, value, expected)
        if allowed is not None and value not in allowed:
            self.fail(path, value, expected)
        return int(value)

    def boolean(self, path: tuple, value: Any) -> bool:
        if not isinstance(value, bool):
            self.fail(path, value, f"expected true or false (got {_kind(value)})")
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
            self.fail(path, value, f"expected a file path string (got {_kind(value)})")
        if value.strip() == "":
            self.fail(path, value, "expected a non-empty file path")
        p = Path(os.path.expanduser(value))
        # paths in the file are relative to the file's folder; paths given with --set to the working folder
        base = Path.cwd() if self.override_for(path) is not None else self.base_dir
        return Path(os.path.normpath(os.path.join(os.path.abspath(base), p)))


# --------------------------------------------------------------------------------------------------------------------
# Small vector helpers (pure Python: three components do not need numpy)

def _dot(a, b) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cross(a, b) -> Vec3:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _norm(a) -> float:
    return math.sqrt(_dot(a, a))


def _sub(a, b) -> Vec3:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _unit(a) -> Vec3:
    n = _norm(a)
    return (a[0] / n, a[1] / n, a[2] / n)


def _sin_angle(a, b) -> float:
    return _norm(_cross(a, b)) / (_norm(a) * _norm(b))


# --------------------------------------------------------------------------------------------------------------------
# Sections

def _data(ctx: _Ctx, tree: dict, method: str, required: bool = True) -> Data:
    t = ctx.table(tree, ("data",), DATA_KEYS)
    if not required and not t:
        return Data(None, None)
    if "augmented" not in t:
        ctx.missing(("data", "augmented"))
    augmented = ctx.path_value(("data", "augmented"), t["augmented"])
    index = None
    if "index" in t:
        index = ctx.path_value(("data", "index"), t["index"])
    elif method == "indexed":
        ctx.missing(("data", "index"), ' (render.method = "indexed" reads the index; use method = "full" without one)')
    data = Data(augmented, index)
    object.__setattr__(data, "_written", t["augmented"])  # not a field: equality and to_dict ignore it
    return data


def spacing_problem(spacing) -> str | None:
    """Why a voxel spacing cannot give a visible image (None when it can): degenerate ratios or magnitudes."""
    lo, hi = min(spacing), max(spacing)
    if not (SPACING_RANGE[0] <= lo and hi <= SPACING_RANGE[1]):
        return (f"spacing outside {SPACING_RANGE[0]:g}..{SPACING_RANGE[1]:g} world units loses the precision "
                f"the camera needs; rescale the units")
    if hi / lo > MAX_SPACING_RATIO:
        return (f"spacing ratio {hi / lo:.3g} exceeds {MAX_SPACING_RATIO:g}: the volume is flat to within a "
                f"pixel and renders as nothing")
    return None


def _image(ctx: _Ctx, tree: dict) -> Image:
    t = ctx.table(tree, ("image",), IMAGE_KEYS)
    p = ("image",)
    width = ctx.integer(p + ("width",), t.get("width", 256), "expected an integer number of pixels in 1..8192", 1, 8192)
    height = ctx.integer(p + ("height",), t.get("height", 256), "expected an integer number of pixels in 1..8192",
                         1, 8192)
    bg = ctx.vector(p + ("background",), t.get("background", [0.0, 0.0, 0.0]), sizes=(3, 4), lo=0.0, hi=1.0,
                    expected="expected 3 or 4 numbers in [0, 1] (RGB or RGBA)")
    if len(bg) == 3:
        bg = bg + (1.0,)
    bit_depth = ctx.integer(p + ("bit_depth",), t.get("bit_depth", 8), "expected 8 or 16", allowed=(8, 16))
    return Image(width, height, bg, bit_depth)


def _volume(ctx: _Ctx, tree: dict) -> Volume:
    t = ctx.table(tree, ("volume",), VOLUME_KEYS)
    p = ("volume",)
    spacing = None
    if "spacing" in t:
        spacing = ctx.vector(p + ("spacing",), t["spacing"], lo=0.0, lo_open=True,
                             expected="expected 3 numbers > 0 (i, j, k spacing in world units)")
        problem = spacing_problem(spacing)
        if problem:
            ctx.fail(p + ("spacing",), t["spacing"], problem)
    origin = None
    if "origin" in t:
        origin = ctx.vector(p + ("origin",), t["origin"], expected="expected 3 numbers (world position of voxel 0,0,0)")
    axes = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    if "axes" in t:
        raw = t["axes"]
        expected = "expected 3 orthonormal vectors [[ix,iy,iz],[jx,jy,jz],[kx,ky,kz]] (world directions of i, j, k)"
        if not isinstance(raw, list) or len(raw) != 3:
            ctx.fail(p + ("axes",), raw, expected)
        vecs = [ctx.vector(p + ("axes", n), raw[n], expected=expected) for n in range(3)]
        worst = max(abs(_dot(vecs[a], vecs[b]) - (1.0 if a == b else 0.0)) for a in range(3) for b in range(3))
        if worst > ORTHONORMAL_TOLERANCE:
            ctx.fail(p + ("axes",), raw, f"{expected}; off by {worst:.3g} (tolerance {ORTHONORMAL_TOLERANCE:g})")
        # Gram-Schmidt in i, j, k order removes the rounding of typed-in values
        i = _unit(vecs[0])
        j = _unit(_sub(vecs[1], tuple(_dot(vecs[1], i) * x for x in i)))
        k = vecs[2]
        k = _sub(k, tuple(_dot(k, i) * x for x in i))
        k = _unit(_sub(k, tuple(_dot(k, j) * x for x in j)))
        axes = (i, j, k)
    return Volume(spacing, origin, axes)


def _camera_mode(ctx: _Ctx, raw: dict, paths: dict[str, tuple]) -> str:
    """Explicit ``mode``, or the one mode whose keys are present; mixing two modes names both keys."""
    if "mode" in raw:
        mode = ctx.choice(paths["mode"], raw["mode"], tuple(CAMERA_MODE_KEYS))
        for key in raw:
            for other, keys in CAMERA_MODE_KEYS.items():
                if key in keys and other != mode:
                    ctx.fail(paths[key], raw[key],
                             f'not a key of camera mode "{mode}" ({key} belongs to mode "{other}")')
        return mode
    first: dict[str, str] = {}  # mode -> first key of it
    for key in raw:
        for mode, keys in CAMERA_MODE_KEYS.items():
            if key in keys:
                first.setdefault(mode, key)
    if len(first) > 1:
        (m1, k1), (m2, k2) = sorted(first.items(), key=lambda mk: _line_order(ctx, paths[mk[1]]))[:2]
        other = _dotted(paths[k1])
        if ctx.override_for(paths[k1]) is None and paths[k1] in ctx.loc:
            other += f" on line {ctx.loc[paths[k1]]}"
        elif ctx.override_for(paths[k1]) is not None:
            other += f" from --set {ctx.override_for(paths[k1])}"
        ctx.fail(paths[k2], raw[k2],
                 f"cannot be combined with {other}: {k2} belongs to camera mode \"{m2}\", "
                 f"{k1} to \"{m1}\"; use the keys of one mode")
    return next(iter(first), "orbit")


def _line_order(ctx: _Ctx, path: tuple) -> tuple:
    return (1 if ctx.override_for(path) else 0, ctx.loc.get(path, 0))


def _camera(ctx: _Ctx, raw: dict, paths: dict[str, tuple]) -> Camera:
    """Validate one camera from its raw keys; ``paths[key]`` is where each key came from (for messages)."""
    g = raw.get
    projection = ctx.choice(paths.get("projection", ("camera", "projection")), g("projection", "orthographic"),
                            ("orthographic", "perspective"))
    mode = _camera_mode(ctx, raw, paths)

    def pth(key):
        return paths.get(key, ("camera", key))

    up = (0.0, 0.0, 1.0)
    if "up" in raw:
        if mode == "paper":
            ctx.fail(pth("up"), raw["up"], 'not used in camera mode "paper" (the view-up vector there is view_up)')
        up = ctx.nonzero_unit(pth("up"), raw["up"], "a world up vector")
    zoom = ctx.number(pth("zoom"), g("zoom", 1.0), "expected a number > 0", lo=0.0, lo_open=True)
    fov = ctx.number(pth("fov"), g("fov", 30.0), "expected a number of degrees with 0 < fov < 180",
                     lo=0.0, hi=180.0, lo_open=True, hi_open=True)
    if projection == "perspective" and fov > FOV_MAX:
        ctx.fail(pth("fov"), fov, f"a field of view this close to 180 degrees shrinks the volume to nothing on "
                                  f"the image; expected fov <= {FOV_MAX:g}")
    near = ctx.number(pth("near"), g("near", 0.0), "expected a distance >= 0 in world units (0 = renderer default)",
                      lo=0.0)

    azimuth = ctx.number(pth("azimuth"), g("azimuth", 0.0), "expected a number of degrees")
    elevation = ctx.number(pth("elevation"), g("elevation", 0.0), "expected a number of degrees in -90..90",
                           lo=-90.0, hi=90.0)
    roll = ctx.number(pth("roll"), g("roll", 0.0), "expected a number of degrees")
    distance = None
    if "distance" in raw:
        distance = ctx.number(pth("distance"), raw["distance"], "expected a distance > 0 in world units",
                              lo=0.0, lo_open=True)
    target = ctx.vector(pth("target"), raw["target"], expected="expected 3 numbers (world point)") \
        if "target" in raw else None

    position = look_at = reference_point = view_up = view_plane_normal = eye = None
    if mode == "look_at":
        for key in ("position", "look_at"):
            if key not in raw:
                ctx.missing(pth(key), ' (camera mode "look_at" needs position and look_at)')
        position = ctx.vector(pth("position"), raw["position"], expected="expected 3 numbers (world point)")
        look_at = ctx.vector(pth("look_at"), raw["look_at"], expected="expected 3 numbers (world point)")
        direction = _sub(look_at, position)
        if _norm(direction) == 0.0:
            ctx.fail(pth("look_at"), raw["look_at"], "must differ from camera.position (no viewing direction)")
        if _sin_angle(up, direction) < PARALLEL_TOLERANCE:
            if "up" in raw:
                ctx.fail(pth("up"), raw["up"], "must not be parallel to the viewing direction look_at - position")
            ctx.fail(pth("look_at"), raw["look_at"], "the viewing direction look_at - position is parallel to the "
                     "default camera.up = [0, 0, 1]; set camera.up")
    elif mode == "paper":
        for key in ("reference_point", "view_up", "view_plane_normal"):
            if key not in raw:
                ctx.missing(pth(key), ' (camera mode "paper" needs reference_point, view_up and view_plane_normal)')
        reference_point = ctx.vector(pth("reference_point"), raw["reference_point"],
                                     expected="expected 3 numbers (the view reference point p, world)")
        view_plane_normal = ctx.nonzero_unit(pth("view_plane_normal"), raw["view_plane_normal"],
                                             "the view plane normal w")
        v = ctx.nonzero_unit(pth("view_up"), raw["view_up"], "the view-up vector v")
        if _sin_angle(v, view_plane_normal) < PARALLEL_TOLERANCE:
            ctx.fail(pth("view_up"), raw["view_up"], "must not be parallel to view_plane_normal")
        # v is taken in the view plane (its component along w removed), as PHIGS does with the view-up vector
        view_up = _unit(_sub(v, tuple(_dot(v, view_plane_normal) * x for x in view_plane_normal)))
        if projection == "perspective":
            if "eye" not in raw:
                ctx.missing(pth("eye"), ' (camera mode "paper" with projection = "perspective" needs the eye e)')
            eye = ctx.vector(pth("eye"), raw["eye"], expected="expected 3 numbers (the projection reference point e)")
            if _dot(_sub(eye, reference_point), view_plane_normal) <= 0.0:
                ctx.fail(pth("eye"), raw["eye"], "must lie in front of the view plane: "
                         "dot(eye - reference_point, view_plane_normal) > 0")
        elif "eye" in raw:
            ctx.fail(pth("eye"), raw["eye"], 'only used with projection = "perspective"')
    return Camera(projection, mode, azimuth, elevation, distance, roll, target, up, position, look_at,
                  reference_point, view_up, view_plane_normal, eye, zoom, fov, near)


def _points(ctx: _Ctx, path: tuple, value: Any, width: int, what: str, first_range: tuple[float, float | None],
            rest_range: tuple[float, float], first_name: str, rest_name: str, min_points: int,
            plural: str = "densities") -> tuple:
    expected = f"expected an array of [{what}] points"
    if not isinstance(value, list):
        ctx.fail(path, value, f"{expected} (got {_kind(value)})")
    if len(value) < min_points:
        ctx.fail(path, value, f"{expected}, at least {min_points}")
    out = []
    previous = None
    for n, point in enumerate(value):
        pp = path + (n,)
        if not isinstance(point, list) or len(point) != width:
            ctx.fail(pp, point, f"expected [{what}]: {width} numbers")
        for x in point:
            if isinstance(x, bool) or not isinstance(x, (int, float)):
                ctx.fail(pp, point, f"expected [{what}]: {width} numbers (got {_kind(x)})")
            if not math.isfinite(x):
                ctx.fail(pp, point, f"expected [{what}]: {width} finite numbers")
        x0 = point[0]
        lo, hi = first_range
        if x0 < lo or (hi is not None and x0 > hi):
            ctx.fail(pp, point, f"{first_name} must be in " + (f"[{lo:g}, {hi:g}]" if hi is not None else f">= {lo:g}"))
        if previous is not None and x0 <= previous:
            ctx.fail(pp, point, f"{plural} must be strictly increasing (the previous point has {_fmt(previous)})")
        previous = x0
        for x in point[1:]:
            if x < rest_range[0] or x > rest_range[1]:
                ctx.fail(pp, point, f"{rest_name} must be in [{rest_range[0]:g}, {rest_range[1]:g}]")
        out.append(tuple(float(x) for x in point))
    return tuple(out)


def _density_window(ctx: _Ctx, data: Data, path: tuple, value: Any) -> tuple[float, float]:
    """The augmented file's density window (read once), for converting data units; an error names ``path``."""
    if ctx.window is None:
        from .augfile import open_augmented

        why = "data units are converted through the augmented file's density window, which cannot be read"
        if data.augmented is None:
            ctx.fail(path, value, "data units are converted through the volume's density window: give it "
                                  "(parse_scene(..., density_window=(LO, HI))) for a volume in memory")
        if not data.augmented.exists():
            ctx.fail(path, value, f"{why}: {data.written} does not exist (augment the scan first)")
        try:
            aug = open_augmented(data.augmented)
        except IsplatError as exc:
            ctx.fail(path, value, f"{why}: {exc}")
        ctx.window, ctx.window_from = aug.density_window, data.written
        ctx.aug_source = aug.attrs.get("source")
        ctx.aug_units = aug.attrs.get("density_units")
    ctx.window_used = True
    return ctx.window


def _to_codes(ctx: _Ctx, data: Data, path: tuple, raw: list, points: tuple, units: str) -> tuple:
    """User points in ``units`` as codes; a data-unit point outside the window is an error with the fix."""
    if units == "code":
        return points
    window = _density_window(ctx, data, ("transfer", "units"), "data")
    lo, hi = window
    out = []
    for n, point in enumerate(points):
        code = float(_units.to_code(point[0], window))
        if not _units.inside(code):
            new = f"{min(lo, point[0]):g},{max(hi, point[0]):g}"
            src = ctx.aug_source or "SCAN"
            ctx.fail(path + (n,), raw[n], f"density {point[0]:g} (data units) is outside the density window "
                     f"{lo:g}..{hi:g} of {ctx.window_from}; re-augment with a window that includes it: "
                     f"isplat augment {src} -o OUT.aug.h5 --window={new}")
        out.append((min(max(code, 0.0), 255.0),) + tuple(point[1:]))
    return tuple(out)


def _preset_points(ctx: _Ctx, data: Data, preset, key: str) -> tuple:
    """A preset's opacity or colour as codes, restricted to the augmented file's window."""
    points = getattr(preset, key)
    if preset.units == "window":
        codes = tuple((x * 255.0, *rest) for x, *rest in points)
    else:
        window = _density_window(ctx, data, ("transfer", "preset"), preset.name)
        codes = tuple((float(_units.to_code(x, window)), *rest) for x, *rest in points)
        if ctx.aug_units != "HU" and key == "opacity":
            logging.getLogger(__name__).warning(
                f"isplat: warning: {ctx.where(('transfer', 'preset'))}: preset {preset.name} is in Hounsfield "
                f"units, but {data.written} does not record Hounsfield data (its window {window[0]:g}..{window[1]:g} "
                "is taken as HU)")
    clipped = _units.clip_points(codes, zero_outside=key == "opacity")
    if not clipped:
        lo, hi = ctx.window
        ctx.fail(("transfer", "preset"), preset.name,
                 f"its opacity ({points[0][0]:g}..{points[-1][0]:g} HU) lies outside the density window "
                 f"{lo:g}..{hi:g} of {ctx.window_from}; re-augment the scan with --window ct-full")
    return clipped


def _preset(ctx: _Ctx, t: dict):
    """The preset named by ``transfer.preset``, or None."""
    if "preset" not in t:
        return None
    from .presets import PRESETS

    name = t["preset"]
    if not isinstance(name, str) or name not in PRESETS:
        close = difflib.get_close_matches(str(name), list(PRESETS), n=1, cutoff=0.6)
        ctx.fail(("transfer", "preset"), name, "expected a preset name (isplat presets lists them): "
                 + ", ".join(PRESETS) + (f"; did you mean '{close[0]}'?" if close else ""))
    return PRESETS[name]


def _transfer(ctx: _Ctx, tree: dict, data: Data) -> Transfer:
    t = ctx.table(tree, ("transfer",), TRANSFER_KEYS)
    p = ("transfer",)
    preset = _preset(ctx, t)
    units = ctx.choice(p + ("units",), t.get("units", "data" if preset else "code"), ("code", "data"))
    if "opacity" not in t and preset is None:
        ctx.missing(p + ("opacity",))
    first = (0, 255) if units == "code" else (-math.inf, None)
    what = "density" if units == "code" else "value"

    def user(key, width, names, default, rest_name, min_points):
        pts = _points(ctx, p + (key,), t.get(key, default), width, names, first, (0, 1), "density", rest_name,
                      min_points)
        return _to_codes(ctx, data, p + (key,), t.get(key, default), pts, units)

    if "opacity" in t or preset is None:
        opacity = user("opacity", 2, f"{what}, opacity", None, "opacity", 1)
    else:
        opacity = _preset_points(ctx, data, preset, "opacity")
    if "color" in t:
        color = user("color", 4, f"{what}, r, g, b", None, "r, g, b", 1)
    elif preset is not None:
        color = _preset_points(ctx, data, preset, "color")
    else:
        color = ((0.0, 1.0, 1.0, 1.0),)   # white
    gradient = _points(ctx, p + ("gradient_opacity",), t.get("gradient_opacity", []), 2,
                       "gradient magnitude, factor", (0, None), (0, 1), "gradient magnitude", "factor", 0,
                       "gradient magnitudes")
    if gradient and units == "data":
        window = _density_window(ctx, data, ("transfer", "units"), "data")
        gradient = tuple((float(_units.gradient_to_code(m, window)), f) for m, f in gradient)
    unit = ctx.number(p + ("unit_distance",), t.get("unit_distance", preset.unit_distance if preset else 0.0),
                      "expected a distance >= 0 in world units (0 = renderer default)", lo=0.0)
    return Transfer(opacity, color, gradient, unit, units, preset.name if preset else None,
                    ctx.window if ctx.window_used else None)


def _shading(ctx: _Ctx, tree: dict) -> Shading:
    t = ctx.table(tree, ("shading",), SHADING_KEYS)
    p = ("shading",)
    enabled = ctx.boolean(p + ("enabled",), t.get("enabled", True))
    coeff = "expected a number >= 0"
    ambient = ctx.number(p + ("ambient",), t.get("ambient", 0.25), coeff, lo=0.0)
    diffuse = ctx.number(p + ("diffuse",), t.get("diffuse", 0.75), coeff, lo=0.0)
    specular = ctx.number(p + ("specular",), t.get("specular", 0.3), coeff, lo=0.0)
    shininess = ctx.number(p + ("shininess",), t.get("shininess", 24.0), "expected a number >= 1", lo=1.0)
    two_sided = ctx.boolean(p + ("two_sided",), t.get("two_sided", True))
    lights = []
    if "light" in t:
        raw = t["light"]
        if not isinstance(raw, list):
            ctx.fail(p + ("light",), raw, "expected an array of tables ([[shading.light]])")
        for n, lt in enumerate(raw):
            lp = p + ("light", n)
            if not isinstance(lt, dict):
                ctx.fail(lp, lt, "expected a table with direction, intensity, color")
            ctx.check_keys(lt, lp, LIGHT_KEYS, "[shading.light]")
            direction = ctx.nonzero_unit(lp + ("direction",), lt.get("direction", list(DEFAULT_LIGHT_DIRECTION)),
                                         "a direction towards the light (camera space)")
            intensity = ctx.number(lp + ("intensity",), lt.get("intensity", 1.0), "expected a number >= 0", lo=0.0)
            color = ctx.vector(lp + ("color",), lt.get("color", [1.0, 1.0, 1.0]), lo=0.0, hi=1.0,
                               expected="expected 3 numbers in [0, 1] (r, g, b)")
            lights.append(Light(direction, intensity, color))
    elif enabled:
        lights.append(Light(_unit(DEFAULT_LIGHT_DIRECTION), 1.0, (1.0, 1.0, 1.0)))
    return Shading(enabled, ambient, diffuse, specular, shininess, two_sided, tuple(lights))


def _cuts(ctx: _Ctx, tree: dict) -> tuple[Cut, ...]:
    raw = tree.get("cut", [])
    if not isinstance(raw, list):
        ctx.fail(("cut",), raw, "expected an array of tables ([[cut]])")
    cuts = []
    for n, c in enumerate(raw):
        cp = ("cut", n)
        if not isinstance(c, dict):
            ctx.fail(cp, c, "expected a table with point and normal")
        ctx.check_keys(c, cp, CUT_KEYS, "[cut]")
        point = ctx.vector(cp + ("point",), c.get("point", [0.0, 0.0, 0.0]),
                           expected="expected 3 numbers (world point)")
        normal = ctx.nonzero_unit(cp + ("normal",), c.get("normal", [1.0, 0.0, 0.0]), "a plane normal (world)")
        cuts.append(Cut(point, normal))
    return tuple(cuts)


def _render(ctx: _Ctx, tree: dict) -> RenderOptions:
    t = ctx.table(tree, ("render",), RENDER_KEYS)
    p = ("render",)
    method = ctx.choice(p + ("method",), t.get("method", "indexed"), ("indexed", "full"))
    early = ctx.number(p + ("early_termination",), t.get("early_termination", 0.99),
                       "expected an opacity in (0, 1] (1 = off)", lo=0.0, hi=1.0, lo_open=True)
    radius = ctx.number(p + ("footprint_radius",), t.get("footprint_radius", 2.5),
                        "expected a cut-off in Gaussian sigmas in 0.5..6", lo=0.5, hi=6.0)
    sigma = ctx.number(p + ("footprint_sigma",), t.get("footprint_sigma", 0.7),
                       "expected a sigma in voxel steps in 0.3..3", lo=0.3, hi=3.0)
    table = ctx.integer(p + ("footprint_table",), t.get("footprint_table", 1024),
                        f"expected an integer number of table entries in 16..{1 << 20}", 16, 1 << 20)
    precision = ctx.choice(p + ("precision",), t.get("precision", "float32"), ("float32", "float64"))
    threads = ctx.integer(p + ("threads",), t.get("threads", 0), "expected an integer >= 0 (0 = all cores)", lo=0)
    sheets = ctx.choice(p + ("sheets",), t.get("sheets", "axis"), ("axis", "image"))
    # "post" is the default from version 4 on; a file that says an older version keeps the splatting it was
    # written for, and image-aligned sheets splat pre-classified
    older = isinstance(tree.get("version"), int) and tree["version"] < 4
    default = "pre" if older or sheets == "image" else "post"
    classification = ctx.choice(p + ("classification",), t.get("classification", default), ("pre", "post"))
    if classification == "post" and sheets == "image":
        ctx.fail(p + ("classification",), classification, 'post-classification samples the slices of the '
                 'principal axis; it takes render.sheets = "axis"')
    supersample = ctx.integer(p + ("supersample",), t.get("supersample", 1),
                              f"expected an integer 1..{SUPERSAMPLE_MAX} (render at N times the width and height, "
                              "box-filtered down; 1 = off)", 1, SUPERSAMPLE_MAX)
    return RenderOptions(method, early, radius, sigma, table, precision, threads, sheets, classification,
                         supersample)


def _cameras(ctx: _Ctx, tree: dict) -> tuple[Camera, tuple[Camera, ...]]:
    raw_cam = ctx.table(tree, ("camera",), CAMERA_KEYS)
    cam_paths = {k: ("camera", k) for k in raw_cam}
    camera = _camera(ctx, raw_cam, cam_paths)
    views_t = ctx.table(tree, ("views",), VIEWS_KEYS)
    vp = ("views",)
    steps = ctx.integer(vp + ("orbit_steps",), views_t.get("orbit_steps", 0),
                        f"expected an integer >= 0, at most {MAX_VIEWS} views", lo=0, hi=MAX_VIEWS)
    vlist = views_t.get("list", [])
    if not isinstance(vlist, list):
        ctx.fail(vp + ("list",), vlist, "expected an array of camera tables, e.g. [{azimuth = 0}, {azimuth = 90}]")
    if steps > 0 and vlist:
        ctx.fail(vp + ("list",), vlist, "views.orbit_steps and views.list cannot both be given")
    if "path" in views_t or "frames" in views_t:
        if steps > 0 or vlist:
            key = "path" if "path" in views_t else "frames"
            ctx.fail(vp + (key,), views_t[key], "views.path cannot be combined with views.orbit_steps or views.list")
        return camera, _path_views(ctx, views_t, raw_cam, cam_paths)
    if steps > 0:
        if camera.mode != "orbit":
            ctx.fail(vp + ("orbit_steps",), steps, f'needs camera mode "orbit" (the camera is in mode "{camera.mode}")')
        return camera, tuple(replace(camera, azimuth=camera.azimuth + n * 360.0 / steps) for n in range(steps))
    if not vlist:
        return camera, (camera,)
    return camera, _merged_cameras(ctx, vp + ("list",), vlist, raw_cam, cam_paths)


def _merged_cameras(ctx: _Ctx, lp: tuple, entries: list, raw_cam: dict, cam_paths: dict) -> tuple[Camera, ...]:
    """Each entry's camera keys merged over [camera] and validated as a whole camera."""
    views = []
    for n, entry in enumerate(entries):
        ep = lp + (n,)
        if not isinstance(entry, dict):
            ctx.fail(ep, entry, "expected a table of camera keys, e.g. {azimuth = 90}")
        ctx.check_keys(entry, ep, CAMERA_KEYS, "camera")
        merged = dict(raw_cam)
        merged.update(entry)
        paths = dict(cam_paths)
        paths.update({k: ep + (k,) for k in entry})
        views.append(_camera(ctx, merged, paths))
    return tuple(views)


def _path_views(ctx: _Ctx, views_t: dict, raw_cam: dict, cam_paths: dict) -> tuple[Camera, ...]:
    """``views.path`` keyframes interpolated into ``views.frames`` cameras (isplat.camera_path)."""
    from .camera_path import PathError, interpolate

    vp = ("views",)
    if "path" not in views_t:
        ctx.fail(vp + ("frames",), views_t["frames"], "needs views.path (the keyframes to interpolate)")
    keys = views_t["path"]
    if not isinstance(keys, list) or len(keys) < 2:
        ctx.fail(vp + ("path",), keys, "expected an array of at least 2 camera tables (keyframes), "
                 "e.g. [{azimuth = 0}, {azimuth = 90, zoom = 2}]")
    frames = ctx.integer(vp + ("frames",), views_t.get("frames", DEFAULT_PATH_FRAMES),
                         f"expected an integer number of frames >= 2, at most {MAX_VIEWS}", lo=2, hi=MAX_VIEWS)
    cams = _merged_cameras(ctx, vp + ("path",), keys, raw_cam, cam_paths)
    try:
        return interpolate(list(cams), frames)
    except PathError as exc:
        if exc.field in keys[exc.key]:
            ctx.fail(vp + ("path", exc.key, exc.field), keys[exc.key][exc.field], str(exc))
        ctx.fail(vp + ("path", exc.key), keys[exc.key], str(exc))


# --------------------------------------------------------------------------------------------------------------------
# Overrides

_SET_PART = re.compile(r"^([A-Za-z0-9_-]+)(?:\[(\d+)\])?$")


def _apply_override(tree: dict, arg: str, set_args: dict[tuple, str]) -> None:
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
            raise IsplatError(f"--set {arg}: '{_dotted(path)}' is not a table")
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
            raise IsplatError(f"--set {arg}: '{_dotted(path)}' is not an array")
        if k > len(seq):
            raise IsplatError(f"--set {arg}: '{_dotted(path)}' has {len(seq)} elements; "
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


# --------------------------------------------------------------------------------------------------------------------
# Entry points

def _check_version(ctx: _Ctx, tree: dict) -> None:
    """First: a newer file's unknown keys are explained by its version, and an older one's version names
    the keys it may not use yet (formats/scene.md, Version)."""
    if "version" not in tree:
        return
    v = tree["version"]
    if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= SCENE_VERSION:
        ctx.fail(("version",), v, f"this isplat reads scene versions 1 to {SCENE_VERSION}")
    for path, since in KEYS_SINCE.items():
        table = tree.get(path[0])
        if since > v and isinstance(table, dict) and path[1] in table:
            ctx.fail(path, table[path[1]], f"this key is new in scene version {since}; the file says version = "
                                           f"{v} (write version = {since}, or leave version out)")


def parse_scene(text: str, base_dir: Path | str, source_name: str, overrides: Iterable[str] = (),
                data_required: bool = True, density_window: tuple[float, float] | None = None) -> Scene:
    """Parse and validate scene ``text``; relative data paths are taken from ``base_dir``.

    ``source_name`` starts every error message; ``overrides`` are ``--set key=value`` strings applied to the
    TOML tree before validation. ``data_required=False`` accepts a scene without ``[data]`` (its
    ``data.augmented`` is then None), for volumes already in memory (:meth:`isplat.selection.Selection.from_arrays`).
    Transfer points in data units are converted through ``density_window`` if given, else through the window
    recorded in ``data.augmented`` (read only then).
    """
    try:
        tree = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        msg = str(exc)
        m = re.search(r"\(at line (\d+), column \d+\)", msg)
        if m:
            line = m.group(1)
        elif "end of document" in msg:
            line = str(text.count("\n") + (0 if text.endswith("\n") else 1))
        else:
            line = None
        raise IsplatError(f"{source_name}{':' + line if line else ''}: TOML syntax error: {msg}") from None
    set_args: dict[tuple, str] = {}
    for arg in overrides:
        _apply_override(tree, arg, set_args)
    ctx = _Ctx(source_name, text, Path(base_dir), set_args, density_window)

    _check_version(ctx, tree)
    ctx.check_keys(tree, (), TOP_KEYS)
    render = _render(ctx, tree)
    data = _data(ctx, tree, render.method, data_required)
    image = _image(ctx, tree)
    volume = _volume(ctx, tree)
    camera, views = _cameras(ctx, tree)
    transfer = _transfer(ctx, tree, data)
    shading = _shading(ctx, tree)
    cuts = _cuts(ctx, tree)
    fps = ctx.number(("views", "fps"), ctx.table(tree, ("views",), VIEWS_KEYS).get("fps", 12.0),
                     "expected frames per second, 0 < fps <= 100", lo=0.0, hi=100.0, lo_open=True)
    return Scene(None, data, image, volume, camera, transfer, shading, cuts, render, views, fps)


def scene_to_dict(scene: Scene, relative_to: Path | str | None = None) -> dict:
    """The scene as plain JSON-ready values (tuples become lists; paths strings, relative to ``relative_to``)."""
    def plain(x):
        if isinstance(x, Path):
            if relative_to is not None and x.is_relative_to(os.path.abspath(relative_to)):
                return str(x.relative_to(os.path.abspath(relative_to)))
            return str(x)
        if hasattr(x, "__dataclass_fields__"):
            return {f: plain(getattr(x, f)) for f in x.__dataclass_fields__}
        if isinstance(x, (tuple, list)):
            return [plain(v) for v in x]
        return x
    return plain(scene)


def load_scene(path: str | os.PathLike, overrides: Iterable[str] = ()) -> Scene:
    """Read, parse and validate the scene file at ``path`` (see ``formats/scene.md``)."""
    p = Path(path)
    name = str(path)
    check_regular(p, "scene", MAX_SCENE_BYTES)          # a fifo would block; a huge file is refused unread
    try:
        raw = p.read_bytes()
    except FileNotFoundError:
        raise IsplatError(f"{name}: scene file does not exist") from None
    except IsADirectoryError:
        raise IsplatError(f"{name}: scene is a folder, expected a .toml file") from None
    except OSError as exc:
        raise IsplatError(f"{name}: cannot read the scene file ({exc.strerror})") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise IsplatError(f"{name}:{line}: the scene file is not UTF-8 text") from None
    if text.startswith("\ufeff"):
        text = text[1:]
    check_scene_text(name, text, overrides)    # size and nesting bounded before tomllib recurses
    scene = parse_scene(text, p.parent, name, overrides)
    return replace(scene, path=Path(os.path.abspath(p)))
