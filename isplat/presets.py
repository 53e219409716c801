"""Transfer-function presets in the scan's own units, for ``transfer.preset = "NAME"`` (docs/presets.md).

CT presets are in Hounsfield units (``units = "data"``): they need an augmented file made from Hounsfield data,
and are converted through its density window like any ``transfer.units = "data"`` point. MRI and micro-CT
values have no calibrated unit, so those presets are written as fractions 0..1 of the density window
(``units = "window"``). Sources are stated per preset; where isplat adapted published values it says so.
"""

from __future__ import annotations

from dataclasses import dataclass

SLICER = "3D Slicer, Modules/Loadable/VolumeRendering/Resources/presets.xml"


@dataclass(frozen=True)
class Preset:
    name: str
    modality: str
    units: str                      # "data" (Hounsfield units) or "window" (fraction of the density window)
    summary: str
    source: str
    opacity: tuple
    color: tuple
    gradient_opacity: tuple = ()
    unit_distance: float = 0.0


def _p(*rows):
    return tuple(tuple(float(x) for x in r) for r in rows)


_SLICER_BONE_COLOR = _p([-16.4458, 0.729412, 0.254902, 0.301961], [641.385, 0.905882, 0.815686, 0.552941],
                        [3071, 1, 1, 1])
_SLICER_MUSCLE_COLOR = _p([-155.407, 0.54902, 0.25098, 0.14902], [217.641, 0.882353, 0.603922, 0.290196],
                          [419.736, 1, 0.937033, 0.954531])
_SLICER_LUNG_COLOR = _p([-1000, 0.3, 0.3, 1], [-600, 0, 0, 1], [-530, 0.134704, 0.781726, 0.0724558],
                        [-460, 0.929244, 1, 0.109473], [-400, 0.888889, 0.254949, 0.0240258], [2952, 1, 0.3, 0.3])
_SLICER_AAA = (_p([143.556, 0], [166.222, 0.686275], [214.389, 0.696078], [419.736, 0.833333], [3071, 0.803922]),
               _p([143.556, 0.615686, 0.356863, 0.184314], [166.222, 0.882353, 0.603922, 0.290196],
                  [214.389, 1, 1, 1], [419.736, 1, 0.937033, 0.954531], [3071, 0.827451, 0.658824, 1]))
_MR_DEFAULT_X = (0, 20, 40, 120, 220, 1024)   # Slicer MR-Default points, in MR scanner values


PRESETS = {p.name: p for p in [
    Preset("ct-bone", "CT", "data", "bone and teeth above 200-400 HU, skin and soft tissue transparent",
           f"{SLICER} CT-Bone colours (its -3024 HU point, below the opacity, dropped) and plateau opacity; "
           "opacity ramp moved by isplat from -16..641 HU to "
           "200..400 HU so that soft tissue (below about 100 HU) stays transparent",
           _p([200, 0], [400, 0.715686], [3071, 0.705882]), _SLICER_BONE_COLOR),
    Preset("ct-skin", "CT", "data", "the skin surface (air/tissue boundary near -400 HU), bone transparent",
           "isplat's own: a surface between air (-1000 HU) and skin (0..100 HU), cut off above soft tissue; "
           f"colours: {SLICER} CT-Muscle's points from -155 to 420 HU (its -3024 and 3071 HU points dropped)",
           _p([-500, 0], [-300, 0.6], [120, 0.6], [200, 0]), _SLICER_MUSCLE_COLOR),
    Preset("ct-soft-tissue", "CT", "data", "fat, muscle and organs (-160..240 HU) semi-transparent",
           "the soft-tissue display window W400/L40 (-160..240 HU) as the opacity's support, shape isplat's own; "
           f"colours: {SLICER} CT-Muscle's points from -155 to 420 HU (its -3024 and 3071 HU points dropped)",
           _p([-160, 0], [-100, 0.03], [30, 0.08], [140, 0.08], [240, 0]), _SLICER_MUSCLE_COLOR),
    Preset("ct-angio", "CT", "data", "contrast-filled vessels (150-400 HU) red-orange, bone white",
           f"{SLICER} CT-AAA, unchanged above 143.556 HU (its -3024 HU point has zero opacity and is dropped)",
           *_SLICER_AAA),
    Preset("ct-lung", "CT", "data", "aerated lung (-900..-600 HU) as a faint volume",
           "opacity isplat's own over the attenuation of aerated lung, inside the lung display window W1500/L-600; "
           f"colours from {SLICER} CT-Lung",
           _p([-950, 0], [-870, 0.05], [-700, 0.05], [-580, 0]), _SLICER_LUNG_COLOR),
    Preset("mri-t1-head", "MRI", "window", "head tissue over the background of a T1 MRI",
           f"{SLICER} MR-Default with its points (0..1024 scanner values) divided by 1024 into fractions of the "
           "density window (isplat's adaptation: MRI values have no calibrated unit)",
           tuple((x / 1024, a) for x, a in zip(_MR_DEFAULT_X[1:], (0, 0.15, 0.3, 0.375, 0.5))),
           tuple((x / 1024, *c) for x, c in zip(_MR_DEFAULT_X[1:], (
               (0.168627, 0, 0), (0.403922, 0.145098, 0.0784314), (0.780392, 0.607843, 0.380392),
               (0.847059, 0.835294, 0.788235), (1, 1, 1))))),
    Preset("micro-ct", "micro-CT", "window", "dense phases opaque, the lighter solid translucent, air hidden",
           "isplat's own (there is no common micro-CT convention): opacity over the upper 75% of a percentile "
           "window such as --window p0.5,p99.9",
           _p([0.25, 0], [0.45, 0.3], [0.7, 0.9], [1, 0.9]),
           _p([0.25, 0.55, 0.45, 0.35], [0.7, 0.95, 0.92, 0.85], [1, 1, 1, 1])),
    Preset("slicer-ct-bone", "CT", "data", "3D Slicer's CT-Bone as published (shows skin faintly)",
           f"{SLICER} CT-Bone, unchanged except the zero-opacity -3024 HU point",
           _p([-16.4458, 0], [641.385, 0.715686], [3071, 0.705882]), _SLICER_BONE_COLOR),
    Preset("slicer-ct-lung", "CT", "data", "3D Slicer's CT-Lung as published (a -600..-400 HU shell)",
           f"{SLICER} CT-Lung, unchanged", _p([-600, 0], [-599, 0.15], [-400, 0.15], [-399, 0]),
           _SLICER_LUNG_COLOR),
]}


def get(name: str) -> Preset:
    return PRESETS[name]


def describe(p: Preset) -> str:
    """One line: name, modality, units, summary and source."""
    unit = "HU" if p.units == "data" else "fraction of the window"
    return f"{p.name}\t{p.modality}\t{unit}\t{p.summary}\t(source: {p.source})"


def as_toml(p: Preset) -> str:
    """The preset as a [transfer] table to copy into a scene."""
    def rows(points):
        return "[" + ", ".join("[" + ", ".join(f"{x:g}" for x in r) + "]" for r in points) + "]"
    def codes(points):  # window fractions as density codes
        return points if p.units == "data" else tuple((x * 255.0, *rest) for x, *rest in points)
    lines = [f"# {p.name}: {p.summary}", f"# source: {p.source}", "[transfer]",
             f'units = "{"data" if p.units == "data" else "code"}"',
             f"opacity = {rows(codes(p.opacity))}", f"color = {rows(codes(p.color))}"]
    if p.gradient_opacity:
        lines.append(f"gradient_opacity = {rows(p.gradient_opacity)}")
    return "\n".join(lines) + "\n"
