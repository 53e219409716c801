r"""Fast, exact direct volume rendering by indexed splatting (Ihm & Lee).

In a notebook, one call from an array (or a scan's path) to a picture, ``isplat.render`` (isplat.api):
``rgba = isplat.render(ct, preset="ct-bone", azimuth=30)``. From the shell, preprocess once, render many times.
Each stage is a plain function first and a command second
(``isplat sample``, ``isplat augment``, ``isplat index``, ``isplat render``, ``isplat stats``; ``isplat --help``):

>>> import pathlib, tempfile, numpy as np
>>> from isplat.samples import make_sample
>>> from isplat.augment import augment_file
>>> from isplat.index import build_index_file
>>> from isplat.renderer import Renderer
>>> from isplat.scene import load_scene
>>> tmp = tempfile.TemporaryDirectory()
>>> folder = pathlib.Path(tmp.name)
>>> volume, spacing = make_sample("head", (48, 48, 42))       # array [k, j, i]; shape and spacing along i, j, k
>>> np.save(folder / "head.npy", volume)
>>> augment_file(folder / "head.npy", folder / "head.aug.h5", spacing=spacing)["shape_ijk"]
(48, 48, 42)
>>> build_index_file(folder / "head.aug.h5", folder / "head.idx.h5").name
'head.idx.h5'
>>> scene = folder / "head.toml"                             # the scene format: formats/scene.md
>>> _ = scene.write_text('[data]\naugmented = "head.aug.h5"\nindex = "head.idx.h5"\n'
...                      '[transfer]\nopacity = [[150, 0], [255, 1]]\n[image]\nwidth = 64\nheight = 48\n')
>>> rgba, stats = Renderer(load_scene(scene)).render_view(0)  # float (H, W, 4), and what the view visited
>>> rgba.shape
(48, 64, 4)
>>> tmp.cleanup()

Modules: isplat.samples (synthetic volumes), isplat.volume_io (reading scans), isplat.augment and
isplat.augfile (the augmented volume, formats/augmented.md), isplat.index (the density index,
formats/index.md), isplat.scene (scene files, formats/scene.md), isplat.renderer (rendering a scene's views),
isplat.selection and isplat.frame (the render core), isplat.stats (the
paper's Figure 5 figures), isplat.cli (the command). Log lines go through the logging module, under the
``isplat`` logger; progress bars (isplat.progress) show only while that logger lets INFO through.
"""

__version__ = "0.1.0"


def __getattr__(name):
    # ``isplat.render(volume, preset=..., azimuth=...)`` (isplat.api), imported on first use so that
    # ``import isplat`` stays light
    if name == "render":
        from .api import render
        return render
    raise AttributeError(f"module 'isplat' has no attribute {name!r}")
