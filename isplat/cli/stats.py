"""isplat stats: dimensions, memory, index size, spatial ratio and what a scene loads (docs/stats.md)."""

from __future__ import annotations

import json
import sys

import click

from .options import quiet_option


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
@quiet_option
def stats(augmented, index, scene_file, overrides, view, as_json):
    """Report the figures of the paper's Figure 5 for AUG.h5 (and its index IDX.h5, and a scene).

    Without a scene: dimensions, voxel count, spacing, density window, bytes per channel; the index's
    bytes in total, per axis and per density range, and bytes per indexed voxel. With --scene: the
    spatial ratio (voxels in the transfer function's non-zero-opacity intervals over all voxels), the
    voxels the view examines and splats, and the bytes the scene reads against the whole files.

    The scene must describe the same files: a data.augmented (or data.index) naming another file is an
    error; an index the scene does not name is taken from IDX.h5, and one it names is reported when
    IDX.h5 is not given.

    \b
    Examples:
      isplat stats head.aug.h5
      isplat stats head.aug.h5 head.idx.h5 --scene head.toml
      isplat stats head.aug.h5 head.idx.h5 --scene head.toml --set 'transfer.opacity=[[100,0],[255,1]]' --json
    """
    from ..errors import IsplatError
    from ..stats import collect, format_table

    if overrides and scene_file is None:
        raise IsplatError("--set needs --scene SCENE.toml")
    figures = collect(augmented, index, scene=scene_file, overrides=list(overrides), view=view)
    if as_json:
        try:
            text = json.dumps(figures, sort_keys=False, allow_nan=False)     # strict JSON: no NaN, no Infinity
        except ValueError:
            raise IsplatError("a figure is not a finite number; please report this with the files") from None
        sys.stdout.write(text)
        sys.stdout.write("\n")
    else:
        sys.stdout.write(format_table(figures))
