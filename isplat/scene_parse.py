"""A parsed TOML tree -> :class:`~isplat.scene_schema.Scene`: each table checked against the schema through the
validation kit (isplat.scene_validate), absent keys given the dataclasses' defaults, camera paths interpolated,
transfer functions in data units and presets converted to density codes.

No file is opened here. Data units need the augmented file's density window; it comes in as ``density_window``:
a window ``(LO, HI)``, a :class:`DensityWindow`, or a provider ``f(data) -> DensityWindow`` called once, and only
when data units or a Hounsfield preset are used (isplat.scene.augmented_window reads the file's attributes). A
provider that cannot give one raises :class:`WindowUnavailable`; the reader adds the file, line and key.
"""

from __future__ import annotations

import difflib
import logging
import math
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Union

from . import units as _units
from .limits import MAX_VIEWS
from .scene_schema import (CAMERA_KEYS, CAMERA_MODE_KEYS, CUT_KEYS, DATA_KEYS, DEFAULT_ORBIT_STEPS,
                           DEFAULT_PATH_FRAMES, DEFAULTS_BEFORE, FOV_MAX, IDENTITY_AXES, IMAGE_KEYS, KEYS_SINCE,
                           LIGHT_KEYS, OLD_DEFAULT_MEANING, ORTHONORMAL_TOLERANCE, PARALLEL_TOLERANCE, RENDER_KEYS,
                           SCENE_VERSION, SHADING_KEYS, SLICE_STRIDE_MAX, STOP_EARLY_TERMINATION, SUPERSAMPLE_MAX,
                           TOP_KEYS, TRANSFER_KEYS, VIEW_CHOICES, VIEWS_KEYS, VOLUME_KEYS, Camera, Cut, Data, Image,
                           Light, RenderOptions, Scene, Shading, Transfer, Vec3, Volume, default_for, defaults,
                           spacing_problem, unit)
from .scene_validate import Ctx, Table, dotted, fmt, kind

__all__ = ["build_scene", "DensityWindow", "WindowUnavailable", "NO_WINDOW"]

log = logging.getLogger("isplat.scene")

NO_WINDOW = ("data units are converted through the volume's density window: give it "
             "(parse_scene(..., density_window=(LO, HI))) for a volume in memory")


@dataclass(frozen=True)
class DensityWindow:
    """The window data units are converted through, and what messages say of it."""

    window: tuple[float, float]
    name: str = "the given density window"   # "... outside the density window LO..HI of NAME"
    source: str | None = None                 # the scan the file was augmented from (the re-augment hint)
    units: str | None = "HU"                  # the file's density_units; a given window is taken as HU
    # () -> int[256] voxels per density code (the file's histogram), asked for only by a preset placed from the
    # data (isplat.presets.tissue_range); None: there is none (a window given alone)
    histogram: Callable[[], Any] | None = field(default=None, compare=False, hash=False, repr=False)


class WindowUnavailable(Exception):
    """A window provider's reason why there is no window (one line; the reader prefixes file, line and key)."""


WindowArg = Union[tuple, DensityWindow, Callable[[Data], DensityWindow], None]


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


def _sin_angle(a, b) -> float:
    return _norm(_cross(a, b)) / (_norm(a) * _norm(b))


# --------------------------------------------------------------------------------------------------------------------
# Sections

def _data(ctx: Ctx, tree: dict, method: str, required: bool = True) -> Data:
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


def _image(ctx: Ctx, tree: dict) -> Image:
    t = Table(ctx, ctx.table(tree, ("image",), IMAGE_KEYS), ("image",), defaults(Image))
    pixels = "expected an integer number of pixels in 1..8192"
    width = t.integer("width", pixels, 1, 8192)
    height = t.integer("height", pixels, 1, 8192)
    bg = t.vector("background", sizes=(3, 4), lo=0.0, hi=1.0,
                  expected="expected 3 or 4 numbers in [0, 1] (RGB or RGBA)")
    if len(bg) == 3:
        bg = bg + (1.0,)
    bit_depth = t.integer("bit_depth", "expected 8 or 16", allowed=(8, 16))
    return Image(width, height, bg, bit_depth)


def _volume(ctx: Ctx, tree: dict, version: Any = None) -> Volume:
    t = Table(ctx, ctx.table(tree, ("volume",), VOLUME_KEYS), ("volume",), defaults(Volume))
    spacing = t.vector("spacing", lo=0.0, lo_open=True,
                       expected="expected 3 numbers > 0 (i, j, k spacing in world units)")
    problem = spacing_problem(spacing) if spacing is not None else None
    if problem:
        t.fail("spacing", problem)
    origin = t.vector("origin", expected="expected 3 numbers (world position of voxel 0,0,0)")
    axes = t.read("axes", _axes, ctx, default=default_for(version, Volume, "volume", "axes"))
    return Volume(spacing, origin, axes)


