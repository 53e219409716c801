"""One call from a volume to a picture, for notebooks: ``isplat.render(volume, preset=..., azimuth=...)``.

>>> import numpy as np, isplat
>>> from isplat.samples import make_sample
>>> ct, spacing = make_sample("ct-head", (64, 64, 56))          # Hounsfield units, [k, j, i]
>>> rgba = isplat.render(ct, preset="ct-bone", azimuth=30, spacing=spacing, size=(96, 64))
>>> rgba.shape, rgba.dtype, bool(rgba[..., :3].max() > 0.5)
((64, 96, 4), dtype('float32'), True)

The volume is augmented in memory once (window: ``window`` or, for Hounsfield data, ``ct-full``) and the
selection of a transfer function is kept, so views of the same volume and transfer function after the first
cost one frame each. Everything a scene file says can be said with ``set=["camera.fov=30", ...]``
(formats/scene.md).
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from pathlib import Path

import numpy as np

from .errors import IsplatError
from .request import SelectionCache

_CACHE: OrderedDict = OrderedDict()       # the augmented volumes of the last few calls
_CACHE_SIZE = 4
_SELECTIONS = SelectionCache(_CACHE_SIZE)  # their selections by request (isplat.request), with band learning


def render(volume, *, preset: str | None = None, opacity=None, color=None, azimuth: float = 0.0,
           elevation: float = 0.0, zoom: float = 1.0, size=256, spacing=None, window=None, shading: bool = True,
           background=None, projection: str = "orthographic", thin_slices: bool = False,
           set=()) -> np.ndarray:  # noqa: A002
    """Render ``volume`` and return straight RGBA floats ``(H, W, 4)`` in [0, 1] over the background.

    ``volume``: a 3-D array ``[k, j, i]`` of the scan's values (Hounsfield units for CT), or the path of a
    scan any ``isplat augment`` reader takes. ``preset`` (``isplat presets``) or ``opacity`` (and ``color``)
    points ``[[value, opacity], ...]`` in the scan's own values give the transfer function; ``size`` is
    ``N`` or ``(width, height)``; ``spacing`` (i, j, k) defaults to the file's or 1; ``window`` as for
    ``isplat augment --window``; ``thin_slices``: interpolate thick slices first, as ``isplat augment
    --thin-slices`` (:mod:`isplat.resample`); ``set`` takes further ``KEY=VALUE`` scene overrides. A scan whose
    file records its orientation in the patient is seen from the front, superior up, azimuth and elevation
    turning from there (``set=["camera.view=left"]`` names another side: formats/scene.md §4.4).
    """
    if preset is None and opacity is None:
        from .presets import PRESETS
        raise IsplatError(f"isplat.render: give preset= (one of {', '.join(PRESETS)}) or opacity= points")
    arr, spacing, axes_lps = _volume_array(volume, spacing)
    if thin_slices:
        from .resample import thin_slices as thin

        arr, spacing = thin(arr, spacing, who="isplat.render")
    identity = ("augment", _digest(arr), spacing, str(window))
    aug = _cached(identity, lambda: _augment(arr, spacing, window))
    width, height = (size, size) if np.ndim(size) == 0 else size
    keys = [f"image.width={int(width)}", f"image.height={int(height)}", f"camera.azimuth={float(azimuth)}",
            f"camera.elevation={float(elevation)}", f"camera.zoom={float(zoom)}",
            f'camera.projection="{projection}"', f"shading.enabled={'true' if shading else 'false'}"]
    keys += [f'transfer.preset="{preset}"'] if preset is not None else ['transfer.units="data"']
    keys += [f"transfer.opacity={_toml(opacity)}"] if opacity is not None else []
    keys += [f"transfer.color={_toml(color)}"] if color is not None else []
    keys += [f"image.background={_toml(background)}"] if background is not None else []
    scene = _scene(keys + list(set), aug)
    return _render_scene(scene, aug, spacing, identity, axes_lps)


def _render_scene(scene, aug, spacing, identity, axes_lps=None) -> np.ndarray:
    """The first view of ``scene`` from the augmented volume ``aug`` (identified by ``identity``), through a
    Renderer whose selection is kept by its request (:data:`_SELECTIONS`)."""
    from .renderer import InMemory, Renderer

    arrays = InMemory({ch: aug[ch] for ch in ("density", "gradient_magnitude", "normal")}, spacing,
                      float(aug["gradient_magnitude_scale"]), identity, axes_lps)
    rgba, _ = Renderer(scene, arrays=arrays, cache=_SELECTIONS).render_view(0)
    return rgba


def _volume_array(volume, spacing):
    """The volume as an array, its spacing (i, j, k): given, else the file's, else 1, and its orientation
    (``axes_lps``, a file's; None for an array)."""
    if isinstance(volume, (str, Path)):
        from .volume_io import read_volume

        vol = read_volume(volume, spacing=spacing)
        return np.asarray(vol.array), tuple(float(s) for s in vol.spacing_ijk), vol.meta.get("axes_lps")
    from .memory import check_volume

    return (*check_volume(volume, spacing, "isplat.render"), None)


def _augment(arr, spacing, window) -> dict:
    from .augment import augment_array

    return augment_array(arr, spacing, window)


def _scene(overrides, aug):
    """The scene of ``overrides``; data units through the augmented volume's window, a preset placed from the
    data on its density histogram."""
    from .scene import SCENE_VERSION, DensityWindow, parse_scene

    window = DensityWindow(tuple(aug["density_window"]), "the volume", None, aug.get("density_units", "HU"),
                           histogram=lambda: np.bincount(np.asarray(aug["density"]).ravel(), minlength=256))
    return parse_scene(f"version = {SCENE_VERSION}\n", ".", "isplat.render", overrides, data_required=False,
                       density_window=window)


def _digest(arr: np.ndarray) -> str:
    """What identifies a volume's values: shape, dtype and a hash of its bytes (about 1 GB/s)."""
    h = hashlib.blake2b(f"{arr.shape}{arr.dtype.str}".encode(), digest_size=16)
    h.update(memoryview(np.ascontiguousarray(arr)).cast("B"))
    return h.hexdigest()


def _cached(key, make):
    if key in _CACHE:
        _CACHE.move_to_end(key)
        return _CACHE[key]
    value = make()
    _CACHE[key] = value
    while len(_CACHE) > _CACHE_SIZE:
        _CACHE.popitem(last=False)
    return value


def _toml(value) -> str:
    """Numbers and nested lists of numbers as a TOML value."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise IsplatError(f"isplat.render: {value!r} is not numbers") from None
    return str(arr.tolist())
