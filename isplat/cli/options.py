"""Options shared by several subcommands, defined once."""

import click

from .. import progress

force_option = click.option("--force", is_flag=True, help="Overwrite OUTPUT if it exists.")


def _set_quiet(ctx, param, value):
    progress.set_quiet(value)
    return value


quiet_option = click.option("-q", "--quiet", is_flag=True, expose_value=False, is_eager=True,
                            callback=_set_quiet, help="No progress bars or log lines on stderr.")