def _axes(path: tuple, raw: Any, ctx: Ctx) -> tuple[Vec3, Vec3, Vec3]:
    """``volume.axes``: three orthonormal vectors, within a tolerance, made exactly so."""
    expected = "expected 3 orthonormal vectors [[ix,iy,iz],[jx,jy,jz],[kx,ky,kz]] (world directions of i, j, k)"
    if not isinstance(raw, list) or len(raw) != 3:
        ctx.fail(path, raw, expected)
    vecs = [ctx.vector(path + (n,), raw[n], expected=expected) for n in range(3)]
    worst = max(abs(_dot(vecs[a], vecs[b]) - (1.0 if a == b else 0.0)) for a in range(3) for b in range(3))
    if worst > ORTHONORMAL_TOLERANCE:
        ctx.fail(path, raw, f"{expected}; off by {worst:.3g} (tolerance {ORTHONORMAL_TOLERANCE:g})")
    # Gram-Schmidt in i, j, k order removes the rounding of typed-in values
    i = unit(vecs[0])
    j = unit(_sub(vecs[1], tuple(_dot(vecs[1], i) * x for x in i)))
    k = vecs[2]
    k = _sub(k, tuple(_dot(k, i) * x for x in i))
    k = unit(_sub(k, tuple(_dot(k, j) * x for x in j)))
    return (i, j, k)


def _camera_mode(ctx: Ctx, raw: dict, paths: dict[str, tuple]) -> str:
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
        other = dotted(paths[k1])
        if ctx.override_for(paths[k1]) is None and paths[k1] in ctx.loc:
            other += f" on line {ctx.loc[paths[k1]]}"
        elif ctx.override_for(paths[k1]) is not None:
            other += f" from --set {ctx.override_for(paths[k1])}"
        ctx.fail(paths[k2], raw[k2],
                 f"cannot be combined with {other}: {k2} belongs to camera mode \"{m2}\", "
                 f"{k1} to \"{m1}\"; use the keys of one mode")
    return next(iter(first), defaults(Camera)["mode"])


def _line_order(ctx: Ctx, path: tuple) -> tuple:
    return (1 if ctx.override_for(path) else 0, ctx.loc.get(path, 0))


def _camera(ctx: Ctx, raw: dict, paths: dict[str, tuple], version: Any = None) -> Camera:
    """Validate one camera from its raw keys; ``paths[key]`` is where each key came from (for messages)."""
    t = Table(ctx, raw, ("camera",), defaults(Camera), paths)
    view = t.choice("view", VIEW_CHOICES, default="none" if "up" in t else default_for(version, Camera, "camera",
                                                                                        "view"))
    if "view" in t and "up" in t and view not in ("auto", "none"):
        t.fail("up", f'not used with camera.view = "{view}" (a named view has its own up: superior, or anterior '
                     'from above and below)')
    projection = t.choice("projection", ("orthographic", "perspective"))
    mode = _camera_mode(ctx, raw, paths)
    if "up" in t and mode == "paper":
        t.fail("up", 'not used in camera mode "paper" (the view-up vector there is view_up)')
    up = t.nonzero_unit("up", "a world up vector")
    zoom = t.number("zoom", "expected a number > 0", lo=0.0, lo_open=True)
    fov = t.number("fov", "expected a number of degrees with 0 < fov < 180", lo=0.0, hi=180.0, lo_open=True,
                   hi_open=True)
    if projection == "perspective" and fov > FOV_MAX:
        ctx.fail(t.path("fov"), fov, f"a field of view this close to 180 degrees shrinks the volume to nothing on "
                                     f"the image; expected fov <= {FOV_MAX:g}")
    near = t.number("near", "expected a distance >= 0 in world units (0 = renderer default)", lo=0.0)
    azimuth = t.number("azimuth", "expected a number of degrees")
    elevation = t.number("elevation", "expected a number of degrees in -90..90", lo=-90.0, hi=90.0)
    roll = t.number("roll", "expected a number of degrees")
    distance = t.number("distance", "expected a distance > 0 in world units", lo=0.0, lo_open=True)
    target = t.vector("target", expected="expected 3 numbers (world point)")
    cam = Camera(projection, mode, azimuth, elevation, distance, roll, target, up, zoom=zoom, fov=fov, near=near,
                 view=view)
    if mode == "look_at":
        return _look_at(t, cam)
    if mode == "paper":
        return _paper(t, cam)
    return cam


