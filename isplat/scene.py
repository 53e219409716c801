"""Read a TOML scene into validated, frozen dataclasses; apply ``--set`` overrides; report errors by line.

The format is specified in ``formats/scene.md``. Every problem raises :class:`IsplatError` with one line naming
the file and line (or the ``--set`` argument), the key, its value and what was expected::

    scene.toml:14: camera.fov = 200: expected a number of degrees with 0 < fov < 180

This module is the front: it reads the file (:func:`load_scene`), decodes the TOML and applies the overrides
(:func:`parse_scene`), and is the only part of the reader that opens the augmented file: :func:`augmented_window`,
called only when the scene's transfer function is in data units or a Hounsfield preset. The rest is in
isplat.scene_positions (key -> line), isplat.scene_validate (the checks and their messages),
isplat.scene_schema (the dataclasses, their defaults, the known keys) and isplat.scene_parse (tree -> Scene).
"""

from __future__ import annotations

import logging
import os
import re
import tomllib
from dataclasses import replace
from pathlib import Path
from typing import Iterable

from .errors import IsplatError
from .fileio import check_regular
from .limits import MAX_SCENE_BYTES, check_scene_text
from .scene_parse import NO_WINDOW, DensityWindow, WindowArg, WindowUnavailable, build_scene, old_defaults_note
from .scene_positions import locate_keys
from .scene_schema import (CAMERA_COMMON_KEYS, CAMERA_KEYS, CAMERA_MODE_KEYS, CUT_KEYS, DATA_KEYS,  # noqa: F401
                           DEFAULT_LIGHT_DIRECTION, DEFAULT_PATH_FRAMES, FOV_MAX, IMAGE_KEYS, KEYS_SINCE, LIGHT_KEYS,
                           MAX_SPACING_RATIO, ORTHONORMAL_TOLERANCE, PARALLEL_TOLERANCE, RENDER_KEYS, SCENE_VERSION,
                           SHADING_KEYS, SPACING_RANGE, SUPERSAMPLE_MAX, TOP_KEYS, TRANSFER_KEYS, VIEWS_KEYS,
                           VOLUME_KEYS, Camera, Cut, Data, Image, Light, RenderOptions, Scene, Shading, Transfer, Vec3,
                           Volume, spacing_problem)
from .scene_validate import Ctx, apply_override

__all__ = [
    "SCENE_VERSION", "Scene", "Data", "Image", "Volume", "Camera", "Transfer", "Shading", "Light", "Cut",
    "RenderOptions", "load_scene", "parse_scene", "scene_tree", "read_scene_text", "locate_keys", "scene_to_dict",
    "augmented_window", "DensityWindow", "WindowUnavailable", "spacing_problem", "old_defaults_note",
]

log = logging.getLogger(__name__)


def augmented_window(data: Data, opened: dict | None = None) -> DensityWindow:
    """The density window recorded in ``data.augmented`` (its attributes only): what :func:`parse_scene` converts
    data units through when not given a window. Raises :class:`WindowUnavailable` with the reason. ``opened``
    (path -> AugmentedVolume): the run's open files, where the one opened here is left for the renderer, so a
    run opens each file once."""
    from . import augfile

    if data.augmented is None:
        raise WindowUnavailable(NO_WINDOW)
    why = "data units are converted through the augmented file's density window, which cannot be read"
    if not data.augmented.exists():
        raise WindowUnavailable(f"{why}: {data.written} does not exist (augment the scan first)")
    try:
        aug = (opened or {}).get(data.augmented) or augfile.open_augmented(data.augmented)
    except IsplatError as exc:
        raise WindowUnavailable(f"{why}: {exc}") from None
    if opened is not None:
        opened[data.augmented] = aug
    return DensityWindow(aug.density_window, data.written, aug.attrs.get("source"), aug.attrs.get("density_units"),
                         histogram=_histogram_of(aug))


def _histogram_of(aug):
    """The file's density histogram, counted from its density channel on the first call (only a preset placed
    from the data asks: isplat.presets.tissue_range), kept for the next."""
    kept = []

    def histogram():
        if not kept:
            from .stats import density_histogram

            kept.append(density_histogram(aug))
        return kept[0]
    return histogram


