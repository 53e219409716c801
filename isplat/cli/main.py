"""The ``isplat`` click group. Subcommands live one per module and are imported lazily,
so ``isplat --help`` and a render start without importing every stage."""

from __future__ import annotations

from .. import interrupts  # noqa: I001  (first: SIGINT/SIGTERM are handled, held, from here on)

interrupts.hold_from_start()

import importlib
import importlib.util
import logging
import os
import signal
import sys

import click

from .. import __version__
from ..errors import IsplatError
from .options import start_verbosity

# name -> (module, attribute, one-line help)
SUBCOMMANDS = {
    "sample": ("isplat.cli.sample", "sample", "Write a deterministic synthetic volume (head, engine, ...)."),
    "augment": ("isplat.cli.augment", "augment", "Turn a scan into 4-byte augmented voxels (HDF5)."),
    "index": ("isplat.cli.index", "index", "Build the three-axis density index (HDF5)."),
    "render": ("isplat.cli.render", "render", "Render images from a TOML scene."),
    "stats": ("isplat.cli.stats", "stats", "Report spatial ratio, memory and bytes a scene loads."),
    "presets": ("isplat.cli.presets", "presets", "List the transfer-function presets (CT bone, lung, MRI, ...)."),
}


class LazyGroup(click.Group):
    def list_commands(self, ctx):
        return [n for n in SUBCOMMANDS if _available(n)]

    def get_command(self, ctx, name):
        if name not in SUBCOMMANDS or not _available(name):
            return None
        mod, attr, _ = SUBCOMMANDS[name]
        return getattr(importlib.import_module(mod), attr)

    def format_commands(self, ctx, formatter):
        rows = [(n, SUBCOMMANDS[n][2]) for n in self.list_commands(ctx)]
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)


def _available(name: str) -> bool:
    return importlib.util.find_spec(SUBCOMMANDS[name][0]) is not None


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="isplat")
@click.option("-v", "--verbose", count=True, help="More on stderr: debug detail, e.g. what a render read and "
                                                  "per-view timing (as render -v).")
@click.option("-q", "--quiet", count=True, help="Less on stderr: no log lines or progress bars (as each "
                                                "subcommand's -q); -qq hides warnings too. Errors always show.")
def cli(verbose, quiet):
    """Fast, exact direct volume rendering by indexed splatting.

    Preprocess once, render many times:

    \b
      isplat sample head -o head.npy
      isplat augment head.npy -o head.aug.h5
      isplat index head.aug.h5 -o head.idx.h5
      isplat render scene.toml -o head.png
      isplat stats head.aug.h5 head.idx.h5 --scene scene.toml --json

    Images, printed commands and JSON go to stdout; log lines and progress bars to stderr.
    """
    start_verbosity(verbose - quiet)


Terminated = interrupts.Terminated
_on_signal = interrupts.on_signal


def _usage_line(exc: click.UsageError) -> str:
    ctx = exc.ctx
    cmd = ctx.command_path if ctx is not None else "isplat"
    return f"isplat: error: {cmd}: {exc.format_message()} (see {cmd} --help)".replace("\n", " ")


def main(argv=None):
    """Entry point: IsplatError becomes one line on stderr and exit status 2, never a traceback.

    SIGTERM and SIGINT remove temporary outputs (:func:`isplat.fileio.atomic_output`), print one line and exit
    143 and 130; click usage errors are one line too."""
    previous = interrupts.install()
    interrupts.reset()
    try:
        _run(argv)
    finally:
        interrupts.restore(previous)


def _run(argv):
    try:
        interrupts.release_start()
        _invoke(argv)
        interrupts.check()                        # a signal whose exception was swallowed on the way still counts
    except Terminated as exc:
        _interrupted(exc.signum)
    except click.UsageError as exc:
        click.echo(_usage_line(exc), err=True)
        sys.exit(exc.exit_code)
    except IsplatError as exc:
        one_line = " ".join(str(exc).split())          # values shown with repr() may span lines
        click.echo(f"isplat: error: {one_line[:2000]}", err=True)
        sys.exit(exc.exit_code)
    except click.exceptions.Abort:
        _interrupted(interrupts.received() or signal.SIGINT)
    except click.ClickException as exc:
        exc.show()
        sys.exit(exc.exit_code)
    except BrokenPipeError:
        sys.exit(1)
    except KeyboardInterrupt:
        _interrupted(signal.SIGINT)
    except MemoryError:
        click.echo("isplat: error: out of memory", err=True)
        sys.exit(1)
    except OSError as exc:                        # the last resort: a system error is one line too
        click.echo(f"isplat: error: {os_error_line(exc)}", err=True)
        sys.exit(1)
    sys.exit(0)


def _invoke(argv) -> None:
    """The command; an exception that a signal caused inside compiled code (an h5py callback) is the signal."""
    try:
        cli.main(args=argv, prog_name="isplat", standalone_mode=False)
    except Exception as exc:
        signum = interrupts.signal_behind(exc)
        if signum is None:
            raise
        raise Terminated(signum) from exc


def _interrupted(signum) -> None:
    """One line, naming the signal and, only when there were some, the incomplete outputs removed; exit 128+N."""
    name = signal.Signals(signum).name
    click.echo(f"isplat: interrupted ({name}){interrupts.removed_note()}", err=True)
    sys.exit(128 + int(signum))


def os_error_line(exc: OSError) -> str:
    """'FILE: reason' for an OSError (its strerror, else its text), on one line."""
    why = exc.strerror or str(exc) or exc.__class__.__name__
    where = exc.filename if exc.filename is not None else None
    text = f"{where}: {why}" if where is not None else why
    return " ".join(str(text).split())[:2000]


def console():
    """The ``isplat`` command: :func:`main`, then out of the process without tearing the interpreter down.

    Once the outputs are written (closed and renamed by the stages) and stdout and stderr are flushed, nothing
    is left to do; yet Python's finalisation frees every module and numba's compiled code one by one, about
    0.3 s of a one-frame render (docs/startup.md, ``python -m benchmarks startup``). ``os._exit`` skips it.
    In-process callers (tests) use :func:`main`, which returns normally."""
    code = 0
    try:
        main()
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        if exc.code is not None and not isinstance(exc.code, int):
            print(exc.code, file=sys.stderr)
    except Terminated as exc:                     # a signal between main's end and here
        code = 128 + int(exc.signum)
        print(f"isplat: interrupted ({signal.Signals(exc.signum).name})", file=sys.stderr)
    interrupts.hold()                             # from here a signal is only recorded: the exit status tells it
    late = interrupts.received()
    if late and code == 0:
        code = 128 + int(late)
        print(f"isplat: interrupted ({signal.Signals(late).name})", file=sys.stderr)
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (BrokenPipeError, ValueError, OSError):
            code = code or 1
    os._exit(code)


if __name__ == "__main__":
    main()
