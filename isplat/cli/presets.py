"""``isplat presets``: the named transfer functions, one line each, or one of them as a [transfer] table."""

from __future__ import annotations

import click


@click.command("presets")
@click.argument("name", required=False, metavar="[NAME]")
@click.argument("augmented", required=False, metavar="[FILE.aug.h5]")
def presets(name, augmented):
    """List the transfer-function presets (transfer.preset = "NAME"): one line each, tab-separated:
    name, modality, units, what it shows, source. With NAME, print that preset as a [transfer] table; an MRI
    preset is placed from the data (fractions of the tissue range of the file's histogram: docs/presets.md), so
    its points in density codes need the augmented file, FILE.aug.h5.

    \b
    Example:
      isplat presets
      isplat presets ct-bone >> scene.toml
      isplat presets mri-t1-head head.aug.h5 >> scene.toml
    """
    from ..errors import IsplatError
    from ..presets import PRESETS, as_toml, describe

    if name is None:
        for p in PRESETS.values():
            click.echo(describe(p))
        return
    if name not in PRESETS:
        raise IsplatError(f"preset {name!r} unknown; expected one of {', '.join(PRESETS)}")
    counts = None
    if augmented is not None and PRESETS[name].units == "tissue":
        from ..augfile import open_augmented
        from ..stats import density_histogram

        counts = density_histogram(open_augmented(augmented))
    click.echo(as_toml(PRESETS[name], counts), nl=False)
