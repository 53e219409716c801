"""``isplat sample``: write a deterministic synthetic volume."""

from __future__ import annotations

import logging
import shlex

import click
import numpy as np

from ..errors import IsplatError
from ..fileio import atomic_output, check_output
from ..samples import DEFAULT_SHAPES, DTYPES, NAMES, ORIENTATIONS, make_sample
from ..volume_io import parse_triple
from .options import force_option, quiet_option

log = logging.getLogger(__name__)

_NAME_HELP = "\n".join(f"  {n:<17} {DTYPES[n]:<8} default {','.join(map(str, DEFAULT_SHAPES[n]))}" for n in NAMES)


def _fmt(x: float) -> str:
    return f"{x:.17g}"


def write_sample(arr: np.ndarray, spacing_ijk, out: str, force: bool, orientation: str | None = None) -> str:
    """Write ``arr[k, j, i]`` to ``out`` (.npy, .nrrd or .raw) atomically; return the augment command for it.

    ``orientation`` (a code such as ``LPS``, :mod:`isplat.orientation`): written into a .nrrd as its patient
    space and directions, else added to the command as ``--orientation``."""
    low = out.lower()
    if not low.endswith((".npy", ".nrrd", ".raw")):
        raise IsplatError(f"{out}: unknown output extension; expected .npy, .nrrd or .raw")
    check_output(out, force)
    sp = ",".join(_fmt(s) for s in spacing_ijk)
    cmd = ["isplat", "augment", out, "-o", out.rsplit(".", 1)[0] + ".aug.h5"]
    with atomic_output(out, force) as tmp:
        if low.endswith(".npy"):
            with open(tmp, "wb") as fh:  # a file object: np.save would append .npy to a name
                np.save(fh, np.ascontiguousarray(arr))
            cmd += ["--spacing", sp]
        elif low.endswith(".nrrd"):
            try:
                import nrrd
            except ImportError:
                raise IsplatError(f"{out}: writing .nrrd needs pynrrd: pip install 'isplat[nrrd]'") from None
            header = {"space dimension": 3, "space directions": np.diag(np.asarray(spacing_ijk, dtype=float)),
                      "space origin": np.zeros(3), "encoding": "raw", "endian": "little"}
            if orientation:
                from ..orientation import axes_from_code

                header.pop("space dimension")
                header["space"] = "left-posterior-superior"
                header["space directions"] = axes_from_code(orientation) * np.asarray(spacing_ijk, float)[:, None]
            nrrd.write(str(tmp), np.ascontiguousarray(arr), header, index_order="C")
        else:
            a = np.ascontiguousarray(arr, dtype=arr.dtype.newbyteorder("<"))
            a.tofile(tmp)
            nk, nj, ni = arr.shape
            cmd += ["--shape", f"{ni},{nj},{nk}", "--dtype", arr.dtype.name, "--byte-order", "little",
                    "--spacing", sp]
    if orientation and not low.endswith(".nrrd"):
        cmd += ["--orientation", orientation]
    return shlex.join(cmd)


def _write_labels(name: str, shape, out: str, force: bool) -> None:
    """The sample's label map at ``out`` (.npy) and its names at ``out`` with .json."""
    import json

    from ..samples import make_sample_labels

    if not out.lower().endswith(".npy"):
        raise IsplatError(f"{out}: --labels writes a .npy label map")
    names_out = out[:-4] + ".json"
    check_output(out, force)
    check_output(names_out, force)
    lab, names = make_sample_labels(name, shape)
    with atomic_output(out, force) as tmp, open(tmp, "wb") as fh:
        np.save(fh, lab)
    with atomic_output(names_out, force) as tmp:
        tmp.write_text(json.dumps({str(k): v for k, v in names.items()}, indent=1) + "\n")
    log.info(f"isplat sample: wrote {out} (labels {', '.join(f'{k} {v}' for k, v in names.items())}) and "
             f"{names_out} (their names)")


@click.command(epilog=f"\b\nSamples (dtype, default NI,NJ,NK):\n{_NAME_HELP}")
@click.argument("name", metavar="NAME", type=click.Choice(NAMES))
@click.option("-o", "--output", "out", required=True, metavar="FILE",
              help="Output file: .npy (array [k,j,i]), .nrrd (with spacing) or .raw (little-endian).")
@click.option("--shape", metavar="NI,NJ,NK", help="Volume size, i fastest (default: per sample, see below).")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the noise (head, engine).")
@click.option("--dtype", type=click.Choice(["uint8", "float32"]),
              help="Voxel type for sphere and two-density-cube (default float32 / uint8).")
@click.option("--background", type=float, default=0.0, metavar="VALUE",
              help="mr-head: raise every voxel by VALUE and widen the air's noise to VALUE/8 (a background that is "
                   "not zero, as the MNI152 template's 350-550).")
@click.option("--labels", "labels", metavar="FILE.npy", default=None,
              help="ct-chest: also write its painted solids as a label map (uint8 [k,j,i]) and their names beside "
                   "it (FILE.json), for isplat augment --labels and a scene's [labels] (docs/labels.md).")
@force_option
@quiet_option
def sample(name, out, shape, seed, dtype, background, force, labels):
    """Write the synthetic volume NAME to FILE and print the `isplat augment` command that reads it back.

    \b
    head            CT-like head (air, skin, skull, brain, ventricles), like the paper's H1
    engine          machined part (block, liners, bores, channels, ~1 % bolts), like E1/E2
    ct-head         the head in Hounsfield units (int16), with contrast-filled carotids and a metal filling
    ct-chest        a chest CT in Hounsfield units (int16): fat, muscle, lungs, heart, contrast aorta, spine
    mr-head         the head as a T1-weighted MRI (uint16, arbitrary units: fat bright, CSF and bone dark)
    marschner-lobb  Marschner & Lobb (1994) test signal, fM=6, alpha=0.25 on [-1,1]^3
    sphere, two-density-cube   small shapes for tests

    The head, ct-head, ct-chest and mr-head samples stand for a patient in the LPS orientation (i towards
    the patient's left, j posterior, k superior): a .nrrd records it, and the command printed for a .npy or
    .raw passes --orientation LPS. The printed command goes to stdout (pipe it to sh); log lines go to stderr.

    \b
    Example:
      isplat sample head -o head.npy
      isplat sample engine -o engine.raw --shape 128,128,55 | sh   # runs the printed augment command
      isplat sample mr-head -o mni-like.npy --background 450        # an MRI whose background is not zero
    """
    shp = parse_triple(shape, "--shape", int) if shape else None
    arr, spacing = make_sample(name, shp, seed, dtype, background)
    if labels is not None:
        _write_labels(name, shp, labels, force)
    cmd = write_sample(arr, spacing, out, force, ORIENTATIONS.get(name))
    if labels is not None:
        cmd += f" --labels {shlex.quote(labels)}"
    log.info(f"isplat sample: wrote {out} ({name}, {arr.dtype}, NI,NJ,NK={','.join(map(str, arr.shape[::-1]))}, "
             f"spacing {','.join(_fmt(s) for s in spacing)})")
    click.echo(cmd)
