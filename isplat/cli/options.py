"""Options shared by several subcommands, defined once, and the log set-up behind ``-v`` and ``-q``.

Log lines go through :mod:`logging` to stderr, never stdout (stdout carries images, commands and JSON). The
level of the ``isplat`` logger is INFO minus 10 per ``-v`` plus 10 per ``-q``, counted on the group
(``isplat -q index ...``) and on a subcommand (``isplat index ... -q``) alike: INFO by default (the
"wrote ..." lines), DEBUG with ``-v`` (e.g. render's per-view report), WARNING with ``-q`` (no log lines,
no progress bars: those show only while INFO does).
"""

from __future__ import annotations

import logging
import sys

import click

force_option = click.option("--force", is_flag=True, help="Overwrite OUTPUT if it exists.")

_VERBOSITY = "isplat.verbosity"      # key of the count in click's context meta, shared by group and subcommand


class StderrHandler(logging.StreamHandler):
    """Writes each record to the ``sys.stderr`` of the moment (pytest and click's test runner swap it)."""

    def __init__(self):
        super().__init__(sys.stderr)

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, value):
        pass


def set_verbosity(verbosity: int) -> int:
    """Send the ``isplat`` logger's records, from level INFO - 10 * ``verbosity`` up, to stderr as bare lines."""
    logger = logging.getLogger("isplat")
    if not any(isinstance(h, StderrHandler) for h in logger.handlers):
        handler = StderrHandler()
        handler.setFormatter(logging.Formatter("%(message)s"))
        logger.addHandler(handler)
        logger.propagate = False
    logger.setLevel(min(max(logging.INFO - 10 * verbosity, logging.DEBUG), logging.CRITICAL))
    return verbosity


def start_verbosity(verbosity: int) -> None:
    """The group's counts: the starting point that a subcommand's own ``-v``/``-q`` move from."""
    click.get_current_context().meta[_VERBOSITY] = set_verbosity(verbosity)


def _move(step: int):
    def callback(ctx, param, count):
        if count:
            ctx.meta[_VERBOSITY] = set_verbosity(ctx.meta.get(_VERBOSITY, 0) + step * count)
        return count
    return callback


quiet_option = click.option("-q", "--quiet", count=True, expose_value=False, is_eager=True, callback=_move(-1),
                            help="No progress bars or log lines on stderr (same as isplat -q).")


def verbose_option(help: str):
    return click.option("-v", "--verbose", count=True, expose_value=False, is_eager=True, callback=_move(+1),
                        help=help)
