"""docs/presets.md and its pictures: every preset rendered on a synthetic scan with the right value ranges.

    python scripts/presets_doc.py OUT_DIR DOCS_DIR      (make presets-doc; OUT_DIR holds the samples)

Samples: ct-head and ct-chest (Hounsfield units; window ct-full, detected), mr-head (T1-like, robust window),
engine (micro-CT stand-in, --window p0.5,p99.9). Each preset is rendered with the scene below into
DOCS_DIR/img/preset-NAME.png, and its values and source are written into DOCS_DIR/presets.md.
"""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from isplat.augment import augment_file
from isplat.index import build_index_file
from isplat.output import write_still
from isplat.presets import PRESETS
from isplat.renderer import Renderer
from isplat.samples import make_sample
from isplat.scene import load_scene

SIZE = (160, 160, 140)
# the page's stamp (benchmarks/_doc.py; make docs-check): the technique of its pictures and what they depend on
TECHNIQUES = ["post"]         # the scene below: the default technique, post-classification, written out
SOURCES = ["isplat/presets.py", "isplat/units.py", "isplat/augment.py", "isplat/samples.py", "isplat/frame.py",
           "isplat/renderer.py", "isplat/selection.py", "isplat/splat/**", "isplat/transfer.py", "isplat/scene.py",
           "isplat/output.py", "scripts/presets_doc.py"]
SAMPLE = {"ct-bone": "ct-head", "slicer-ct-bone": "ct-head", "ct-skin": "ct-head", "ct-soft-tissue": "ct-chest",
          "ct-angio": "ct-chest", "ct-lung": "ct-chest", "slicer-ct-lung": "ct-chest", "mri-t1-head": "mr-head",
          "micro-ct": "engine"}
WINDOW = {"engine": "p0.5,p99.9"}
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
    arr, spacing = make_sample(sample, SIZE)
    npy, aug, idx = out / f"{sample}.npy", out / f"{sample}.aug.h5", out / f"{sample}.idx.h5"
    np.save(npy, arr)
    augment_file(npy, aug, force=True, window=WINDOW.get(sample), spacing=spacing)
    build_index_file(aug, idx, force=True)
    return aug, idx


def render(out: Path, img: Path, name: str, files) -> None:
    aug, idx = files
    scene_file = out / f"preset-{name}.toml"
    scene_file.write_text(SCENE.format(aug=aug.resolve(), idx=idx.resolve(), name=name,
                                       azimuth=35 if SAMPLE[name] == "engine" else 20))
    rgba, _ = Renderer(load_scene(scene_file)).render_view(0)
    write_still(str(img / f"preset-{name}.png"), rgba, 8, force=True)


def _rows(points, scale):
    return "<br>".join("[" + ", ".join(f"{x * scale if n == 0 else x:g}" for n, x in enumerate(p)) + "]"
                       for p in points)


def markdown(sizes) -> str:
    lines = ["# Transfer-function presets", "",
             "`transfer.preset = \"NAME\"` in a scene (formats/scene.md §4.5); `isplat presets` lists them and "
             "`isplat presets NAME` prints one as a `[transfer]` table. CT presets are in Hounsfield units and are "
             "converted through the augmented file's window (the default window for Hounsfield data, `ct-full`, "
             "holds them all); MRI and micro-CT values have no calibrated unit, so those presets are in fractions "
             "of the window (shown here as density codes, fraction x 255). Each picture is the preset on a "
             f"synthetic scan ({'x'.join(map(str, sizes))} voxels, `isplat sample`), made by "
             "`make presets-doc` (scripts/presets_doc.py), which also writes this page; every picture is "
             "rendered with isplat's default technique, post-classification (`render.classification = \"post\"`).",
             "",
             "| preset | shows | sample | opacity `[value, opacity]` | colour `[value, r, g, b]` | source | picture |",
             "|---|---|---|---|---|---|---|"]
    for p in PRESETS.values():
        scale = 1.0 if p.units == "data" else 255.0
        unit = "HU" if p.units == "data" else "codes"
        lines.append(f"| `{p.name}` | {p.summary} | {SAMPLE[p.name]} | {unit}:<br>{_rows(p.opacity, scale)} | "
                     f"{_rows(p.color, scale)} | {p.source} | ![](img/preset-{p.name}.png) |")
    lines += ["", "A preset sets `[transfer]` only (Slicer's presets also carry shading coefficients; the scene's "
              "`[shading]` applies here). tests/test_units_presets.py checks, voxel by voxel on these samples, that "
              "each preset gives its material opacity and leaves the others at zero, and renders each one.", "",
              "Where a source is 3D Slicer, the values are those of its `presets.xml`; where isplat changed them "
              "the source column says how and why. The window names of `isplat augment --window` (`ct-bone` = "
              "W2000/L300, `ct-soft-tissue` = W400/L40, `ct-lung` = W1500/L-600, `ct-brain` = W80/L40) are the "
              "common radiology display windows (formats/augmented.md §4).", ""]
    return "\n".join(lines)


def main(out: str, docs: str) -> None:
    out_p, docs_p = Path(out), Path(docs)
    (docs_p / "img").mkdir(parents=True, exist_ok=True)
    out_p.mkdir(parents=True, exist_ok=True)
    files = {s: prepare(out_p, s) for s in sorted(set(SAMPLE.values()))}
    for name in PRESETS:
        render(out_p, docs_p / "img", name, files[SAMPLE[name]])
        print(f"presets_doc: {docs_p}/img/preset-{name}.png", file=sys.stderr)
    rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    stamp = {"section": "presets", "commit": rev or "unknown", "command": "make presets-doc", "techniques": TECHNIQUES,
             "sources": SOURCES}
    (docs_p / "presets.md").write_text(f"<!-- isplat-stamp: {json.dumps(stamp)} -->\n" + markdown(SIZE))
    print(f"presets_doc: {docs_p}/presets.md", file=sys.stderr)


if __name__ == "__main__":
    main(*sys.argv[1:3])
