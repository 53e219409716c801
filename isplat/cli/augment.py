"""``isplat augment``: turn a scan into the augmented volume (density, gradient magnitude, normal)."""

from __future__ import annotations

import logging

import click

from ..volume_io import BYTE_ORDERS, RAW_DTYPES, parse_triple
from .options import force_option, quiet_option

log = logging.getLogger(__name__)


@click.command()
@click.argument("input", metavar="INPUT")
@click.option("-o", "--output", "out", required=True, metavar="OUT.aug.h5", help="Augmented HDF5 file to write.")
@force_option
@click.option("--window", metavar="LO,HI|NAME",
              help="Input values mapped to densities 0 and 255: numbers (write negative values as "
                   "--window=-1000,2000), percentiles of a strided subsample (p0.5,p99.9, or mixed: "
                   "--window=-1024,p99.9), or a name: ct-full (-1024..3071 HU), ct-bone (W2000/L300), "
                   "ct-soft-tissue (W400/L40), ct-lung (W1500/L-600), ct-brain (W80/L40). Default: ct-full for "
                   "Hounsfield data (a CT rescale in the file, or values starting at -1024, -2048 or about "
                   "-1000), else the 0.1 and 99.9 percentiles.")
@click.option("--spacing", metavar="SX,SY,SZ",
              help="Voxel spacing along i, j, k, in that order: i is the fastest axis (NI of --shape, the last "
                   "axis of a .npy's [k, j, i] shape), k the slices; e.g. --spacing 0.7,0.7,2.5 for 0.7 mm pixels "
                   "and 2.5 mm slices. Overrides the file's; without it, the file's, or 1,1,1 for .npy, raw and "
                   "TIFF (the spacing used and its source are printed).")
@click.option("--shape", metavar="NI,NJ,NK", help="Raw input: volume size, i fastest.")
@click.option("--dtype", metavar="TYPE", help=f"Raw input: voxel type, one of {', '.join(RAW_DTYPES)}.")
@click.option("--byte-order", type=click.Choice(sorted(BYTE_ORDERS)), default="little", show_default=True,
              help="Raw input: byte order.")
@click.option("--header-bytes", type=click.IntRange(min=0), default=0, show_default=True,
              help="Raw input: bytes to skip before the data.")
@click.option("--level", type=click.IntRange(min=0), default=None, metavar="N",
              help="OME-Zarr input: multiscale level to read (0 = full resolution, the default).")
@click.option("--series", metavar="UID", default=None,
              help="DICOM folder with several series: the SeriesInstanceUID to read (an error lists them).")
@click.option("--orientation", metavar="CODE", default=None,
              help="Where i, j, k point in the patient, three letters (LPS: i to the patient's left, j posterior, "
                   "k superior; RAS: NIfTI's identity): for input without an orientation (.npy, raw, TIFF, Zarr), "
                   "or to override the file's. Recorded as axes_lps for named views.")
@click.option("--index", "with_index", is_flag=True,
              help="Also build the index beside OUT (NAME.aug.h5 -> NAME.idx.h5) with its values and runs files, as "
                   "`isplat index` would.")
@click.option("--thin-slices", "thin", is_flag=True,
              help="Interpolate (linearly) along an axis whose spacing is more than twice the smallest, before "
                   "augmenting: for the paper's pre-classified splatting (render.classification = \"pre\"), whose "
                   "thick slices streak. The default, post-classified rendering already interpolates between "
                   "slices and gains nothing from it (docs/thick-slices.md); costs 2-4x the file and memory. "
                   "The window is the one given, or the one the scan gets without --thin-slices.")
@click.option("--bricks/--rows", default=True,
              help="--bricks (the default): store the channels in 8x8x8 bricks (augmented format 6), so that the "
                   "default, post-classified render reads only the bricks its scene needs (fewer bytes, less "
                   "memory held) and loads no slower than from rows. --rows: chunks of whole rows (format 4), read "
                   "whole (docs/selective-read.md).")
@click.option("--labels", "labels", metavar="MASK", default=None,
              help="A segmentation on the scan's grid (any input format above, e.g. mask.nii.gz or labels.npy): "
                   "integer label ids 0..65535 stored as the label channel (formats/augmented.md), shown by a "
                   "scene's [labels] table (docs/labels.md).")
