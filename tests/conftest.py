import contextlib
import os
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("ISPLAT_PROGRESS", "0")

# Property tests draw the same examples on every run (CI included), so a red run is repeatable and a green one
# is not luck; HYPOTHESIS_PROFILE=explore draws new ones (and keeps what fails in .hypothesis/).
from hypothesis import settings  # noqa: E402

settings.register_profile("deterministic", derandomize=True, database=None)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "deterministic"))


def write_volume(tmp: Path, density, spacing=(1.0, 1.0, 1.0), name="v", gm=None, normal=None, gscale=1.0,
                 index=True):
    """Write an augmented file (and its index) for ``density`` [k, j, i]; returns (aug, idx) paths."""
    from isplat.augfile import write_augmented
    from isplat.index import build_index_file

    density = np.ascontiguousarray(density, dtype=np.uint8)
    gm = np.zeros_like(density) if gm is None else np.asarray(gm, np.uint8)
    if normal is None:
        normal = np.full(density.shape, 0x8080, np.uint16)
    aug = tmp / f"{name}.aug.h5"
    idx = tmp / f"{name}.idx.h5"
    write_augmented(aug, density, gm, np.asarray(normal, np.uint16), spacing, (0.0, 255.0), gscale)
    if index:
        build_index_file(aug, idx)
    return aug, idx


@contextlib.contextmanager
def post_setting(name: str, value):
    """Context: the module setting ``isplat.splat.post.<name>`` (BETWEEN_SLICES, WEIGHTED_SHADING, ...) set to
    ``value``, restored after (a frame reads it when planned)."""
    from isplat.splat import post

    old = getattr(post, name)
    setattr(post, name, value)
    try:
        yield
    finally:
        setattr(post, name, old)


def scene_text(aug, idx, **sections) -> str:
    """A scene TOML string with [data] filled in and extra sections given as raw TOML text."""
    head = f'[data]\naugmented = "{aug}"\nindex = "{idx}"\n'
    arrays = {"cut", "shading.light"}          # arrays of tables: [[cut]]

    def header(k):
        k = k.replace("__", ".")
        return f"[[{k}]]" if k in arrays else f"[{k}]"
    return head + "\n".join(f"{header(k)}\n{v}" for k, v in sections.items())


@pytest.fixture
def make_scene(tmp_path):
    from isplat.scene import parse_scene

    def make(aug, idx, overrides=(), **sections):
        return parse_scene(scene_text(aug, idx, **sections), tmp_path, "test.toml", overrides)

    return make
