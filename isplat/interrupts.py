"""SIGINT and SIGTERM for the ``isplat`` command: an exception in the main thread, held back where one would break
what it interrupts, and never lost.

The command (:func:`isplat.cli.main.main`) turns each signal into :class:`Terminated`, raised in the main thread,
so that temporary outputs are removed on the way out (:func:`isplat.fileio.atomic_output`). Three refinements:

* **From the start.** The handlers are installed by the first lines of :mod:`isplat.cli.main` when it is the
  command being run (:func:`hold_from_start`), before click and the rest are imported; a signal that arrives before
  :func:`main` can report it is held until then (:func:`release_start`), so it still ends in one line and
  exit 130 or 143, not a traceback or a bare exit -15.
* **Deferred while numba loads or compiles.** An exception raised inside numba's compiler or cache loader (its
  LLVM modules, its compile locks and counters half updated) made later calls segfault or fail with
  "no compiled object yet"; :func:`deferred` holds the signal until the outermost load or compile returns, then
  raises it (:func:`defer_numba_compiles` wraps numba's ``Dispatcher.compile``).
* **Never lost.** A signal is remembered even when code between the handler and :func:`main` swallows the
  exception; no output is renamed into place after one (:func:`check`, called by ``atomic_output`` before it
  commits), and :func:`main` then still exits 130/143.
* **Not printed where Python cannot raise it.** The handler runs at the main thread's next bytecode, which may be
  a weakref or ``__del__`` callback (the garbage collector's): Python prints an exception raised there as
  "Exception ignored in ..." with a traceback, and goes on. :func:`_unraisable` keeps that quiet for
  :class:`Terminated` and sends the signal again, so that it is raised at the next bytecode outside the callback.
"""

from __future__ import annotations

import contextlib
import functools
import os
import signal
import sys
import threading

SIGNALS = (signal.SIGTERM, signal.SIGINT)
RESEND_SECONDS = 0.01      # a signal raised inside a garbage-collector callback is sent again after this (_unraisable)


class Terminated(BaseException):
    """SIGTERM or SIGINT, raised in the main thread so that temporary outputs are removed on the way out
    (not KeyboardInterrupt, which click turns into Abort after writing a blank line)."""

    def __init__(self, signum):
        super().__init__(signum)
        self.signum = signum


_state = {"depth": 0, "pending": None, "received": None, "installed": False, "start_hold": False}
_LOCK = threading.Lock()
REMOVED: list[str] = []            # incomplete outputs removed on the way out (what the last line may name)


def on_signal(signum, frame):
    """The handler: remember the signal; raise :class:`Terminated` now, or when the deferral ends."""
    _state["received"] = _state["received"] or signum
    if _state["depth"] > 0:
        _state["pending"] = _state["pending"] or signum
        return
    raise Terminated(signum)


def _unraisable(args) -> None:
    """``sys.unraisablehook`` while the handlers are installed: a :class:`Terminated` raised where Python cannot
    raise (a callback of the garbage collector) is not printed; its signal is sent again a moment later from
    another thread (sent from here, it would be raised in this hook and printed after all), and the handler
    raises it at the main thread's next bytecode, or a deferral holds it. Anything else goes to Python's hook,
    unless a signal has been received."""
    if not isinstance(args.exc_value, Terminated):
        if _state["received"] is None:
            sys.__unraisablehook__(args)
        # else the run is ending on a signal, and an object it cut off half made fails in its finalizer
        # (llvmlite's OutputString, when the signal came inside its __init__ during a compile: "no attribute
        # '_ptr'"); not printed after the run's one line, which says why it ended
        return
    with _LOCK:                     # a signal meanwhile is only recorded: the one sent again stands for it
        _state["depth"] += 1
    try:
        again = threading.Timer(RESEND_SECONDS, os.kill, (os.getpid(), args.exc_value.signum))
        again.daemon = True
        again.start()
    finally:
        with _LOCK:
            _state["depth"] -= 1
            if _state["depth"] == 0:
                _state["pending"] = None


def install() -> dict:
    """Install :func:`on_signal` for SIGTERM and SIGINT where their handlers are Python's defaults (and
    :func:`_unraisable`); return the handlers replaced (to restore)."""
    if sys.unraisablehook is sys.__unraisablehook__:
        sys.unraisablehook = _unraisable
    previous = {}
    for sig, default in ((signal.SIGTERM, signal.SIG_DFL), (signal.SIGINT, signal.default_int_handler)):
        current = signal.getsignal(sig)
        if current is default:
            previous[sig] = signal.signal(sig, on_signal)
    if previous:
        _state["installed"] = True
    return previous