@quiet_option
def augment(input, out, force, window, spacing, shape, dtype, byte_order, header_bytes, level, series, orientation,
            with_index, thin, bricks, labels):
    """Augment INPUT into 4-byte voxels: density, gradient magnitude, octahedral normal (formats/augmented.md).

    INPUT is a .npy array [k,j,i], a .nrrd/.nhdr, a .nii/.nii.gz, a multi-page .tif/.tiff, a folder of
    TIFF slices or of DICOM files (--series picks one of several), a MetaImage .mha/.mhd, VTK image
    data .vti, an InVesalius project .inv3, a Zarr array or OME-Zarr store (read lazily, --level picks
    the resolution), or raw data (a file, or - for stdin) with --shape and --dtype.
    Densities are 8-bit through --window; gradients are central differences of the windowed density in
    physical units (spacing-aware).

    \b
    Example:
      isplat sample head -o head.npy
      isplat augment head.npy -o head.aug.h5
      isplat augment chest.npy -o chest.aug.h5 --spacing 0.7,0.7,2.5   # i, j, k: 2.5 mm slices along k
      cat scan.raw | isplat augment - -o scan.aug.h5 --shape 256,256,225 --dtype uint16 --byte-order big
    """
    from ..augment import augment_file  # numba import only when the command runs
    from ..fileio import check_output
    from ..resample import THICK_RATIO

    idx = index_path(out) if with_index else None
    if idx is not None:
        from ..index.store import values_path
        from .index import check_runs_beside

        check_output(idx, force)  # before any work: the index, its values and runs files (formats/index.md §9.1, §12)
        check_output(values_path(idx), force)
        check_runs_beside(idx, force)
    win = window if window else None
    sp = parse_triple(spacing, "--spacing") if spacing else None
    shp = parse_triple(shape, "--shape", int) if shape else None
    info = augment_file(input, out, force=force, window=win, spacing=sp, shape=shp, dtype=dtype,
                        byte_order=byte_order, header_bytes=header_bytes, level=level, series=series,
                        thin_slices=THICK_RATIO if thin else None, orientation=orientation, labels=labels,
                        bricks=bricks)
    if info.get("labels") is not None:
        c = info["labels"]
        log.info(f"isplat augment: labels from {labels}: {int((c[1:] > 0).sum())} ids present (largest "
                 f"{len(c) - 1}), {int(c[1:].sum()):,} labelled voxels")
    for line in (spacing_line(info), orientation_line(info), window_line(info)):
        log.info(f"isplat augment: {line}")
    sp_out = info["spacing_ijk"]
    if not thin and max(sp_out) > THICK_RATIO * min(sp_out):
        log.info(f"isplat augment: slices {max(sp_out) / min(sp_out):.1f} times thicker than the smallest spacing; "
                 "pre-classified renders (render.classification = \"pre\") streak on them unless --thin-slices "
                 "interpolates them first (the default, post-classified, needs no --thin-slices)")
    log.info(f"isplat augment: wrote {out} (NI,NJ,NK={','.join(map(str, info['shape_ijk']))}, "
             f"gradient scale {info['gradient_magnitude_scale']:g}/code)")
    if idx is not None:
        from ..index import build_index_file

        from .index import write_runs_beside

        build_index_file(out, idx, force=force)
        write_runs_beside(out, idx, force, True)
        log.info(f"isplat augment: wrote {idx} (the index, all axes, its values and runs files)")


def index_path(out: str) -> str:
    """NAME.aug.h5 -> NAME.idx.h5 (else OUT + .idx.h5)."""
    return out[: -len(".aug.h5")] + ".idx.h5" if out.endswith(".aug.h5") else out + ".idx.h5"


def spacing_line(info: dict) -> str:
    """The spacing used, in i, j, k order, and where it came from (the file, --spacing or the default 1)."""
    sp = ",".join(f"{s:g}" for s in info["spacing_ijk"])
    src = info["spacing_source"]
    default = src.startswith("default")
    line = f"spacing {sp} (i, j, k): " + (f"the default{src[len('default 1,1,1'):]}" if default else f"from {src}")
    thin = info.get("thinned_from")
    if thin:
        line += f", refined by --thin-slices from {','.join(f'{s:g}' for s in thin['spacing_ijk'])}"
    if default:
        line += ("; give the scan's with --spacing SX,SY,SZ in i, j, k order (i the fastest axis: the last of a "
                 ".npy's [k, j, i] shape)")
    return line


def window_line(info: dict) -> str:
    """The window, how it was chosen, and the shares clipped at each end with what they probably are."""
    from ..augment import clipped_note

    lo, hi = info["density_window"]
    hu = info.get("hounsfield")
    method = info["density_window_method"]
    if hu and not method.startswith("Hounsfield"):
        method += f"; Hounsfield data: {hu}"
    parts = []
    for side, share, edge in (("below", info["clipped"][0], lo), ("above", info["clipped"][1], hi)):
        note = f" ({clipped_note(side, edge, bool(hu)).replace('LO,', f'{lo:g},')})" if share > 0 else ""
        parts.append(f"{100 * share:.2f}%{' of voxels' if side == 'below' else ''} {side} {edge:g}{note}")
    return f"window {lo:g},{hi:g}{' HU' if hu else ''} ({method}); clipped {', '.join(parts)}"


def orientation_line(info: dict) -> str:
    """The orientation recorded, and from where; or that there is none and what that means."""
    from ..orientation import describe

    if info["axes_lps"] is None:
        return (f"no orientation in {info['source_format']} input: named views (anterior, left, ...) are not "
                "available and the volume keeps voxel index space; give one with --orientation, e.g. LPS")
    return f"{describe(info['axes_lps'])} (from {info['orientation_source']})"
