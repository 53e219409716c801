"""docs/presets.md and its pictures: every preset rendered on a synthetic scan with the right value ranges.

    python scripts/presets_doc.py OUT_DIR DOCS_DIR      (make presets-doc; OUT_DIR holds the samples)

Samples: ct-head and ct-chest (Hounsfield units; window ct-full, detected), mr-head (T1-like, robust window),
the same with a background that is not zero (``isplat sample mr-head --background 450``: every voxel + 450, the
air's noise 450/8, as the MNI152 template's 350-550), engine (micro-CT stand-in, --window p0.5,p99.9). Each preset
is rendered with the scene below into DOCS_DIR/img/preset-NAME.png (the MRI preset on both MRI samples, and on
the raised background with its former fixed points too), the raised background's histogram with the presets'
ramps (``isplat stats --plot``) into DOCS_DIR/img/preset-hist-mr-head-bg.png, and the values and sources into
DOCS_DIR/presets.md.
"""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from isplat.augfile import open_augmented
from isplat.augment import augment_file
from isplat.index import build_index_file
from isplat.output import write_still
from isplat.presets import PRESETS, tissue_range
from isplat.stats import histogram_section, plot_histogram
from isplat.renderer import Renderer
from isplat.samples import make_sample
from isplat.scene import load_scene

SIZE = (160, 160, 140)
# the page's stamp (benchmarks/_doc.py; make docs-check): the technique of its pictures and what they depend on
TECHNIQUES = ["post"]         # the scene below: the default technique, post-classification, written out
SOURCES = ["isplat/presets.py", "isplat/scene_parse.py", "isplat/stats.py", "isplat/units.py", "isplat/augment.py", "isplat/samples.py", "isplat/frame.py",
           "isplat/renderer.py", "isplat/selection.py", "isplat/splat/**", "isplat/transfer.py", "isplat/scene.py",
           "isplat/output.py", "scripts/presets_doc.py"]
SAMPLE = {"ct-bone": "ct-head", "slicer-ct-bone": "ct-head", "ct-skin": "ct-head", "ct-soft-tissue": "ct-chest",
          "ct-angio": "ct-chest", "ct-lung": "ct-chest", "slicer-ct-lung": "ct-chest", "mri-t1-head": "mr-head",
          "micro-ct": "engine"}
WINDOW = {"engine": "p0.5,p99.9"}
BACKGROUND = 450.0            # mr-head-bg: isplat sample mr-head --background 450
# the MRI preset's points before they were placed from the data (fractions of the window: Slicer's MR-Default
# divided by 1024), shown on the raised background for comparison
OLD_MRI = ("[[4.98047, 0], [9.96094, 0.15], [29.8828, 0.3], [54.7852, 0.375], [255, 0.5]]",
           "[[4.98047, 0.168627, 0, 0], [9.96094, 0.403922, 0.145098, 0.0784314], "
           "[29.8828, 0.780392, 0.607843, 0.380392], [54.7852, 0.847059, 0.835294, 0.788235], [255, 1, 1, 1]]")
SCENE = """version = 4
[data]
augmented = "{aug}"
index = "{idx}"
[image]
width = 256
height = 256
[camera]
azimuth = {azimuth}
elevation = 15
zoom = 1.15
[transfer]
preset = "{name}"
unit_distance = 1.0
[shading]
ambient = 0.25
specular = 0.3
shininess = 30
[render]
classification = "post"
"""


def prepare(out: Path, sample: str) -> tuple[Path, Path]:
    if sample == "mr-head-bg":
        arr, spacing = make_sample("mr-head", SIZE, background=BACKGROUND)
    else:
        arr, spacing = make_sample(sample, SIZE)
    npy, aug, idx = out / f"{sample}.npy", out / f"{sample}.aug.h5", out / f"{sample}.idx.h5"
    np.save(npy, arr)
    augment_file(npy, aug, force=True, window=WINDOW.get(sample), spacing=spacing)
    build_index_file(aug, idx, force=True)
    return aug, idx


def render(out: Path, img: Path, name: str, files, tag: str = "", old: bool = False) -> None:
    """The preset ``name`` on ``files`` into img/preset-NAME[-TAG].png; ``old``: the MRI preset's former fixed
    points instead (codes, over the preset's name for the rest)."""
    aug, idx = files
    stem = f"preset-{name}" + (f"-{tag}" if tag else "")
    scene_file = out / f"{stem}.toml"
    text = SCENE.format(aug=aug.resolve(), idx=idx.resolve(), name=name,
                        azimuth=35 if SAMPLE[name] == "engine" else 20)
    if old:
        text = text.replace(f'preset = "{name}"', f'units = "code"\nopacity = {OLD_MRI[0]}\ncolor = {OLD_MRI[1]}')
    scene_file.write_text(text)
    rgba, _ = Renderer(load_scene(scene_file)).render_view(0)
    write_still(str(img / f"{stem}.png"), rgba, 8, force=True)


def _rows(points, scale):
    return "<br>".join("[" + ", ".join(f"{x * scale if n == 0 else x:g}" for n, x in enumerate(p)) + "]"
                       for p in points)


def _placed(p, files) -> str:
    """The tissue range of a placed preset on a sample: Otsu's threshold .. the 99th percentile, in codes and in
    the sample's values."""
    h = histogram_section(open_augmented(files[0]))
    counts = h["code_counts"]
    start, top = tissue_range(counts)
    a, b = h["tissue_range"]
    return f"codes {start:g} .. {top:g} ({a:.0f} .. {b:.0f} in the scan's values)"


