"""A render's input as a scene: a scene file, or an augmented file given alone (``isplat render ct.aug.h5 --preset
ct-bone``) whose scene is made here; and any scene as TOML text (``isplat render --print-scene``).

An augmented file's scene is ``version`` the current one, ``data.augmented`` the file, ``data.index`` the index
beside it (the same stem, ``.idx.h5``; without one ``render.method = "full"``, said in one line), an image of
:data:`QUICK_SIZE` pixels square, and every other key the scene's default. The options ``--index``, ``--preset``
and ``--size`` are overrides of ``data.index``, ``transfer.preset`` and ``image.width``/``image.height``, applied
before the ``--set`` ones, for a scene file as for an augmented file.

>>> print(to_toml({"version": 5, "data": {"augmented": "a.aug.h5"}, "views": {"list": [{"azimuth": 90.0}]}}))
version = 5
<BLANKLINE>
[data]
augmented = "a.aug.h5"
<BLANKLINE>
[views]
list = [{azimuth = 90.0}]
<BLANKLINE>
>>> parse_size("640x480"), index_beside("scans/ct.aug.h5").as_posix(), output_stem("scans/ct.aug.h5")
((640, 480), 'scans/ct.idx.h5', 'ct')
"""

from __future__ import annotations

import copy
import json
import logging
import math
import os
import re
from dataclasses import replace
from pathlib import Path

from .errors import IsplatError

__all__ = ["load_input", "is_augmented_path", "index_beside", "output_stem", "option_overrides", "parse_size",
           "to_toml", "toml_string", "QUICK_SIZE"]

log = logging.getLogger(__name__)

QUICK_SIZE = 512                       # pixels, width and height, of an augmented file's scene
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
_AUG_TAILS = (".aug.h5", ".aug.hdf5", ".h5", ".hdf5")
_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")


def is_augmented_path(path) -> bool:
    """An augmented (HDF5) file rather than a scene: by its extension, else by the HDF5 signature."""
    suffix = Path(path).suffix.lower()
    if suffix in (".h5", ".hdf5") or suffix == ".toml":
        return suffix != ".toml"
    if not Path(path).is_file():         # a fifo or device is not opened (the scene reader refuses it)
        return False
    try:
        with open(path, "rb") as f:
            return f.read(len(HDF5_SIGNATURE)) == HDF5_SIGNATURE
    except OSError:
        return False


def output_stem(path) -> str:
    """The name of ``path`` without its extension (``ct.aug.h5`` -> ``ct``): a default output's stem."""
    name = Path(path).name
    for tail in _AUG_TAILS + (".toml",):
        if name.lower().endswith(tail) and len(name) > len(tail):
            return name[:-len(tail)]
    return Path(path).stem


def index_beside(augmented) -> Path:
    """The index an augmented file's scene takes when none is given: the same stem with ``.idx.h5``."""
    return Path(augmented).with_name(output_stem(augmented) + ".idx.h5")


def parse_size(text: str) -> tuple[int, int]:
    """``--size N`` (square) or ``WxH``, in pixels."""
    m = re.fullmatch(r"\s*(\d+)\s*(?:[xX]\s*(\d+)\s*)?", str(text))
    w, h = (int(m[1]), int(m[2] or m[1])) if m else (0, 0)
    if not (1 <= w <= 8192 and 1 <= h <= 8192):
        raise IsplatError(f"--size {text}: expected N or WxH pixels, each 1..8192 (e.g. --size 512, --size 640x480)")
    return w, h


def option_overrides(index=None, preset=None, size=None) -> list[str]:
    """``--index``, ``--preset`` and ``--size`` as ``--set`` arguments."""
    out = []
    if index is not None:
        out.append("data.index=" + toml_string(str(index)))
    if preset is not None:
        out.append("transfer.preset=" + toml_string(str(preset)))
    if size is not None:
        w, h = parse_size(size)
        out += [f"image.width={w}", f"image.height={h}"]
    return out