def _look_at(t: Table, cam: Camera) -> Camera:
    """The ``look_at`` mode's keys: a position and the point it looks at."""
    for key in ("position", "look_at"):
        if key not in t:
            t.ctx.missing(t.path(key), ' (camera mode "look_at" needs position and look_at)')
    position = t.vector("position", expected="expected 3 numbers (world point)")
    look_at = t.vector("look_at", expected="expected 3 numbers (world point)")
    direction = _sub(look_at, position)
    if _norm(direction) == 0.0:
        t.fail("look_at", "must differ from camera.position (no viewing direction)")
    if _sin_angle(cam.up, direction) < PARALLEL_TOLERANCE:
        if "up" in t:
            t.fail("up", "must not be parallel to the viewing direction look_at - position")
        t.fail("look_at", "the viewing direction look_at - position is parallel to the default camera.up = "
                          "[0, 0, 1]; set camera.up")
    return replace(cam, position=position, look_at=look_at)


def _paper(t: Table, cam: Camera) -> Camera:
    """The ``paper`` mode's keys: the paper's view reference point, view-up vector, view plane normal, eye."""
    for key in ("reference_point", "view_up", "view_plane_normal"):
        if key not in t:
            t.ctx.missing(t.path(key), ' (camera mode "paper" needs reference_point, view_up and view_plane_normal)')
    reference_point = t.vector("reference_point", expected="expected 3 numbers (the view reference point p, world)")
    view_plane_normal = t.nonzero_unit("view_plane_normal", "the view plane normal w")
    v = t.nonzero_unit("view_up", "the view-up vector v")
    if _sin_angle(v, view_plane_normal) < PARALLEL_TOLERANCE:
        t.fail("view_up", "must not be parallel to view_plane_normal")
    # v is taken in the view plane (its component along w removed), as PHIGS does with the view-up vector
    view_up = unit(_sub(v, tuple(_dot(v, view_plane_normal) * x for x in view_plane_normal)))
    eye = None
    if cam.projection == "perspective":
        if "eye" not in t:
            t.ctx.missing(t.path("eye"), ' (camera mode "paper" with projection = "perspective" needs the eye e)')
        eye = t.vector("eye", expected="expected 3 numbers (the projection reference point e)")
        if _dot(_sub(eye, reference_point), view_plane_normal) <= 0.0:
            t.fail("eye", "must lie in front of the view plane: dot(eye - reference_point, view_plane_normal) > 0")
    elif "eye" in t:
        t.fail("eye", 'only used with projection = "perspective"')
    return replace(cam, reference_point=reference_point, view_up=view_up, view_plane_normal=view_plane_normal,
                   eye=eye)


def _points(ctx: Ctx, path: tuple, value: Any, width: int, what: str, first_range: tuple[float, float | None],
            rest_range: tuple[float, float], first_name: str, rest_name: str, min_points: int,
            plural: str = "densities") -> tuple:
    expected = f"expected an array of [{what}] points"
    if not isinstance(value, list):
        ctx.fail(path, value, f"{expected} (got {kind(value)})")
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
                ctx.fail(pp, point, f"expected [{what}]: {width} numbers (got {kind(x)})")
            if not math.isfinite(x):
                ctx.fail(pp, point, f"expected [{what}]: {width} finite numbers")
        x0 = point[0]
        lo, hi = first_range
        if x0 < lo or (hi is not None and x0 > hi):
            ctx.fail(pp, point, f"{first_name} must be in " + (f"[{lo:g}, {hi:g}]" if hi is not None else f">= {lo:g}"))
        if previous is not None and x0 <= previous:
            ctx.fail(pp, point, f"{plural} must be strictly increasing (the previous point has {fmt(previous)})")
        previous = x0
        for x in point[1:]:
            if x < rest_range[0] or x > rest_range[1]:
                ctx.fail(pp, point, f"{rest_name} must be in [{rest_range[0]:g}, {rest_range[1]:g}]")
        out.append(tuple(float(x) for x in point))
    return tuple(out)


