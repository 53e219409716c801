"""Camera paths: keyframe cameras interpolated into ``frames`` views at constant angular speed.

The view direction of each keyframe is written as (azimuth, elevation) about the common ``up`` vector (orbit
keyframes as given, so 0 -> 360 is a full turn; look_at keyframes from ``position - look_at``, unwrapped to the
nearest turn). Those angles, and log zoom, log distance, target, roll and field of view, follow a monotone cubic
spline through the keyframes (PCHIP, Fritsch-Carlson: C1, so no kink at a keyframe, and no overshoot, so the
camera never swings past a keyframe and back, as a Catmull-Rom spline does with unequal steps). It is then
re-timed so that consecutive frames are the same angle apart (the angle between their view directions); a path
that turns back on itself between two frames (where no equal angles exist with the frames in path order) is
timed by the angle turned along it instead; a sharp turn that does not turn back gets equal angles too. A
stretch between two keyframes with the same direction (only zoom or target change) takes the time of an
average turning stretch. The first and last frames are the first and last keyframes exactly.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

SAMPLES_PER_SEGMENT = 512       # dense samples of the spline per keyframe interval, for the re-timing
STILL = 1e-9                    # radians: a stretch turning less than this does not rotate
REFINE, GAIN = 60, 0.5          # damped passes that equalise the angles between consecutive frames
SETTLED = 1e-3                  # their spread (max - min over mean) when they did; else the equal arcs are kept


class PathError(ValueError):
    """A keyframe problem: ``key`` is the index of the offending keyframe, ``field`` the key."""

    def __init__(self, key: int, field: str, message: str):
        super().__init__(message)
        self.key, self.field = key, field


def _basis(up):
    """(e1, e2, up) of the orbit formula (formats/scene.md §4.4)."""
    up = np.asarray(up, dtype=np.float64)
    up = up / np.linalg.norm(up)
    ref = np.array([0.0, -1.0, 0.0]) if abs(up[1]) < 0.99 else np.array([1.0, 0.0, 0.0])
    e1 = ref - (ref @ up) * up
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(up, e1), up


def directions(az_deg, el_deg, up) -> np.ndarray:
    """Unit vectors from the target to the eye for arrays of azimuth and elevation (degrees)."""
    e1, e2, u = _basis(up)
    az, el = np.radians(np.asarray(az_deg, dtype=np.float64)), np.radians(np.asarray(el_deg, dtype=np.float64))
    return (np.cos(el) * np.cos(az))[..., None] * e1 + (np.cos(el) * np.sin(az))[..., None] * e2 \
        + np.sin(el)[..., None] * u


def angles_between(a, b) -> np.ndarray:
    """Angles (radians) between rows of unit vectors ``a`` and ``b``, accurate for small angles."""
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def _angles_of(cam, up) -> tuple[float, float]:
    if cam.mode == "orbit":
        return cam.azimuth, cam.elevation
    e1, e2, u = _basis(up)
    w = np.subtract(cam.position, cam.look_at)
    w = w / np.linalg.norm(w)
    return math.degrees(math.atan2(w @ e2, w @ e1)), math.degrees(math.asin(max(-1.0, min(1.0, w @ u))))


def _channels(keys) -> np.ndarray:
    """Per keyframe: azimuth, elevation, log zoom, roll, fov, log distance, target x, y, z (NaN when unused)."""
    rows, prev_az = [], None
    for cam in keys:
        az, el = _angles_of(cam, keys[0].up)
        if cam.mode == "look_at":
            if prev_az is not None:
                az += 360.0 * round((prev_az - az) / 360.0)
            dist, target = float(np.linalg.norm(np.subtract(cam.position, cam.look_at))), cam.look_at
        else:
            dist, target = cam.distance, cam.target
        prev_az = az
        rows.append([az, el, math.log(cam.zoom), cam.roll, cam.fov, math.log(dist) if dist else math.nan,
                     *(target if target is not None else (math.nan,) * 3)])
    return np.asarray(rows, dtype=np.float64)


def _slopes(points: np.ndarray) -> np.ndarray:
    """Fritsch-Carlson tangents at unit-spaced knots: zero at a local extreme, else the harmonic mean of the
    neighbouring secants (one-sided three-point formula at the ends, limited likewise), so no overshoot."""
    delta = np.diff(points, axis=0)
    if len(points) == 2:
        return np.concatenate([delta, delta])
    same = delta[:-1] * delta[1:] > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        inner = np.where(same, 2.0 / (1.0 / np.where(same, delta[:-1], 1) + 1.0 / np.where(same, delta[1:], 1)), 0.0)

    def end(d0, d1):
        m = (3 * d0 - d1) / 2
        m = np.where(np.sign(m) != np.sign(d0), 0.0, m)
        return np.where((np.sign(d0) != np.sign(d1)) & (np.abs(m) > np.abs(3 * d0)), 3 * d0, m)
    return np.concatenate([end(delta[0], delta[1])[None], inner, end(delta[-1], delta[-2])[None]])


def spline(points: np.ndarray, u) -> np.ndarray:
    """Monotone cubic Hermite spline (PCHIP) through ``points[n, c]`` at unit-spaced knots, at ``u`` in [0, n-1]:
    C1 (no kink at a keyframe) and without overshoot (it never swings past a keyframe and back)."""
    m = _slopes(points)
    u = np.asarray(u, dtype=np.float64)
    seg = np.clip(np.floor(u).astype(int), 0, len(points) - 2)
    t = (u - seg)[..., None]
    h00, h10, h01, h11 = 2 * t**3 - 3 * t**2 + 1, t**3 - 2 * t**2 + t, -2 * t**3 + 3 * t**2, t**3 - t**2
    return h00 * points[seg] + h10 * m[seg] + h01 * points[seg + 1] + h11 * m[seg + 1]


def frame_parameters(ch: np.ndarray, up, frames: int) -> np.ndarray:
    """Spline parameters of ``frames`` frames equally spaced in the angle turned (see the module text)."""
    n = len(ch)
    m = SAMPLES_PER_SEGMENT
    u = np.linspace(0.0, n - 1, (n - 1) * m + 1)
    v = spline(ch[:, :2], u)
    d = directions(v[:, 0], np.clip(v[:, 1], -90, 90), up)
    step = angles_between(d[:-1], d[1:])
    turn = step.reshape(n - 1, m).sum(axis=1)
    moving = turn > STILL
    still_time = turn[moving].mean() if moving.any() else 1.0
    step = np.where(np.repeat(moving, m), step, still_time / m)
    time = np.concatenate([[0.0], np.cumsum(step)])
    target = np.linspace(0.0, time[-1], frames)
    arc = np.interp(target, time, u)
    if not moving.all():
        return arc
    uf, best = arc, math.inf
    for _ in range(REFINE):   # equal arcs -> equal angles between consecutive frames (their chords)
        v = spline(ch[:, :2], uf)
        d = directions(v[:, 0], np.clip(v[:, 1], -90, 90), up)
        chord = angles_between(d[:-1], d[1:])
        if not chord.min() > 0:   # two frames on one direction: no chord to equalise
            break
        spread = (chord.max() - chord.min()) / chord.mean()
        if spread < best:
            best, best_u = spread, uf
        if spread < 1e-9:
            break
        reached = np.concatenate([[0.0], np.cumsum(chord)])
        target = np.clip(target + GAIN * (np.linspace(0.0, reached[-1], frames) - reached), 0.0, time[-1])
        uf = np.interp(target, time, u)
    # A sharp turn between two frames (a high keyframe the path goes up to and down from) makes that chord much
    # shorter than the arc at first; the passes above still equalise it. Only a path that really turns back on
    # itself between two frames (no equal chords with the frames in path order) keeps the equal arcs.
    if best > SETTLED or not np.all(np.diff(best_u) > 0):
        return arc
    return best_u


def _show(v) -> str:
    return f'"{v}"' if isinstance(v, str) else str(list(v) if isinstance(v, tuple) else v)


def _check(keys) -> None:
    first = keys[0]
    if first.mode not in ("orbit", "look_at"):
        raise PathError(0, "mode", f'camera paths take orbit or look_at keyframes, not mode "{first.mode}"')
    for n, cam in enumerate(keys):
        for field in ("mode", "projection", "up", "view"):
            if getattr(cam, field) != getattr(first, field):
                raise PathError(n, field, f"every keyframe of a path needs the same {field} (keyframe 0 has "
                                          f"{_show(getattr(first, field))}, this one {_show(getattr(cam, field))})")
        for field in ("target", "distance"):
            if first.mode == "orbit" and (getattr(cam, field) is None) != (getattr(first, field) is None):
                raise PathError(n, field, f"give {field} in every keyframe or in none (or once in [camera])")


def interpolate(keys, frames: int) -> tuple:
    """``frames`` cameras along the path through the keyframe cameras ``keys`` (at least 2)."""
    _check(keys)
    if frames < 2:
        return (keys[0],)
    ch = _channels(keys)
    up = keys[0].up
    uf = frame_parameters(ch, up, frames)
    v = spline(ch, uf)
    out = []
    for row in v:
        az, el = float(row[0]), float(np.clip(row[1], -90.0, 90.0))
        common = dict(zoom=math.exp(row[2]), roll=float(row[3]), fov=float(np.clip(row[4], 1e-3, 179.999)))
        target = None if np.isnan(row[6]) else tuple(float(x) for x in row[6:9])
        dist = None if np.isnan(row[5]) else math.exp(row[5])
        if keys[0].mode == "orbit":
            out.append(replace(keys[0], azimuth=az, elevation=el, target=target, distance=dist, **common))
        else:
            w = directions(az, el, up)
            pos = tuple(float(x) for x in np.asarray(target) + dist * w)
            out.append(replace(keys[0], position=pos, look_at=target, **common))
    out[0], out[-1] = keys[0], keys[-1]
    return tuple(out)
