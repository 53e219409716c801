"""``isplat presets``: the named transfer functions, one line each, or one of them as a [transfer] table."""

from __future__ import annotations

import click


@click.command("presets")
@click.argument("name", required=False, metavar="[NAME]")
def presets(name):
    """List the transfer-function presets (transfer.preset = "NAME"): one line each, tab-separated:
    name, modality, units, what it shows, source. With NAME, print that preset as a [transfer] table.

    \b
    Example:
      isplat presets
      isplat presets ct-bone >> scene.toml
    """
    from ..errors import IsplatError
    from ..presets import PRESETS, as_toml, describe

    if name is None:
        for p in PRESETS.values():
            click.echo(describe(p))
        return
    if name not in PRESETS:
        raise IsplatError(f"preset {name!r} unknown; expected one of {', '.join(PRESETS)}")
    click.echo(as_toml(PRESETS[name]), nl=False)