class _Units:
    """Data units and presets -> density codes, through a window asked for once, when first needed."""

    def __init__(self, ctx: Ctx, data: Data, density_window: WindowArg):
        self.ctx, self.data, self.given, self.info = ctx, data, density_window, None

    @property
    def used(self) -> tuple[float, float] | None:
        """The window points were converted through (None when none was needed)."""
        return self.info.window if self.info is not None else None

    def window(self, path: tuple, value: Any) -> tuple[float, float]:
        """The density window; a provider that cannot give one fails on ``path = value``."""
        if self.info is None:
            given = self.given
            if callable(given):
                try:
                    given = given(self.data)
                except WindowUnavailable as exc:
                    self.ctx.fail(path, value, str(exc))
            if given is None:
                self.ctx.fail(path, value, NO_WINDOW)
            self.info = given if isinstance(given, DensityWindow) else DensityWindow(given)
        return self.info.window

    def to_codes(self, path: tuple, raw: list, points: tuple, units: str) -> tuple:
        """User points in ``units`` as codes; a data-unit point outside the window is an error with the fix."""
        if units == "code":
            return points
        window = self.window(("transfer", "units"), "data")
        lo, hi = window
        out = []
        for n, point in enumerate(points):
            code = float(_units.to_code(point[0], window))
            if not _units.inside(code):
                new = f"{min(lo, point[0]):g},{max(hi, point[0]):g}"
                src = self.info.source or "SCAN"
                self.ctx.fail(path + (n,), raw[n], f"density {point[0]:g} (data units) is outside the density window "
                              f"{lo:g}..{hi:g} of {self.info.name}; re-augment with a window that includes it: "
                              f"isplat augment {src} -o OUT.aug.h5 --window={new}")
            out.append((min(max(code, 0.0), 255.0),) + tuple(point[1:]))
        return tuple(out)

    def gradient(self, gradient: tuple) -> tuple:
        """Gradient-magnitude points in data units per world unit as codes."""
        window = self.window(("transfer", "units"), "data")
        return tuple((float(_units.gradient_to_code(m, window)), f) for m, f in gradient)

    def preset_points(self, preset, key: str) -> tuple:
        """A preset's opacity or colour as codes, restricted to the augmented file's window."""
        points = getattr(preset, key)
        if preset.units == "window":
            codes = tuple((x * 255.0, *rest) for x, *rest in points)
        elif preset.units == "tissue":
            from .presets import place

            self.window(("transfer", "preset"), preset.name)
            if self.info.histogram is None:
                self.ctx.fail(("transfer", "preset"), preset.name,
                              f"preset {preset.name} is placed from the data's density histogram, which "
                              f"{self.info.name} does not give (give the augmented file as data.augmented)")
            codes = place(points, self.info.histogram())
        else:
            window = self.window(("transfer", "preset"), preset.name)
            codes = tuple((float(_units.to_code(x, window)), *rest) for x, *rest in points)
            if self.info.units != "HU" and key == "opacity":
                log.warning(f"isplat: warning: {self.ctx.where(('transfer', 'preset'))}: preset {preset.name} is in "
                            f"Hounsfield units, but {self.data.written} does not record Hounsfield data (its window "
                            f"{window[0]:g}..{window[1]:g} is taken as HU)")
        clipped = _units.clip_points(codes, zero_outside=key == "opacity")
        if not clipped:
            lo, hi = self.info.window
            self.ctx.fail(("transfer", "preset"), preset.name,
                          f"its opacity ({points[0][0]:g}..{points[-1][0]:g} HU) lies outside the density window "
                          f"{lo:g}..{hi:g} of {self.info.name}; re-augment the scan with --window ct-full")
        return clipped


def _preset(ctx: Ctx, t: dict):
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


def _transfer(ctx: Ctx, tree: dict, data: Data, conv: "_Units") -> Transfer:
    """``[transfer]`` in density codes; a preset gives what the table leaves out (units "data", its unit
    distance), and the schema's defaults the rest."""
    t = Table(ctx, ctx.table(tree, ("transfer",), TRANSFER_KEYS), ("transfer",), defaults(Transfer))
    raw, p = t.raw, ("transfer",)
    preset = _preset(ctx, raw)
    units = t.choice("units", ("code", "data"), default="data" if preset else t.defaults["units"])
    if "opacity" not in raw and preset is None:
        ctx.missing(p + ("opacity",))
    first = (0, 255) if units == "code" else (-math.inf, None)
    what = "density" if units == "code" else "value"

    def user(key, width, names, rest_name):
        pts = _points(ctx, p + (key,), raw[key], width, names, first, (0, 1), "density", rest_name, 1)
        return conv.to_codes(p + (key,), raw[key], pts, units)

    opacity = user("opacity", 2, f"{what}, opacity", "opacity") if "opacity" in raw else \
        conv.preset_points(preset, "opacity")
    if "color" in raw:
        color = user("color", 4, f"{what}, r, g, b", "r, g, b")
    else:
        color = conv.preset_points(preset, "color") if preset is not None else t.defaults["color"]
    gradient = t.read("gradient_opacity", lambda path, value: _points(
        ctx, path, value, 2, "gradient magnitude, factor", (0, None), (0, 1), "gradient magnitude", "factor", 0,
        "gradient magnitudes"))
    if gradient and units == "data":
        gradient = conv.gradient(gradient)
    unit = t.number("unit_distance", "expected a distance >= 0 in world units (0 = renderer default)", lo=0.0,
                    default=float(preset.unit_distance) if preset else t.defaults["unit_distance"])
    return Transfer(opacity, color, gradient, unit, units, preset.name if preset else None, conv.used)


