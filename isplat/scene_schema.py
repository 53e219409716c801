"""The scene schema: its frozen dataclasses (the contract with the renderer) with every default written once, as
the field's default, the known keys of each table, the version table and the limits the checks use.

The reader (isplat.scene_parse) takes an absent key's value from :func:`defaults` of the dataclass; the few
defaults that depend on other keys or on the file's ``version`` are said next to the field and in
:data:`DEFAULTS_BEFORE`. formats/scene.md is the user's copy of this.

>>> defaults(RenderOptions)["early_termination"], defaults(Image)["background"]
(0.986, (0.0, 0.0, 0.0, 1.0))
>>> [default_for(v, RenderOptions, "render", "early_termination") for v in (7, 8)]
[0.99, 0.986]
>>> [default_for(v, RenderOptions, "render", "classification") for v in (3, 4, None)]
['pre', 'post', 'post']
>>> [default_for(v, Camera, "camera", "view") for v in (4, 5)], default_for(4, Volume, "volume", "axes")[0]
(['none', 'auto'], (1.0, 0.0, 0.0))
"""

from __future__ import annotations

import math
from dataclasses import MISSING, dataclass, fields
from functools import cache
from pathlib import Path
from typing import Any

__all__ = [
    "SCENE_VERSION", "KEYS_SINCE", "DEFAULTS_BEFORE", "STOP_EARLY_TERMINATION", "OLD_DEFAULT_MEANING",
    "Scene", "Data", "Image", "Volume", "Camera", "Transfer", "Shading", "Light", "Cut", "RenderOptions", "Labels",
    "LabelStyle", "defaults", "default_for", "spacing_problem",
]

SCENE_VERSION = 8
IDENTITY_AXES = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
# keys added by each version after 1: a file that says an older version must not use them
KEYS_SINCE = {("transfer", "units"): 2, ("transfer", "preset"): 2, ("views", "path"): 2, ("views", "frames"): 2,
              ("views", "fps"): 2, ("render", "sheets"): 3,
              ("render", "classification"): 4, ("render", "supersample"): 4, ("camera", "view"): 5,
              ("render", "mode"): 6, ("render", "window"): 6, ("render", "intensity_color"): 6,
              ("labels", "names"): 6, ("labels", "show"): 6, ("labels", "opacity"): 6,
              ("render", "slice_stride"): 6, ("render", "termination"): 7}
# tables added by a version after 1 (the whole table is new)
TABLES_SINCE = {"labels": 6}
# render.early_termination where a pixel that reaches it is stopped (render.termination = "stop": "pre", the
# intensity projections, files before version 7) and in every frame of a file before version 8. Where it is
# filled, RenderOptions' default: the lowest opacity at which the fill was as close to the converged ray
# integral as the stop at 0.99 in every case of docs/termination.md (RMSE to four digits)
STOP_EARLY_TERMINATION = 0.99
# defaults a version changed: (table, key) -> (that version, the default of a file that says an older one)
DEFAULTS_BEFORE = {("render", "classification"): (4, "pre"), ("camera", "view"): (5, "none"),
                   ("volume", "axes"): (5, IDENTITY_AXES), ("render", "termination"): (7, "stop"),
                   ("render", "early_termination"): (8, STOP_EARLY_TERMINATION)}
# what each of those older defaults means, for the note a scene of an older version gets (old_defaults_note)
OLD_DEFAULT_MEANING = {("render", "classification"): "the paper's splatting",
                       ("camera", "view"): "the orbit about camera.up, not the anatomical front",
                       ("volume", "axes"): "grid space, not the file's patient orientation",
                       ("render", "termination"): "a pixel that reaches render.early_termination keeps its opacity, "
                                                  "the background showing through the rest",
                       ("render", "early_termination"): "also where a pixel that reaches it is filled"}
# camera.view: a named anatomical view (isplat.camera.NAMED_VIEWS), "auto" or "none" (class Camera)
NAMED_VIEW_NAMES = ("anterior", "posterior", "left", "right", "superior", "inferior")
VIEW_CHOICES = NAMED_VIEW_NAMES + ("auto", "none")

Vec3 = tuple[float, float, float]
SUPERSAMPLE_MAX = 8
SLICE_STRIDE_MAX = 64         # render.slice_stride: every n-th slice at most this far apart
DEFAULT_LIGHT_DIRECTION = (-0.4, 0.6, 1.0)   # towards the light, camera space; normalised as typed-in ones are


