"""Copy the demo's images, scaled to 256 pixels high, into docs/img/ for the README (make readme-images)."""

import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np

NAMES = ["head-bone", "head-perspective", "head-cut", "engine", "ct-bone", "ct-skin", "mri-t1-head", "ct-chest-mip"]


def shrink(img: np.ndarray, height: int = 256) -> np.ndarray:
    """Box-filter ``img`` down by an integer factor to about ``height`` rows."""
    f = max(1, img.shape[0] // height)
    h, w = img.shape[0] // f * f, img.shape[1] // f * f
    return img[:h, :w].reshape(h // f, f, w // f, f, -1).mean(axis=(1, 3)).round().astype(np.uint8)


def main(src: str, dst: str) -> None:
    Path(dst).mkdir(parents=True, exist_ok=True)
    for n in NAMES:
        img = iio.imread(Path(src) / f"{n}.png")[..., :3]
        iio.imwrite(Path(dst) / f"demo-{n}.png", shrink(img))
        print(f"readme_images: {dst}/demo-{n}.png", file=sys.stderr)


if __name__ == "__main__":
    main(*sys.argv[1:3])