def _shading(ctx: Ctx, tree: dict) -> Shading:
    t = Table(ctx, ctx.table(tree, ("shading",), SHADING_KEYS), ("shading",), defaults(Shading))
    enabled = t.boolean("enabled")
    coeff = "expected a number >= 0"
    ambient = t.number("ambient", coeff, lo=0.0)
    diffuse = t.number("diffuse", coeff, lo=0.0)
    specular = t.number("specular", coeff, lo=0.0)
    shininess = t.number("shininess", "expected a number >= 1", lo=1.0)
    two_sided = t.boolean("two_sided")
    lights = t.read("light", _lights, ctx, default=t.defaults["lights"] if enabled else ())
    return Shading(enabled, ambient, diffuse, specular, shininess, two_sided, lights)


def _lights(path: tuple, raw: Any, ctx: Ctx) -> tuple[Light, ...]:
    if not isinstance(raw, list):
        ctx.fail(path, raw, "expected an array of tables ([[shading.light]])")
    lights = []
    for n, lt in enumerate(raw):
        if not isinstance(lt, dict):
            ctx.fail(path + (n,), lt, "expected a table with direction, intensity, color")
        ctx.check_keys(lt, path + (n,), LIGHT_KEYS, "[shading.light]")
        t = Table(ctx, lt, path + (n,), defaults(Light))
        direction = t.nonzero_unit("direction", "a direction towards the light (camera space)")
        intensity = t.number("intensity", "expected a number >= 0", lo=0.0)
        color = t.vector("color", lo=0.0, hi=1.0, expected="expected 3 numbers in [0, 1] (r, g, b)")
        lights.append(Light(direction, intensity, color))
    return tuple(lights)


def _cuts(ctx: Ctx, tree: dict) -> tuple[Cut, ...]:
    raw = tree.get("cut", [])
    if not isinstance(raw, list):
        ctx.fail(("cut",), raw, "expected an array of tables ([[cut]])")
    cuts = []
    for n, c in enumerate(raw):
        cp = ("cut", n)
        if not isinstance(c, dict):
            ctx.fail(cp, c, "expected a table with point and normal")
        ctx.check_keys(c, cp, CUT_KEYS, "[cut]")
        t = Table(ctx, c, cp, defaults(Cut))
        point = t.vector("point", expected="expected 3 numbers (world point)")
        normal = t.nonzero_unit("normal", "a plane normal (world)")
        cuts.append(Cut(point, normal))
    return tuple(cuts)


def _render(ctx: Ctx, tree: dict) -> RenderOptions:
    t = Table(ctx, ctx.table(tree, ("render",), RENDER_KEYS), ("render",), defaults(RenderOptions))
    method = t.choice("method", ("indexed", "full"))
    radius = t.number("footprint_radius", "expected a cut-off in Gaussian sigmas in 0.5..6", lo=0.5, hi=6.0)
    sigma = t.number("footprint_sigma", "expected a sigma in voxel steps in 0.3..3", lo=0.3, hi=3.0)
    table = t.integer("footprint_table", f"expected an integer number of table entries in 16..{1 << 20}", 16,
                      1 << 20)
    precision = t.choice("precision", ("float32", "float64"))
    threads = t.integer("threads", "expected an integer >= 0 (0 = all cores)", lo=0)
    sheets = t.choice("sheets", ("axis", "image"))
    # a file that says an older version keeps the splatting it was written for (DEFAULTS_BEFORE), and
    # image-aligned sheets splat pre-classified
    default = "pre" if sheets == "image" else default_for(tree.get("version"), RenderOptions, "render",
                                                          "classification")
    classification = t.choice("classification", ("pre", "post"), default=default)
    if classification == "post" and sheets == "image":
        ctx.fail(t.path("classification"), classification, 'post-classification samples the slices of the '
                 'principal axis; it takes render.sheets = "axis"')
    supersample = t.integer("supersample", f"expected an integer 1..{SUPERSAMPLE_MAX} (render at N times the width "
                            "and height, box-filtered down; 1 = off)", 1, SUPERSAMPLE_MAX)
    mode, color = _mode(ctx, t, classification, sheets)
    term = _termination(t, tree.get("version"), classification, mode)
    return RenderOptions(method, _early_termination(t, tree.get("version"), term), radius, sigma, table, precision,
                         threads, sheets, classification, supersample, mode, None, color,
                         _slice_stride(t, classification, mode), term)


