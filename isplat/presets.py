"""Transfer-function presets in the scan's own units, for ``transfer.preset = "NAME"`` (docs/presets.md).

CT presets are in Hounsfield units (``units = "data"``): they need an augmented file made from Hounsfield data,
and are converted through its density window like any ``transfer.units = "data"`` point. MRI values have no
calibrated unit and their background is not always zero (a template's 350-550, a proton-density series' noise),
so the MRI preset is placed from the data (``units = "tissue"``): its points are fractions 0..1 of the *tissue
range* of the file's density histogram, 0 at the background threshold and 1 at the tissue's 99th percentile
(:func:`tissue_range`), computed when the scene is read. The micro-CT preset is in fractions 0..1 of the density
window (``units = "window"``). Sources are stated per preset; where isplat adapted published values it says so.
"""

from __future__ import annotations

from dataclasses import dataclass

SLICER = "3D Slicer, Modules/Loadable/VolumeRendering/Resources/presets.xml"


@dataclass(frozen=True)
class Preset:
    name: str
    modality: str
    units: str                      # "data" (Hounsfield units), "window" (fraction of the density window) or
                                    # "tissue" (fraction of the tissue range: tissue_range)
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
    Preset("mri-t1-head", "MRI", "tissue", "head tissue over the background of a T1 MRI",
           f"{SLICER} MR-Default, its points placed from the data by isplat (MRI values have no calibrated unit, "
           "and the background is not always zero): its 20 (where the opacity starts) at the background threshold "
           "and its 1024 at the tissue's 99th percentile, the points between in proportion (tissue_range)",
           tuple(((x - 20) / 1004, a) for x, a in zip(_MR_DEFAULT_X[1:], (0, 0.15, 0.3, 0.375, 0.5))),
           tuple(((x - 20) / 1004, *c) for x, c in zip(_MR_DEFAULT_X[1:], (
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


TISSUE_PERCENTILE = 99.0   # the tissue range's top: this percentile of the voxels above the background threshold


def otsu_threshold(counts) -> int:
    """Otsu's threshold of a histogram of density codes: the code ``t`` that maximises the between-class
    variance of ``codes <= t`` and ``codes > t`` (Otsu 1979; the usual head/background split of MRI, e.g. dipy's
    ``median_otsu``). 0 when the histogram holds one code or none."""
    import numpy as np

    h = np.asarray(counts, dtype=np.float64)
    n = h.sum()
    if n <= 0:
        return 0
    codes = np.arange(h.size, dtype=np.float64)
    w0 = np.cumsum(h)[:-1]                    # voxels with code <= t, t = 0..254
    m0 = np.cumsum(h * codes)[:-1]
    w1 = n - w0
    mu = (h * codes).sum()
    with np.errstate(divide="ignore", invalid="ignore"):
        between = np.where((w0 > 0) & (w1 > 0), (m0 * n - mu * w0) ** 2 / (w0 * w1), -1.0)
    return int(np.argmax(between)) if between.max() > 0 else 0


def tissue_range(counts) -> tuple[float, float]:
    """``(start, top)`` in density codes, from the file's histogram (int[256] voxels per density code): where
    a ``units = "tissue"`` preset's 0 and 1 lie. *start* is half a code above Otsu's threshold ``t``
    (:func:`otsu_threshold`: the background, air or a template's or scanner's offset and its noise, is the
    lower class), so the background's codes get a preset's first point; *top* is the :data:`TISSUE_PERCENTILE`
    percentile (numpy's ``inverted_cdf``) of the voxels above ``t``, at least one code above *start*."""
    import numpy as np

    h = np.asarray(counts, dtype=np.int64)
    t = otsu_threshold(h)
    above = h[t + 1:]
    start = t + 0.5
    if above.sum() == 0:
        return start, min(255.0, start + 1.0)
    cum = np.cumsum(above) / above.sum()
    top = float(t + 1 + int(np.searchsorted(cum, TISSUE_PERCENTILE / 100.0)))
    return start, max(top, start + 1.0)


def place(points, counts) -> tuple:
    """A ``units = "tissue"`` preset's points (fractions of the tissue range) as density codes for the data whose
    histogram is ``counts``."""
    start, top = tissue_range(counts)
    return tuple((start + x * (top - start), *rest) for x, *rest in points)


def get(name: str) -> Preset:
    return PRESETS[name]


def describe(p: Preset) -> str:
    """One line: name, modality, units, summary and source."""
    unit = {"data": "HU", "window": "fraction of the window", "tissue": "fraction of the tissue range"}[p.units]
    return f"{p.name}\t{p.modality}\t{unit}\t{p.summary}\t(source: {p.source})"


def as_toml(p: Preset, counts=None) -> str:
    """The preset as a [transfer] table to copy into a scene; a ``tissue`` preset placed on the histogram
    ``counts`` (int[256]), or as ``transfer.preset`` with its fractions in comments when none is given."""
    def rows(points):
        return "[" + ", ".join("[" + ", ".join(f"{x:g}" for x in r) + "]" for r in points) + "]"
    def codes(points):  # window fractions as density codes
        if p.units == "tissue":
            return place(points, counts)
        return points if p.units == "data" else tuple((x * 255.0, *rest) for x, *rest in points)
    if p.units == "tissue" and counts is None:
        return "\n".join([f"# {p.name}: {p.summary}", f"# source: {p.source}",
                          "# placed from the data when the scene is read: opacity and colour in fractions of the "
                          "tissue range", f"#   opacity = {rows(p.opacity)}", f"#   color = {rows(p.color)}",
                          "# (isplat presets NAME FILE.aug.h5 prints them in density codes for that file)",
                          "[transfer]", f'preset = "{p.name}"']) + "\n"
    lines = [f"# {p.name}: {p.summary}", f"# source: {p.source}", "[transfer]",
             f'units = "{"data" if p.units == "data" else "code"}"',
             f"opacity = {rows(codes(p.opacity))}", f"color = {rows(codes(p.color))}"]
    if p.gradient_opacity:
        lines.append(f"gradient_opacity = {rows(p.gradient_opacity)}")
    return "\n".join(lines) + "\n"