def _toml(text: str, source_name: str) -> dict:
    """The TOML tree of ``text``; a syntax error is one line with its line number."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        msg = str(exc)
        m = re.search(r"\(at line (\d+), column \d+\)", msg)
        if m:
            line = m.group(1)
        elif "end of document" in msg:
            line = str(text.count("\n") + (0 if text.endswith("\n") else 1))
        else:
            line = None
        raise IsplatError(f"{source_name}{':' + line if line else ''}: TOML syntax error: {msg}") from None


def scene_tree(text: str, source_name: str, overrides: Iterable[str] = ()) -> tuple[dict, dict]:
    """The TOML tree of scene ``text`` with the ``--set`` ``overrides`` applied, and where each override went
    (``{key path: argument}``); not validated (:func:`parse_scene` does that)."""
    tree = _toml(text, source_name)
    set_args: dict[tuple, str] = {}
    for arg in overrides:
        apply_override(tree, arg, set_args)
    return tree, set_args


def parse_scene(text: str, base_dir: Path | str, source_name: str, overrides: Iterable[str] = (),
                data_required: bool = True, density_window: WindowArg = None) -> Scene:
    """Parse and validate scene ``text``; relative data paths are taken from ``base_dir``.

    ``source_name`` starts every error message; ``overrides`` are ``--set key=value`` strings applied to the
    TOML tree before validation. ``data_required=False`` accepts a scene without ``[data]`` (its
    ``data.augmented`` is then None), for volumes already in memory (:meth:`isplat.selection.Selection.from_arrays`).
    Transfer points in data units are converted through ``density_window``: a window ``(LO, HI)``, or a provider
    ``f(data) -> DensityWindow`` called only if data units or a Hounsfield preset are used; left out, it is
    :func:`augmented_window` (the window recorded in ``data.augmented``, read only then).
    """
    tree, set_args = scene_tree(text, source_name, overrides)
    ctx = Ctx(source_name, locate_keys(text), Path(base_dir), set_args)
    return build_scene(ctx, tree, data_required, augmented_window if density_window is None else density_window)


def scene_to_dict(scene: Scene, relative_to: Path | str | None = None) -> dict:
    """The scene as plain JSON-ready values (tuples become lists; paths strings, relative to ``relative_to``)."""
    def plain(x):
        if isinstance(x, Path):
            if relative_to is not None and x.is_relative_to(os.path.abspath(relative_to)):
                return str(x.relative_to(os.path.abspath(relative_to)))
            return str(x)
        if hasattr(x, "__dataclass_fields__"):
            return {f: plain(getattr(x, f)) for f in x.__dataclass_fields__}
        if isinstance(x, (tuple, list)):
            return [plain(v) for v in x]
        return x
    return plain(scene)


def load_scene(path: str | os.PathLike, overrides: Iterable[str] = (), say_old_defaults: bool = False) -> Scene:
    """Read, parse and validate the scene file at ``path`` (see ``formats/scene.md``). ``say_old_defaults``: log
    (INFO) the one line of :func:`old_defaults_note` when the file says an older ``version`` (a command does it
    once, on the load whose scene it uses)."""
    text = read_scene_text(path)
    overrides = list(overrides)
    check_scene_text(str(path), text, overrides)    # size and nesting bounded before tomllib recurses
    scene = parse_scene(text, Path(path).parent, str(path), overrides)
    if say_old_defaults:
        note = old_defaults_note(scene_tree(text, str(path), overrides)[0], str(path))
        if note:
            log.info(note)
    return replace(scene, path=Path(os.path.abspath(path)))


def read_scene_text(path: str | os.PathLike) -> str:
    """The text of the scene file at ``path`` (UTF-8, a byte-order mark dropped); one line when it cannot be."""
    p = Path(path)
    name = str(path)
    check_regular(p, "scene", MAX_SCENE_BYTES)          # a fifo would block; a huge file is refused unread
    try:
        raw = p.read_bytes()
    except FileNotFoundError:
        raise IsplatError(f"{name}: scene file does not exist") from None
    except IsADirectoryError:
        raise IsplatError(f"{name}: scene is a folder, expected a .toml file") from None
    except OSError as exc:
        raise IsplatError(f"{name}: cannot read the scene file ({exc.strerror})") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise IsplatError(f"{name}:{line}: the scene file is not UTF-8 text") from None
    return text[1:] if text.startswith("\ufeff") else text