def _early_termination(t: Table, version, term: str) -> float:
    """``render.early_termination``: an opacity in (0, 1]; by default RenderOptions' where a pixel that reaches it
    is filled (``term``), STOP_EARLY_TERMINATION where it is stopped and in a file before version 8."""
    default = default_for(version, RenderOptions, "render", "early_termination") if term == "fill" else \
        STOP_EARLY_TERMINATION
    return t.number("early_termination", "expected an opacity in (0, 1] (1 = off)", lo=0.0, hi=1.0, lo_open=True,
                    default=default)


def _termination(t: Table, version, classification: str, mode: str) -> str:
    """``render.termination``: "fill" (the default of version >= 7) or "stop"; the fill takes the colour of a
    post-classified composite sample, so "fill" is refused in one line with "pre" and with an intensity
    projection, whose default is "stop"."""
    post = classification == "post" and mode == "composite"
    default = default_for(version, RenderOptions, "render", "termination") if post else "stop"
    term = t.choice("termination", ("fill", "stop"), default=default)
    if term == "fill" and not post:
        t.fail("termination", 'a pixel is filled with the colour of its post-classified sample; "fill" takes '
               'render.classification = "post" and render.mode = "composite"')
    return term


def _slice_stride(t: Table, classification: str, mode: str) -> int:
    """``render.slice_stride``: an integer 1..SLICE_STRIDE_MAX; above 1 only for the post-classified composite
    (isplat.splat.post), refused in one line with "pre" and with an intensity projection."""
    n = t.integer("slice_stride", f"expected an integer 1..{SLICE_STRIDE_MAX} (sample every n-th slice of the "
                  "principal axis, the opacity corrected for the longer step; 1 = every slice)", 1, SLICE_STRIDE_MAX)
    if n > 1 and classification != "post":
        t.fail("slice_stride", 'render.slice_stride > 1 samples the post-classified slices; it takes '
                               'render.classification = "post"')
    if n > 1 and mode != "composite":
        t.fail("slice_stride", f'render.slice_stride > 1 corrects the opacity of a composited ray; it takes '
                               f'render.mode = "composite" (the mode is "{mode}")')
    return n


MODES = ("composite", "mip", "minip")


def _mode(ctx: Ctx, t: Table, classification: str, sheets: str) -> tuple[str, str]:
    """``render.mode`` and ``render.intensity_color``; an intensity projection samples the trilinear field of the
    principal axis's slices (isplat.splat.mip), so the paper's pre-classified splatting and image sheets are
    refused in one line, and keys that apply to an intensity projection only are refused with "composite"."""
    mode = t.choice("mode", MODES)
    color = t.choice("intensity_color", ("grey", "transfer"))
    if mode == "composite":
        for key in ("window", "intensity_color"):
            if key in t:
                t.fail(key, f'render.{key} applies to render.mode = "mip" or "minip" (the mode is "composite")')
        return mode, color
    if sheets == "image":
        t.fail("sheets", f'render.mode = "{mode}" samples the slices of the principal axis; it takes render.sheets '
                         '= "axis"')
    if classification != "post":
        ctx.fail(t.path("classification") if "classification" in t else t.path("mode"),
                 t.raw.get("classification", mode), f'render.mode = "{mode}" reconstructs the density as '
                 'render.classification = "post" does; it takes "post" (the default of version >= 4)')
    return mode, color