def unit(a) -> Vec3:
    """``a`` scaled to length 1."""
    n = math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
    return (a[0] / n, a[1] / n, a[2] / n)


# --------------------------------------------------------------------------------------------------------------------
# Output dataclasses (the contract with the renderer); a field's default is the value of an absent key

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
    width: int = 256
    height: int = 256
    background: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)   # an RGB one gets alpha 1
    bit_depth: int = 8


@dataclass(frozen=True)
class Volume:
    spacing: Vec3 | None = None   # None: the augmented file's
    origin: Vec3 | None = None
    axes: tuple[Vec3, Vec3, Vec3] | None = None   # None: the augmented file's axes_lps (world = patient space,
                                                  # LPS), or the identity without one; the identity before version 5


@dataclass(frozen=True)
class Camera:
    projection: str = "orthographic"
    mode: str = "orbit"           # absent: the mode whose keys are given (isplat.scene_parse._camera_mode)
    azimuth: float = 0.0
    elevation: float = 0.0
    distance: float | None = None
    roll: float = 0.0
    target: Vec3 | None = None
    up: Vec3 = (0.0, 0.0, 1.0)
    position: Vec3 | None = None
    look_at: Vec3 | None = None
    reference_point: Vec3 | None = None
    view_up: Vec3 | None = None
    view_plane_normal: Vec3 | None = None
    eye: Vec3 | None = None
    zoom: float = 1.0
    fov: float = 30.0
    near: float = 0.0
    view: str = "auto"            # orbit: a named view (NAMED_VIEW_NAMES; azimuth and elevation turn from it, in the
                                  # patient) of data with an orientation; "auto": "anterior" when the data has one,
                                  # else "none"; "none": azimuth and elevation about camera.up. "none" before
                                  # version 5 and when the scene gives camera.up


@dataclass(frozen=True)
class Transfer:
    """Always in density codes (0..255) for the renderer; ``units``, ``preset`` and ``density_window`` record
    what the scene said and the window its data-unit points were converted through (None for codes only)."""

    opacity: tuple[tuple[float, float], ...]   # required, unless a preset gives it
    color: tuple[tuple[float, float, float, float], ...] = ((0.0, 1.0, 1.0, 1.0),)   # white; a preset's
    gradient_opacity: tuple[tuple[float, float], ...] = ()
    unit_distance: float = 0.0    # 0 = renderer default; a preset's
    units: str = "code"           # "data" with a preset
    preset: str | None = None
    density_window: tuple[float, float] | None = None


@dataclass(frozen=True)
class Light:
    direction: Vec3 = unit(DEFAULT_LIGHT_DIRECTION)
    intensity: float = 1.0
    color: Vec3 = (1.0, 1.0, 1.0)


@dataclass(frozen=True)
class Shading:
    enabled: bool = True
    ambient: float = 0.25
    diffuse: float = 0.75
    specular: float = 0.3
    shininess: float = 24.0
    two_sided: bool = True
    lights: tuple[Light, ...] = (Light(),)   # without [[shading.light]]; none when shading is off


@dataclass(frozen=True)
class Cut:
    point: Vec3 = (0.0, 0.0, 0.0)
    normal: Vec3 = (1.0, 0.0, 0.0)


@dataclass(frozen=True)
class RenderOptions:
    method: str = "indexed"
    early_termination: float = 0.986      # where a pixel is filled (version 8); else STOP_EARLY_TERMINATION
    footprint_radius: float = 2.5
    footprint_sigma: float = 0.7
    footprint_table: int = 1024
    precision: str = "float32"
    threads: int = 0
    sheets: str = "axis"          # "axis": a sheet per slice; "image": slabs parallel to the image plane
    classification: str = "post"  # "pre": each voxel classified, then splatted; "post": density splatted,
                                  # then classified (isplat.splat.post). "pre" for image sheets and files that
                                  # say version < 4 (DEFAULTS_BEFORE)
    supersample: int = 1          # render at N times the width and height, box-filtered down
    mode: str = "composite"       # "mip" / "minip": the maximum / minimum of the reconstructed density along each
                                  # ray (isplat.splat.mip), version 6
    window: tuple[float, float] | None = None   # mip/minip: the density codes mapped to black..white (None: 0..255)
    intensity_color: str = "grey" # mip/minip: "grey" (the window's ramp) or "transfer" (the transfer's colour)
    slice_stride: int = 1         # post: sample every n-th slice of the principal axis (c % n == 0), each sample's
                                  # opacity corrected for the n slices' path (isplat.splat.post), version 6
    termination: str = "fill"     # post composite: "fill" a pixel that reaches early_termination takes the colour of
                                  # the sample that took it there for the rest of its transmittance, "stop" keeps
                                  # the opacity it reached (isplat.splat.composite.saturated), version 7; "stop"
                                  # for "pre", an intensity projection and files that say version < 7