def _augmented_scene(path, index_given: bool) -> dict:
    """The TOML tree of an augmented file's scene (module docstring)."""
    from .fileio import check_regular

    check_regular(path, "augmented file")              # a fifo or device: refused unopened
    if not Path(path).is_file():
        raise IsplatError(f"{path}: " + ("is a folder, expected an augmented .h5 file" if Path(path).is_dir() else
                                         "augmented file does not exist (isplat augment SCAN -o FILE.aug.h5 makes it)"))
    from .scene_schema import SCENE_VERSION

    data = {"augmented": os.path.abspath(path)}
    tree = {"version": SCENE_VERSION, "data": data}
    beside = index_beside(path)
    if not index_given and beside.is_file():
        data["index"] = os.path.abspath(beside)
    elif not index_given:
        log.info(f"isplat render: no index beside {path} ({beside}): every voxel is read (render.method = "
                 f"\"full\"); isplat index {path} -o {beside} builds it")
        tree["render"] = {"method": "full"}
    tree["image"] = {"width": QUICK_SIZE, "height": QUICK_SIZE}
    return tree


def load_input(path, overrides=(), index=None, preset=None, size=None, opened: dict | None = None):
    """``(scene, toml_text)``: the scene of a render's input ``path`` (a scene file or an augmented file) with the
    options and ``--set`` ``overrides`` applied, and that scene as TOML that renders the same (``--print-scene``:
    the data paths absolute, ``version`` written). ``opened``: the run's open files (``augmented_window``)."""
    from .limits import check_scene_text
    from .scene import augmented_window, old_defaults_note, parse_scene, read_scene_text, scene_tree

    sets = option_overrides(index, preset, size) + list(overrides)
    augmented = is_augmented_path(path)
    if augmented:
        text, base, name = to_toml(_augmented_scene(path, index is not None)), Path.cwd(), f"{path} (its scene)"
    else:
        text, base, name = read_scene_text(path), Path(path).parent, str(path)
    check_scene_text(name, text, sets)           # size and nesting bounded before tomllib recurses
    tree, _ = scene_tree(text, name, sets)
    if augmented and "transfer" not in tree:
        raise IsplatError(f"{path}: no transfer function: give --preset NAME (isplat presets lists them), e.g. "
                          f"--preset ct-bone, or --set 'transfer.opacity=[[LO, 0], [HI, 1]]' (density codes)")
    scene = parse_scene(text, base, name, sets, density_window=lambda data: augmented_window(data, opened))
    note = old_defaults_note(tree, name)            # once per render, whatever the number of views
    if note:
        log.info(note)
    if not augmented:
        scene = replace(scene, path=Path(os.path.abspath(path)))
    return scene, _printable(tree, scene)


def _printable(tree: dict, scene) -> str:
    """``tree`` as TOML with the scene's data paths absolute and its version written."""
    from .scene_schema import SCENE_VERSION

    out = {"version": tree.get("version", SCENE_VERSION)}
    out.update(copy.deepcopy(tree))
    data = out.get("data")
    if isinstance(data, dict) and scene.data.augmented is not None:
        data["augmented"] = str(scene.data.augmented)
        if scene.data.index is not None:
            data["index"] = str(scene.data.index)
    labels = out.get("labels")
    if isinstance(labels, dict) and scene.labels.names is not None:
        labels["names"] = str(scene.labels.names)        # the names map's path absolute too
    return to_toml(out)


# --------------------------------------------------------------------------------------------------------------------
# TOML writing (the scene's values: tables, arrays, strings, numbers, booleans)

def toml_string(s: str) -> str:
    """A TOML basic string."""
    return json.dumps(s).replace("\x7f", "\\u007f")


def _key(k) -> str:
    return k if _BARE_KEY.match(str(k)) else toml_string(str(k))


def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return ("-inf" if v < 0 else "inf") if math.isinf(v) else "nan" if math.isnan(v) else repr(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_key(k)} = {_value(x)}" for k, x in v.items()) + "}"
    return toml_string(str(v))


def _table(lines: list, path: tuple, table: dict) -> None:
    plain = [(k, v) for k, v in table.items() if not isinstance(v, dict)]
    if path and (plain or not table):
        lines += ["", "[" + ".".join(_key(k) for k in path) + "]"]
    lines += [f"{_key(k)} = {_value(v)}" for k, v in plain]
    for k, v in table.items():
        if isinstance(v, dict):
            _table(lines, path + (k,), v)


def to_toml(tree: dict) -> str:
    """``tree`` (as tomllib reads a scene) as TOML text; arrays of tables are written inline."""
    lines: list = []
    _table(lines, (), tree)
    return "\n".join(lines).lstrip("\n") + "\n"