def restore(previous: dict) -> None:
    for sig, handler in previous.items():
        signal.signal(sig, handler)
    if previous:
        _state["installed"] = False
        if sys.unraisablehook is _unraisable:
            sys.unraisablehook = sys.__unraisablehook__


def reset() -> None:
    """Forget signals received (one :func:`isplat.cli.main.main` call to the next, in one process); not one
    held since the start (:func:`hold_from_start`)."""
    if _state["start_hold"]:
        return
    _state["pending"] = _state["received"] = None
    REMOVED.clear()


def received() -> int | None:
    return _state["received"]


def signal_behind(exc: BaseException) -> int | None:
    """The signal whose :class:`Terminated` caused ``exc`` (its ``__cause__`` or ``__context__`` chain), else None.

    Compiled code that calls back into Python (h5py iterating attributes, say) may turn an exception raised by
    :func:`on_signal` inside the callback into another one: h5py's lock reports ``SystemError: ... returned a
    result with an exception set``, with the :class:`Terminated` as its cause."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, Terminated):
            return exc.signum
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


def check() -> None:
    """Raise :class:`Terminated` if a signal arrived under :func:`on_signal` (even one whose exception was
    swallowed): nothing is committed after it."""
    if _state["installed"] and _state["received"] and _state["depth"] == 0:
        raise Terminated(_state["received"])


@contextlib.contextmanager
def deferred():
    """Hold SIGINT and SIGTERM (when :func:`on_signal` handles them) until the block ends, then raise; a block
    in another thread (numba compiling a kernel first called there) sends the held signal again, so that the
    main thread raises it."""
    with _LOCK:
        _state["depth"] += 1
    try:
        yield
    finally:
        with _LOCK:
            _state["depth"] -= 1
            signum = _state["pending"] if _state["depth"] == 0 else None
            if signum:
                _state["pending"] = None
        if signum:
            if threading.current_thread() is threading.main_thread():
                raise Terminated(signum)
            os.kill(os.getpid(), signum)


def defer_numba_compiles(dispatcher_class) -> None:
    """Make ``dispatcher_class.compile`` (numba's cache load or compile of one signature, the outermost of
    which also serves a first call) run under :func:`deferred`. Idempotent."""
    compile_ = dispatcher_class.compile
    if getattr(compile_, "_isplat_deferred", False):
        return

    @functools.wraps(compile_)
    def compile(self, sig):
        with deferred():
            return compile_(self, sig)

    compile._isplat_deferred = True
    dispatcher_class.compile = compile


def _running_as_command() -> bool:
    """True when this process is the ``isplat`` command (its console script, or ``python -m isplat``)."""
    main = sys.modules.get("__main__")
    spec = getattr(main, "__spec__", None)
    if spec is not None and spec.name == "isplat.__main__":
        return True
    return os.path.basename(getattr(main, "__file__", "") or "") == "isplat"


def hold_from_start() -> None:
    """When this process is the command: install the handlers now, holding any signal until
    :func:`release_start` (called by ``main`` once it can report one)."""
    if _state["start_hold"] or not _running_as_command():
        return
    if install():
        _state["start_hold"] = True
        _state["depth"] += 1


def release_start() -> None:
    """End :func:`hold_from_start`'s hold; a signal held meanwhile is raised here."""
    if not _state["start_hold"]:
        return
    _state["start_hold"] = False
    _state["depth"] -= 1
    if _state["depth"] == 0 and _state["pending"]:
        signum, _state["pending"] = _state["pending"], None
        raise Terminated(signum)


def hold() -> None:
    """Hold every later signal for good (the command's last steps before ``os._exit``): it is only recorded."""
    with _LOCK:
        _state["depth"] += 1


def removed_note() -> str:
    """'; incomplete outputs removed (NAME, ...)' when something was removed, else ''."""
    if not REMOVED:
        return ""
    names = ", ".join(REMOVED[:3]) + (f" and {len(REMOVED) - 3} more" if len(REMOVED) > 3 else "")
    return f"; incomplete outputs removed ({names})"
