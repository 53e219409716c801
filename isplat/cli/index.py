"""``isplat index``: build the three-axis density index of an augmented volume (paper §2.1, §2.3)."""

from __future__ import annotations

import logging

import click

from .options import force_option, quiet_option

log = logging.getLogger(__name__)


@click.command("index")
@click.argument("augmented", metavar="AUG.h5")
@click.option("-o", "--output", required=True, metavar="OUT.idx.h5", help="Index file to write (HDF5).")
@click.option("--densities", default=None, metavar="LO:HI[,LO:HI...]",
              help="Index only these inclusive density ranges (default 0:255, all).")
@click.option("--axes", default="ijk", show_default=True, help="Slice axes to index: a subset of 'ijk'.")
@click.option("--no-values", "no_values", is_flag=True,
              help="Do not write OUT.values.idx.h5 (the indexed voxels' normals and gradient magnitudes, read only by "
                   "render.classification = \"pre\"; without it pre gathers them from AUG.h5).")
@click.option("--no-runs", "no_runs", is_flag=True,
              help="Do not write OUT.runs.idx.h5 (the channel bytes in range runs, formats/runs.md, which "
                   "post-classified frames read instead of the bricks; with --force, remove one left beside).")
@force_option
@quiet_option
def index(augmented, output, densities, axes, force, no_values, no_runs):
    """Index AUG.h5 by density, slice by slice, along each axis; write OUT.idx.h5 atomically, and beside it
    OUT.values.idx.h5, the channel values the pre-classified technique reads (formats/index.md §9), and
    OUT.runs.idx.h5, the channel bytes in runs by their neighbourhood's density range (formats/runs.md)."""
    from ..fileio import check_output
    from ..index import build_index_file, open_index, parse_axes, parse_ranges

    axes = parse_axes(axes)
    ranges = parse_ranges(densities) if densities is not None else None
    check_output(output, force)
    check_runs_beside(output, force)
    path = build_index_file(augmented, output, axes=axes, ranges=ranges, force=force, values=not no_values)
    write_runs_beside(augmented, path, force, not no_runs)
    if log.isEnabledFor(logging.INFO):
        idx = open_index(path)
        counts = {a: int(idx.voxel_counts(a).sum()) for a in idx.axes}
        size = path.stat().st_size
        n = next(iter(counts.values()))
        per = size / max(1, n * len(counts))
        vf = idx.values_file
        values = f"; values {vf.path} ({vf.path.stat().st_size} bytes)" if vf is not None else \
            "; no values file (--no-values: pre-classification gathers them from the augmented file)"
        from ..runsfile import runs_path

        rp = runs_path(path)
        runs = f"; runs {rp} ({rp.stat().st_size} bytes)" if not no_runs and rp.is_file() else ""
        log.info(f"isplat index: wrote {path} (axes {idx.axes}, {n} voxels indexed per axis, "
                 f"{size} bytes, {per:.3f} bytes per indexed voxel per axis){values}{runs}")


def check_runs_beside(index_path, force: bool) -> None:
    """Before any work: the runs file beside ``index_path`` may be written (new, or ``force``); with ``force`` a
    runs file of an earlier build is removed now, so that an interrupted build never leaves it beside a new
    index (formats/runs.md §1)."""
    from ..fileio import check_output
    from ..runsfile import runs_path

    rpath = check_output(runs_path(index_path), force)
    if force and rpath.is_file():
        rpath.unlink()


def write_runs_beside(augmented, index_path, force: bool, runs: bool) -> None:
    """The runs file beside the index just written (``isplat index``, ``isplat augment --index``)."""
    from ..runsfile import build_runs_file

    if runs:
        build_runs_file(augmented, index_path, force)
