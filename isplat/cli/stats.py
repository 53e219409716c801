"""isplat stats: dimensions, memory, index size, spatial ratio and what a scene loads (docs/stats.md)."""

from __future__ import annotations

import json
import sys

import click

from .options import force_option, quiet_option


@click.command("stats")
@click.argument("augmented", metavar="AUG.h5", type=click.Path(dir_okay=False))
@click.argument("index", metavar="[IDX.h5]", required=False, type=click.Path(dir_okay=False))
@click.option("--scene", "scene_file", metavar="SCENE.toml", default=None,
              help="Also report the scene's spatial ratio, the voxels its view splats and the bytes it loads "
                   "(the view is rendered once).")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE",
              help="Override a scene key, e.g. --set render.method=full (repeatable; needs --scene).")
@click.option("--view", "view", type=int, default=0, show_default=True, metavar="N",
              help="Which view of the scene's batch to render.")
@click.option("--json", "as_json", is_flag=True, help="Print the figures as one JSON object (keys: docs/stats.md).")
@click.option("--histogram", is_flag=True,
              help="Also print the density histogram in data units (Hounsfield units for CT) and percentiles.")
@click.option("--bins", type=int, default=32, show_default=True, metavar="N",
              help="Histogram bins: a power of two up to 256 (each holds 256/N density codes).")
@click.option("--plot", "plot", metavar="HIST.png", default=None,
              help="Write the histogram (log scale) with the presets' opacity ramps drawn over it: PNG, SVG or "
                   "PDF by the extension (needs matplotlib: pip install 'isplat[plot]').")
@force_option
@quiet_option
def stats(augmented, index, scene_file, overrides, view, as_json, histogram, bins, plot, force):
    """Report the figures of the paper's Figure 5 for AUG.h5 (and its index IDX.h5, and a scene).

    Without a scene: dimensions, voxel count, spacing, density window, bytes per channel; the index's
    bytes in total, per axis and per density range, and bytes per indexed voxel. With --scene: the
    spatial ratio (voxels in the transfer function's non-zero-opacity intervals over all voxels), the
    voxels the view examines and splats, and the bytes the scene reads against the whole files.

    The scene is applied to the files on the command line, whatever its data.augmented names; without
    IDX.h5 the index is the scene's own when it names AUG.h5, else the one beside AUG.h5 (same stem,
    .idx.h5) if there is one.

    --histogram adds the density histogram: each bin's range in data units (through the file's density
    window), its voxels and share, and percentiles; --plot draws it, with the opacity ramps of the presets
    that apply (CT presets on Hounsfield data, the window presets always), to find thresholds.

    \b
    Examples:
      isplat stats head.aug.h5
      isplat stats ct.aug.h5 --histogram --bins 64 --plot ct-hist.png
      isplat stats head.aug.h5 head.idx.h5 --scene head.toml
      isplat stats head.aug.h5 head.idx.h5 --scene head.toml --set 'transfer.opacity=[[100,0],[255,1]]' --json
    """
    from ..errors import IsplatError
    from ..stats import collect, format_histogram, format_table

    if overrides and scene_file is None:
        raise IsplatError("--set needs --scene SCENE.toml")
    figures = collect(augmented, index, scene=scene_file, overrides=list(overrides), view=view)
    if histogram or plot:
        _histogram(figures, augmented, bins, plot, force, histogram)
    if as_json:
        try:
            text = json.dumps(figures, sort_keys=False, allow_nan=False)     # strict JSON: no NaN, no Infinity
        except ValueError:
            raise IsplatError("a figure is not a finite number; please report this with the files") from None
        sys.stdout.write(text)
        sys.stdout.write("\n")
    else:
        sys.stdout.write(format_table(figures))
        if figures.get("histogram"):
            sys.stdout.write("\n" + format_histogram(figures["histogram"]))


def _histogram(figures, augmented, bins, plot, force, keep):
    """Add the histogram to ``figures`` (when ``keep``) and write its plot (when ``plot``)."""
    import logging

    from ..augfile import open_augmented
    from ..stats import histogram_section, plot_histogram

    if plot:
        from ..fileio import check_output

        check_output(plot, force)                                # before reading the volume
    h = histogram_section(open_augmented(augmented), bins)
    if keep:
        figures["histogram"] = h
    if plot:
        plot_histogram(h, plot, force, title=f"{augmented}: density histogram and preset opacity ramps")
        logging.getLogger(__name__).info(f"isplat stats: wrote {plot}")