def _not_applied(ctx: Ctx, tree: dict, render: RenderOptions) -> None:
    """One warning line per key the scene gives that an intensity projection does not use (shading's lights and
    terms, early termination and what it does to a pixel, the footprint's keys: it reconstructs with the tent and
    finishes pixels by their bound). ``shading.enabled`` alone says nothing (shading is on by default;
    isplat.render always writes it)."""
    if render.mode == "composite":
        return
    shading = tree.get("shading") if isinstance(tree.get("shading"), dict) else {}
    given = [("shading", k) for k in shading if k != "enabled"]
    given += [("render", k) for k in ("early_termination", "termination", "footprint_radius", "footprint_sigma",
                                      "footprint_table") if k in (tree.get("render") or {})]
    for path in given:
        log.warning(f"isplat: warning: {ctx.where(path)}: {dotted(path)} does not apply to render.mode = "
                    f'"{render.mode}" (ignored)')


def _window(ctx: Ctx, tree: dict, render: RenderOptions, units: str, conv: "_Units") -> RenderOptions:
    """``render.window`` (an intensity projection's grey ramp: [LO, HI] in the transfer function's units, or a
    named window of isplat augment, in Hounsfield units) as density codes; absent: the whole range, 0..255."""
    raw = (tree.get("render") or {})
    if render.mode == "composite" or "window" not in raw:
        return render
    path, value = ("render", "window"), raw["window"]
    if isinstance(value, str):
        from .augment import NAMED_WINDOWS

        if value not in NAMED_WINDOWS:
            ctx.fail(path, value, "expected [LO, HI] or a named window: " + ", ".join(NAMED_WINDOWS))
        lo, hi = NAMED_WINDOWS[value]
        codes = tuple(float(_units.to_code(x, conv.window(path, value))) for x in (lo, hi))
    else:
        lo, hi = ctx.vector(path, value, 2, "expected [LO, HI], LO < HI, in the transfer function's units, or a "
                                            "named window")
        if not lo < hi:
            ctx.fail(path, value, "expected [LO, HI] with LO < HI")
        codes = (lo, hi) if units == "code" else tuple(float(_units.to_code(x, conv.window(path, value)))
                                                       for x in (lo, hi))
    return replace(render, window=codes)


