"""Phong shading for the slow references (render_reference, sheets_reference, post_reference): lights in camera
space turned into world directions, and the diffuse and specular terms of a world normal, computed directly."""

from __future__ import annotations

import numpy as np


def camera_lights(shading, frame) -> list:
    """(light direction, half vector, rgb intensity) per light, in world space, for an infinite viewer."""
    R = np.stack([frame.u, frame.v, frame.w])
    out = []
    for L in shading.lights:
        lw = np.asarray(L.direction) @ R
        lw = lw / np.linalg.norm(lw)
        h = lw + frame.w
        out.append((lw, h / np.linalg.norm(h), L.intensity * np.asarray(L.color)))
    return out


def phong(n, shading, lights) -> tuple[np.ndarray, np.ndarray]:
    """(diffuse rgb factor with the ambient term, specular rgb) of world normal ``n``."""
    diff = np.full(3, shading.ambient)
    spec = np.zeros(3)
    for lw, hv, lc in lights:
        ndl, ndh = n @ lw, n @ hv
        if shading.two_sided:
            ndl, ndh = abs(ndl), abs(ndh)
        else:
            ndh = max(ndh, 0.0) if ndl > 0 else 0.0
            ndl = max(ndl, 0.0)
        diff += shading.diffuse * ndl * lc
        spec += shading.specular * ndh ** shading.shininess * lc
    return diff, spec