def markdown(sizes, files) -> str:
    lines = ["# Transfer-function presets", "",
             "`transfer.preset = \"NAME\"` in a scene (formats/scene.md §4.5) or `isplat render FILE.aug.h5 --preset "
             "NAME`; `isplat presets` lists them and `isplat presets NAME` prints one as a `[transfer]` table. CT "
             "presets are in Hounsfield units and are converted through the augmented file's window (the default "
             "window for Hounsfield data, `ct-full`, holds them all). The micro-CT preset is in fractions of the "
             "window (shown here as density codes, fraction x 255). The MRI preset is **placed from the data**: "
             "MRI values have no calibrated unit and the background is not always zero, so its points are "
             "fractions of the *tissue range* of the file's density histogram, computed when the scene is read "
             "(`isplat.presets.tissue_range`; shown here as fractions):", "",
             "- **where the background ends**: Otsu's threshold of the histogram of density codes (the code that "
             "best splits the voxels into two classes by between-class variance; the background, air or a "
             "template's or scanner's offset with its noise, is the lower class, as in the usual head masking of "
             "MRI, e.g. dipy's `median_otsu`); the range starts half a code above it, so every background code "
             "gets the preset's first point (opacity 0);",
             "- **where the tissue ends**: the 99th percentile of the voxels above the threshold.", "",
             "The file's histogram is counted from its density channel (one byte per voxel, read once, only for "
             "such a preset); `isplat stats FILE.aug.h5 --histogram` prints the tissue range and `--plot` draws "
             "the presets' ramps where a scene places them (below). Where the background's noise reaches the "
             "tissue's values no threshold separates them.", "",
             f"Each picture is the preset on a synthetic scan ({'x'.join(map(str, sizes))} voxels, `isplat "
             "sample`), made by `make presets-doc` (scripts/presets_doc.py), which also writes this page; every "
             "picture is rendered with isplat's default technique, **post-classified** splatting "
             "(`render.classification = \"post\"`), and says so under it.", "",
             "| preset | shows | sample | opacity `[value, opacity]` | colour `[value, r, g, b]` | source | picture |",
             "|---|---|---|---|---|---|---|"]
    for p in PRESETS.values():
        scale = 255.0 if p.units == "window" else 1.0
        unit = {"data": "HU", "window": "codes", "tissue": "fractions of the tissue range"}[p.units]
        sample = SAMPLE[p.name]
        pic = f"![](img/preset-{p.name}.png)<br>post-classified"
        if p.units == "tissue":
            sample = (f"mr-head: {_placed(p, files['mr-head'])}<br>mr-head-bg (`--background {BACKGROUND:g}`): "
                      f"{_placed(p, files['mr-head-bg'])}")
            pic += (f"<br>![](img/preset-{p.name}-bg.png)<br>post-classified, on mr-head-bg<br>"
                    f"![](img/preset-{p.name}-bg-old.png)<br>post-classified, on mr-head-bg with the preset's former "
                    "fixed points (2%..100% of the window): the raised background opaque")
        lines.append(f"| `{p.name}` | {p.summary} | {sample} | {unit}:<br>{_rows(p.opacity, scale)} | "
                     f"{_rows(p.color, scale)} | {p.source} | {pic} |")
    lines += ["", "![](img/preset-hist-mr-head-bg.png)", "",
              f"`img/preset-hist-mr-head-bg.png`: `isplat stats mr-head-bg.aug.h5 --histogram --plot ...` of the MRI "
              f"sample with its background raised by {BACKGROUND:g}: the voxels per density code (log scale) and "
              "the opacity ramps of the presets for data that is not Hounsfield, `mri-t1-head` placed on this "
              "histogram.", "",
              "A preset sets `[transfer]` only (Slicer's presets also carry shading coefficients; the scene's "
              "`[shading]` applies here). tests/test_units_presets.py checks, voxel by voxel on these samples, that "
              "each preset gives its material opacity and leaves the others at zero (the MRI preset also on the "
              "raised background), and renders each one.", "",
              "Where a source is 3D Slicer, the values are those of its `presets.xml`; where isplat changed them "
              "the source column says how and why. The window names of `isplat augment --window` (`ct-bone` = "
              "W2000/L300, `ct-soft-tissue` = W400/L40, `ct-lung` = W1500/L-600, `ct-brain` = W80/L40) are the "
              "common radiology display windows (formats/augmented.md §4).", ""]
    return "\n".join(lines)


def main(out: str, docs: str) -> None:
    out_p, docs_p = Path(out), Path(docs)
    (docs_p / "img").mkdir(parents=True, exist_ok=True)
    out_p.mkdir(parents=True, exist_ok=True)
    files = {s: prepare(out_p, s) for s in sorted(set(SAMPLE.values()) | {"mr-head-bg"})}
    for name in PRESETS:
        render(out_p, docs_p / "img", name, files[SAMPLE[name]])
        print(f"presets_doc: {docs_p}/img/preset-{name}.png", file=sys.stderr)
        if PRESETS[name].units == "tissue":
            render(out_p, docs_p / "img", name, files["mr-head-bg"], "bg")
            render(out_p, docs_p / "img", name, files["mr-head-bg"], "bg-old", old=True)
    hist = histogram_section(open_augmented(files["mr-head-bg"][0]), bins=64)
    plot_histogram(hist, docs_p / "img" / "preset-hist-mr-head-bg.png", force=True,
                   title=f"isplat sample mr-head --background {BACKGROUND:g} (robust window)")
    rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    stamp = {"section": "presets", "commit": rev or "unknown", "command": "make presets-doc", "techniques": TECHNIQUES,
             "sources": SOURCES}
    (docs_p / "presets.md").write_text(f"<!-- isplat-stamp: {json.dumps(stamp)} -->\n" + markdown(SIZE, files))
    print(f"presets_doc: {docs_p}/presets.md", file=sys.stderr)


if __name__ == "__main__":
    main(*sys.argv[1:3])