def _cameras(ctx: Ctx, tree: dict) -> tuple[Camera, tuple[Camera, ...]]:
    raw_cam = ctx.table(tree, ("camera",), CAMERA_KEYS)
    cam_paths = {k: ("camera", k) for k in raw_cam}
    version = tree.get("version")
    camera = _camera(ctx, raw_cam, cam_paths, version)
    views_t = ctx.table(tree, ("views",), VIEWS_KEYS)
    vp = ("views",)
    steps = ctx.integer(vp + ("orbit_steps",), views_t.get("orbit_steps", DEFAULT_ORBIT_STEPS),
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
        return camera, _path_views(ctx, views_t, raw_cam, cam_paths, version)
    if steps > 0:
        if camera.mode != "orbit":
            ctx.fail(vp + ("orbit_steps",), steps, f'needs camera mode "orbit" (the camera is in mode "{camera.mode}")')
        return camera, tuple(replace(camera, azimuth=camera.azimuth + n * 360.0 / steps) for n in range(steps))
    if not vlist:
        return camera, (camera,)
    return camera, _merged_cameras(ctx, vp + ("list",), vlist, raw_cam, cam_paths, version)


def _merged_cameras(ctx: Ctx, lp: tuple, entries: list, raw_cam: dict, cam_paths: dict,
                    version: Any = None) -> tuple[Camera, ...]:
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
        views.append(_camera(ctx, merged, paths, version))
    return tuple(views)


def _path_views(ctx: Ctx, views_t: dict, raw_cam: dict, cam_paths: dict, version: Any = None) -> tuple[Camera, ...]:
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
    cams = _merged_cameras(ctx, vp + ("path",), keys, raw_cam, cam_paths, version)
    try:
        return interpolate(list(cams), frames)
    except PathError as exc:
        if exc.field in keys[exc.key]:
            ctx.fail(vp + ("path", exc.key, exc.field), keys[exc.key][exc.field], str(exc))
        ctx.fail(vp + ("path", exc.key), keys[exc.key], str(exc))


# --------------------------------------------------------------------------------------------------------------------
# The whole scene

def _check_version(ctx: Ctx, tree: dict) -> None:
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


def old_defaults_note(tree: dict, source_name: str) -> str | None:
    """The one line a scene of an older ``version`` gets (once per command, from the CLI): which of the defaults
    its version changed it keeps because it does not set them itself; None for a current or unversioned scene,
    or one that sets them all (formats/scene.md, Version).

    >>> print(old_defaults_note({"version": 1}, "head.toml"))   # doctest: +NORMALIZE_WHITESPACE
    head.toml: version = 1 keeps version-1 defaults: render.classification = "pre" (the paper's splatting),
    camera.view = "none" (the orbit about camera.up, not the anatomical front), volume.axes = identity (grid
    space, not the file's patient orientation); say version = 8 for the current defaults
    >>> print(old_defaults_note({"version": 6}, "s"))   # doctest: +NORMALIZE_WHITESPACE
    s: version = 6 keeps version-6 defaults: render.termination = "stop" (a pixel that reaches
    render.early_termination keeps its opacity, the background showing through the rest); say version = 8 for the
    current defaults
    >>> print(old_defaults_note({"version": 7}, "s"))   # doctest: +NORMALIZE_WHITESPACE
    s: version = 7 keeps version-7 defaults: render.early_termination = 0.99 (also where a pixel that reaches it is
    filled); say version = 8 for the current defaults
    >>> old_defaults_note({"version": 6, "render": {"classification": "pre"}}, "s")
    >>> old_defaults_note({"version": 7, "render": {"termination": "stop"}}, "s")
    >>> old_defaults_note({}, "s") is None and old_defaults_note({"version": 8}, "s") is None
    True
    """
    v = tree.get("version")
    if isinstance(v, bool) or not isinstance(v, int) or v >= SCENE_VERSION:
        return None
    kept = []
    for (table, key), (since, older) in DEFAULTS_BEFORE.items():
        t = tree.get(table)
        t = t if isinstance(t, dict) else {}
        if v >= since or key in t:
            continue
        if (table, key) == ("render", "classification") and t.get("sheets") == "image":
            continue                                  # image-aligned sheets splat pre-classified in every version
        if (table, key) == ("camera", "view") and "up" in t:
            continue                                  # camera.up means "none" in every version
        if (table, key) == ("render", "termination") and not _post_composite(v, t):
            continue                                  # pre-classified and intensity frames stop in every version
        if (table, key) == ("render", "early_termination") and not (_post_composite(v, t) and t.get(
                "termination", default_for(v, RenderOptions, "render", "termination")) == "fill"):
            continue                                  # a pixel that is stopped stops at 0.99 in every version
        shown = "identity" if older == IDENTITY_AXES else f'"{older}"' if isinstance(older, str) else str(older)
        kept.append(f"{table}.{key} = {shown} ({OLD_DEFAULT_MEANING[table, key]})")
    if not kept:
        return None
    return (f"{source_name}: version = {v} keeps version-{v} defaults: {', '.join(kept)}; say version = "
            f"{SCENE_VERSION} for the current defaults")


def _post_composite(version: int, render: dict) -> bool:
    """Whether a scene of ``version`` whose ``[render]`` table is ``render`` composites post-classified samples
    (the frames that ``render.termination`` applies to)."""
    classification = render.get("classification", default_for(version, RenderOptions, "render", "classification"))
    return (classification == "post" and render.get("sheets") != "image"
            and render.get("mode", "composite") == "composite")


def build_scene(ctx: Ctx, tree: dict, data_required: bool = True, density_window: WindowArg = None) -> Scene:
    """The validated scene of a TOML ``tree`` (``--set`` overrides already applied); ``ctx`` places its keys.

    ``data_required=False`` accepts a scene without ``[data]`` (for a volume in memory). ``density_window``:
    see the module's docstring; None fails on data units.
    """
    _check_version(ctx, tree)
    ctx.check_keys(tree, (), TOP_KEYS)
    render = _render(ctx, tree)
    data = _data(ctx, tree, render.method, data_required)
    image = _image(ctx, tree)
    volume = _volume(ctx, tree, tree.get("version"))
    camera, views = _cameras(ctx, tree)
    conv = _Units(ctx, data, density_window)
    transfer = _transfer(ctx, tree, data, conv)
    render = _window(ctx, tree, render, transfer.units, conv)
    shading = _shading(ctx, tree)
    _not_applied(ctx, tree, render)
    cuts = _cuts(ctx, tree)
    fps = Table(ctx, ctx.table(tree, ("views",), VIEWS_KEYS), ("views",), defaults(Scene)).number(
        "fps", "expected frames per second, 0 < fps <= 100", lo=0.0, hi=100.0, lo_open=True)
    from .scene_labels import parse_labels

    labels = parse_labels(ctx, tree)
    if labels.shown and render.mode != "composite":
        ctx.fail(("labels",), "...", f'labels are composited over the density; render.mode = "{render.mode}" '
                                     'shows one density per pixel (use mode = "composite", or leave [labels] out)')
    return Scene(None, data, image, volume, camera, transfer, shading, cuts, render, views, fps, labels)