@dataclass(frozen=True)
class LabelStyle:
    """A shown segmentation label (docs/labels.md): its id in the augmented file's label channel, colour and
    opacity (per unit distance, as the transfer function's), its name when a names map gave it."""

    id: int
    color: Vec3
    opacity: float = 1.0
    name: str | None = None

    @property
    def where(self) -> str:
        """Where the scene gave it (``FILE:LINE: labels.ID``, for messages about the data; set by the reader,
        not a field: it is not part of the scene's value)."""
        return self.__dict__.get("_where", "")


@dataclass(frozen=True)
class Labels:
    shown: tuple[LabelStyle, ...] = ()   # none: the label channel is not read
    names: Path | None = None            # the names map (CSV or JSON) the scene named
    opacity: float = 1.0                 # the opacity of a shown label that gives none


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
    labels: Labels = Labels()    # segmentation labels shown (scene version 6)


@cache
def defaults(cls: type) -> dict[str, Any]:
    """The field defaults of a schema dataclass: the values of absent keys."""
    return {f.name: f.default for f in fields(cls) if f.default is not MISSING}


def default_for(version: Any, cls: type, table: str, key: str) -> Any:
    """``cls``'s default for ``key``, or the older default for a file whose ``version`` predates a change."""
    since, older = DEFAULTS_BEFORE.get((table, key), (None, None))
    if since is not None and isinstance(version, int) and version < since:
        return older
    return defaults(cls)[key]


# --------------------------------------------------------------------------------------------------------------------
# Known keys per table, and the limits of the checks

TOP_KEYS = ("version", "data", "image", "volume", "camera", "transfer", "shading", "cut", "render", "views", "labels")
LABELS_KEYS = ("names", "show", "opacity")   # and one sub-table per shown label: [labels.ID] or [labels.NAME]
LABEL_KEYS = ("color", "opacity")
DATA_KEYS = ("augmented", "index")
IMAGE_KEYS = ("width", "height", "background", "bit_depth")
VOLUME_KEYS = ("spacing", "origin", "axes")
CAMERA_COMMON_KEYS = ("projection", "mode", "up", "roll", "zoom", "fov", "near")
CAMERA_MODE_KEYS = {
    "orbit": ("azimuth", "elevation", "distance", "target", "view"),
    "look_at": ("position", "look_at"),
    "paper": ("reference_point", "view_up", "view_plane_normal", "eye"),
}
CAMERA_KEYS = CAMERA_COMMON_KEYS + tuple(k for keys in CAMERA_MODE_KEYS.values() for k in keys)
TRANSFER_KEYS = ("opacity", "color", "gradient_opacity", "unit_distance", "units", "preset")
SHADING_KEYS = ("enabled", "ambient", "diffuse", "specular", "shininess", "two_sided", "light")
LIGHT_KEYS = ("direction", "intensity", "color")
CUT_KEYS = ("point", "normal")
RENDER_KEYS = ("method", "early_termination", "footprint_radius", "footprint_sigma", "footprint_table",
               "precision", "threads", "sheets", "classification", "supersample", "mode", "window",
               "intensity_color", "slice_stride", "termination")
VIEWS_KEYS = ("orbit_steps", "list", "path", "frames", "fps")
DEFAULT_ORBIT_STEPS = 0      # views.orbit_steps: 0 = no orbit
DEFAULT_PATH_FRAMES = 60     # views.frames of a views.path

ORTHONORMAL_TOLERANCE = 1e-3
# sin of the smallest angle accepted between an up vector and the viewing direction
PARALLEL_TOLERANCE = 1e-6
MAX_SPACING_RATIO = 1e6       # beyond it the thin axis's voxels project to nothing (docs/reliability.md)
SPACING_RANGE = (1e-30, 1e30)  # beyond it world coordinates lose the precision the camera needs
FOV_MAX = 180.0 * (1 - 1e-3)  # a wider field of view (within 1e-3 of 180, relative) leaves nothing visible


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
