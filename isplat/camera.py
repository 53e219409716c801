"""Viewing: the camera frame, the principal axis and slice order, and the paper's §3 projection coefficients.

World space holds both the volume (origin ``q`` and unit axes i, j, k, scaled by the voxel spacing) and the
image space ``(p; u, v, w)`` of the paper: ``p`` the view reference point (image centre), ``v`` the view-up,
``w`` the view-plane normal pointing from the scene towards the viewer (the camera looks along ``-w``), and
``u = v x w`` to the right. Perspective adds the eye ``e`` on the ``+w`` side of the image plane.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import IsplatError
from .grid import AXES, SLICE_AXES  # noqa: F401  (the axis convention, re-exported)



@dataclass(frozen=True)
class VolumeGeometry:
    """Where the voxel grid sits in the world: voxel (i, j, k) is at ``q + i*I + j*J + k*K``."""

    shape: tuple[int, int, int]      # (n_k, n_j, n_i)
    spacing: np.ndarray              # (s_i, s_j, s_k)
    q: np.ndarray                    # world position of voxel (0, 0, 0)
    unit_axes: np.ndarray            # rows: unit vectors of i, j, k in the world

    @property
    def n_ijk(self) -> np.ndarray:
        return np.array(self.shape[::-1], dtype=np.int64)

    @property
    def steps(self) -> np.ndarray:
        """Rows I, J, K: world vectors of one grid step along i, j, k (spacing applied)."""
        return self.unit_axes * self.spacing[:, None]

    @property
    def centre(self) -> np.ndarray:
        return self.q + ((self.n_ijk - 1) / 2.0) @ self.steps

    @property
    def radius(self) -> float:
        """Radius of the bounding sphere of the voxel boxes."""
        return 0.5 * float(np.linalg.norm(self.n_ijk * self.spacing))

    def to_grid(self, x) -> np.ndarray:
        """World point -> continuous grid coordinates (i, j, k)."""
        return (self.unit_axes @ (np.asarray(x, float) - self.q)) / self.spacing


def volume_geometry(shape, spacing_ijk, origin=None, axes=None) -> VolumeGeometry:
    """Place a volume: ``origin=None`` centres it at the world origin; ``axes`` rows are i, j, k unit vectors."""
    sp = np.asarray(spacing_ijk, dtype=np.float64)
    ax = np.eye(3) if axes is None else np.asarray(axes, dtype=np.float64)
    # re-orthonormalise (the scene accepts axes orthonormal to 1e-3)
    uq, _, vt = np.linalg.svd(ax)
    ax = uq @ vt
    n = np.asarray(shape[::-1], dtype=np.float64)
    if origin is None:
        q = -((n - 1) / 2.0) @ (ax * sp[:, None])
    else:
        q = np.asarray(origin, dtype=np.float64)
    return VolumeGeometry(tuple(int(x) for x in shape), sp, q, ax)


@dataclass(frozen=True)
class ViewFrame:
    """A resolved view: image space, projection and pixel scale."""

    projection: str          # "orthographic" | "perspective"
    p: np.ndarray            # view reference point (image centre)
    u: np.ndarray
    v: np.ndarray
    w: np.ndarray            # towards the viewer
    e: np.ndarray | None     # eye (perspective)
    pixel_size: float        # world units per pixel on the image plane
    width: int
    height: int
    near: float              # perspective: cull voxels closer to the eye than this (along -w)
    clip: float = 0.0        # perspective: where the integral starts (along -w): camera.near when set, else 0 (the
                             # eye); the material between it and the first slab kept goes to that slab

    @property
    def direction(self) -> np.ndarray:
        """Viewing direction (into the scene)."""
        return -self.w


def _unit(x, what) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    big = float(np.abs(x).max()) if x.size else 0.0
    if np.isfinite(big) and big > 1e150:                 # scaled first: the squares of 1e300 overflow
        x = x / big
    n = float(np.linalg.norm(x))
    if not np.isfinite(n) or n < 1e-12:
        raise IsplatError(f"camera: {what} = {x.tolist()} has no direction")
    return x / n


def _frame_from(w, up, roll_deg, what_up="camera.up"):
    w = _unit(w, "view direction")
    up = _unit(up, what_up)
    v = up - (up @ w) * w
    if np.linalg.norm(v) < 1e-9:
        raise IsplatError(f"{what_up} = {up.tolist()} is parallel to the viewing direction; choose another up vector")
    v = v / np.linalg.norm(v)
    u = np.cross(v, w)
    if roll_deg:
        r = math.radians(roll_deg)
        u, v = math.cos(r) * u + math.sin(r) * v, -math.sin(r) * u + math.cos(r) * v
    return u, v, w


def orbit_direction(azimuth_deg, elevation_deg, up) -> np.ndarray:
    """Unit vector from the target to the camera. Azimuth 0 looks from -y towards +y when up is +z;
    azimuth 90 from +x; elevation lifts the camera towards ``up``."""
    up = _unit(up, "camera.up")
    ref = np.array([0.0, -1.0, 0.0]) if abs(up[1]) < 0.99 else np.array([1.0, 0.0, 0.0])
    e1 = ref - (ref @ up) * up
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    return math.cos(el) * (math.cos(az) * e1 + math.sin(az) * e2) + math.sin(el) * up


def resolved_view(view: str | None, axes_lps) -> str | None:
    """The named view an orbit camera's ``camera.view`` asks for: "auto" is "anterior" for data with an
    orientation (``axes_lps``) and None (azimuth and elevation about ``camera.up``) without one, as is "none"."""
    if view in (None, "none") or (view == "auto" and axes_lps is None):
        return None
    return "anterior" if view == "auto" else view


def view_frame(cam, geom: VolumeGeometry, width: int, height: int, axes_lps=None) -> ViewFrame:
    """Resolve a scene camera (orbit, look_at or the paper's p, v, w, e) into a :class:`ViewFrame`; an orbit
    camera's named view (``cam.view``) takes the data's orientation ``axes_lps`` (:func:`named_view`)."""
    persp = cam.projection == "perspective"
    if cam.mode == "orbit":
        target = geom.centre if cam.target is None else np.asarray(cam.target, float)
        dist = 3.0 * geom.radius if cam.distance is None else float(cam.distance)
        named = resolved_view(getattr(cam, "view", None), axes_lps)
        if named is not None:
            w, up_frame = named_view(named, axes_lps, cam.azimuth, cam.elevation, geom.unit_axes)
        else:
            w = orbit_direction(cam.azimuth, cam.elevation, cam.up)
            # the frame's up is d(w)/d(elevation): perpendicular to w and defined even straight overhead
            up_frame = orbit_direction(cam.azimuth, cam.elevation + 90.0, cam.up)
        u, v, w = _frame_from(w, up_frame, cam.roll)
        p, e = target, target + dist * w
    elif cam.mode == "look_at":
        e = np.asarray(cam.position, float)
        p = np.asarray(cam.look_at, float)
        u, v, w = _frame_from(e - p, cam.up, cam.roll)
    elif cam.mode == "paper":
        p = np.asarray(cam.reference_point, float)
        u, v, w = _frame_from(cam.view_plane_normal, cam.view_up, cam.roll, "camera.view_up")
        e = None if cam.eye is None else np.asarray(cam.eye, float)
        if persp:
            if e is None:
                raise IsplatError("camera.eye is required for a perspective camera in paper mode")
            if (e - p) @ w <= 0:
                raise IsplatError(f"camera.eye = {e.tolist()} must lie on the side camera.view_plane_normal points to "
                                  "(the normal points from the scene towards the viewer)")
    else:  # pragma: no cover - the scene validates modes
        raise IsplatError(f"camera.mode = {cam.mode!r}: expected orbit, look_at or paper")
    if persp:
        d_img = float((e - p) @ w)
        if d_img <= 0:
            raise IsplatError("camera: the eye must be in front of the image plane (distance > 0)")
        pix = 2.0 * d_img * math.tan(math.radians(cam.fov) / 2.0) / (cam.zoom * height)
        clip = float(cam.near) if cam.near and cam.near > 0 else 0.0
        near = clip or float(geom.spacing.min())
    else:
        pix = 2.0 * geom.radius / (cam.zoom * min(width, height))
        e, near, clip = None, 0.0, 0.0
    frame = ViewFrame("perspective" if persp else "orthographic", p, u, v, w, e, pix, width, height, near, clip)
    check_precision(cam, geom, frame)
    warn_if_empty(frame, geom)
    return frame


# world coordinates, pixels and voxels are float64: a coordinate more than PRECISION_RATIO times a pixel or a voxel
# step (2**40, errors above 1e-4 of either) lost the precision the projection needs (speckled images, from a
# volume.origin of 1e17; overflow at camera.zoom = 1e308)
PRECISION_RATIO = 2.0 ** 40


def check_precision(cam, geom: VolumeGeometry, frame: ViewFrame) -> None:
    """Refuse a view whose numbers lose float64 precision: a pixel of no size (camera.zoom, camera.fov), or world
    coordinates (volume.origin, the camera's points) too far from each other for the voxels and pixels."""
    step = float(geom.spacing.min())
    pix = frame.pixel_size
    zoom = getattr(cam, "zoom", 1.0)
    points = [geom.q, geom.centre, frame.p] + ([frame.e] if frame.e is not None else [])
    far = max(float(np.abs(x).max()) for x in points)
    if not math.isfinite(far) or far > PRECISION_RATIO * step:
        near_q = float(np.abs(geom.q).max()) >= far / 2
        which = "volume.origin" if near_q else "the camera's target, position or distance"
        raise IsplatError(f"{which}: world coordinates of {far:.3g} with voxels of {step:.3g} world units lose "
                          f"float64 precision (at most {PRECISION_RATIO:.3g} times a voxel); move the volume and "
                          f"camera nearer the world origin, e.g. volume.origin = [0, 0, 0]")
    if not (math.isfinite(pix) and pix > 0 and max(step, far) <= pix * PRECISION_RATIO
            and pix <= step * PRECISION_RATIO):
        fov = f", camera.fov = {cam.fov:g}" if frame.projection == "perspective" else ""
        lo, hi = _zoom_bound(zoom, pix, step, far, False), _zoom_bound(zoom, pix, step, far, True)
        raise IsplatError(f"camera.zoom = {zoom:g}{fov}: a pixel would be {pix:.3g} world units for voxels of "
                          f"{step:.3g} at coordinates up to {far:.3g}, beyond float64 precision (ratio at most "
                          f"{PRECISION_RATIO:.3g}); expected a zoom between about {lo:.3g} and {hi:.3g}")


def _zoom_bound(zoom, pix, step, far, upper: bool) -> float:
    if not (math.isfinite(pix) and pix > 0 and math.isfinite(zoom)):
        return 1.0 if not upper else PRECISION_RATIO
    return zoom * pix * (PRECISION_RATIO / max(step, far) if upper else 1.0 / (PRECISION_RATIO * step))


_WARNED: set = set()


def warn_if_empty(frame: ViewFrame, geom: VolumeGeometry) -> None:
    """A warning line (once per process and image) when the volume's box covers no pixel centre of the image,
    or spans less than two pixels across: the frame is empty or nearly (a zoom far out, a field of view near 180
    degrees, a camera looking away)."""
    n = geom.n_ijk.astype(np.float64)
    corners = np.array([[a, b, c] for a in (-0.5, n[0] - 0.5) for b in (-0.5, n[1] - 0.5)
                        for c in (-0.5, n[2] - 0.5)]) @ geom.steps + geom.q
    if frame.projection == "perspective":
        depth = (frame.e - corners) @ frame.w
        if np.all(depth <= 0):
            _warn(frame, "the volume is behind the camera")
            return
        if np.any(depth <= 0):
            return                                   # the eye is inside or beside the box: not judged here
    with np.errstate(all="ignore"):
        xy = project_points(frame, corners)
    if not np.all(np.isfinite(xy)):
        return
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    size = np.array([frame.width, frame.height], float)
    first, last = np.ceil(np.maximum(lo, 0.0)), np.floor(np.minimum(hi, size - 1))
    if np.any(last < first):
        _warn(frame, "the volume's box covers no pixel of the image")
    elif np.any(hi - lo < 2.0):
        _warn(frame, f"the volume's box spans {hi[0] - lo[0]:.2g} x {hi[1] - lo[1]:.2g} pixels")


def _warn(frame: ViewFrame, what: str) -> None:
    import logging

    key = (what.split(" spans")[0], frame.width, frame.height)
    if key in _WARNED:
        return
    _WARNED.add(key)
    logging.getLogger(__name__).warning(
        f"isplat: warning: {what} ({frame.width}x{frame.height}, a pixel {frame.pixel_size:.3g} world units): the "
        f"frame is empty or nearly; zoom in (camera.zoom), narrow camera.fov or point the camera at the volume")


def principal_axis(frame: ViewFrame, geom: VolumeGeometry) -> tuple[str, int]:
    """The slice axis among i, j, k and its traversal sign (+1: increasing index is front to back).

    Chosen in grid space (spacing accounted for): the axis whose slices the viewing ray crosses fastest,
    so a ray moves at most about one voxel within a slice per slice step (§2.2).
    """
    d_grid = (geom.unit_axes @ frame.direction) / geom.spacing
    c = int(np.argmax(np.abs(d_grid)))
    return AXES[c], (1 if d_grid[c] > 0 else -1)


def slice_order(frame: ViewFrame, geom: VolumeGeometry, axis: str, sign: int) -> np.ndarray:
    """Slice indices front to back. Orthographic: by ``sign``. Perspective: outward from the eye's slice
    coordinate, which is also right when the eye is inside the volume."""
    c = AXES.index(axis)
    n = int(geom.n_ijk[c])
    if frame.projection == "orthographic":
        order = np.arange(n) if sign > 0 else np.arange(n - 1, -1, -1)
    else:
        ce = geom.to_grid(frame.e)[c]
        order = np.argsort(np.abs(np.arange(n) - ce), kind="stable")
    return order.astype(np.int64)


@dataclass(frozen=True)
class Projection:
    """Per-frame constants of §3 for one slice axis, in pixel units.

    Orthographic (§3.1): ``x = X0 + c*Xc + a*Xa + b*Xb`` and likewise y; per slice two additions, per voxel
    two multiplications and two additions per coordinate.
    Perspective (§3.2): ``D = W0 + c*Wc + a*Wa + b*Wb`` (= w.(X - e) < 0 in front of the eye),
    ``t0 = wpe / D`` and ``x = cx + t0 * (X0 + c*Xc + a*Xa + b*Xb)`` with the numerator coefficients
    scaled by 1/pixel.
    """

    coef: np.ndarray       # float64[16]: X0 Xa Xb Xc Y0 Ya Yb Yc W0 Wa Wb Wc cx cy wpe near
    jac: np.ndarray        # float64[2, 3]: pixel motion per grid step along a, b, c (at t0 = 1)
    ds: float              # path length between slices along the central ray (world units)
    steps: np.ndarray      # rows A, B, C: world vectors of a grid step along a, b, c
    q: np.ndarray


def projection(frame: ViewFrame, geom: VolumeGeometry, axis: str) -> Projection:
    """Compute the paper's per-frame dot products once (§3.1, §3.2) for slices along ``axis``."""
    ia, ib, ic = SLICE_AXES[axis]
    S = geom.steps
    A, B, C = S[ia], S[ib], S[ic]
    pix = frame.pixel_size
    u, v, w = frame.u, frame.v, frame.w
    cx = frame.width / 2.0 - 0.5
    cy = frame.height / 2.0 - 0.5
    coef = np.zeros(16)
    if frame.projection == "orthographic":
        qp = geom.q - frame.p
        coef[0:4] = [cx + (u @ qp) / pix, (u @ A) / pix, (u @ B) / pix, (u @ C) / pix]
        coef[4:8] = [cy - (v @ qp) / pix, -(v @ A) / pix, -(v @ B) / pix, -(v @ C) / pix]
        coef[12:14] = [cx, cy]
    else:
        e = frame.e
        qe = geom.q - e
        pe = frame.p - e
        coef[0:4] = [(u @ qe) / pix, (u @ A) / pix, (u @ B) / pix, (u @ C) / pix]
        coef[4:8] = [-(v @ qe) / pix, -(v @ A) / pix, -(v @ B) / pix, -(v @ C) / pix]
        coef[8:12] = [w @ qe, w @ A, w @ B, w @ C]
        coef[12] = cx - (u @ pe) / pix
        coef[13] = cy + (v @ pe) / pix
        coef[14] = w @ pe
        coef[15] = frame.near
    jac = np.array([[u @ A, u @ B, u @ C], [-(v @ A), -(v @ B), -(v @ C)]]) / pix
    cos = abs(float(w @ geom.unit_axes[ic]))
    ds = float(geom.spacing[ic]) / max(cos, 1e-12)
    return Projection(coef, jac, ds, np.stack([A, B, C]), geom.q)


def project_points(frame: ViewFrame, points: np.ndarray) -> np.ndarray:
    """Direct 4x4-matrix projection of world points to pixel coordinates (x, y) — the obvious reference."""
    pts = np.atleast_2d(np.asarray(points, float))
    R = np.stack([frame.u, frame.v, frame.w])
    cx, cy = frame.width / 2.0 - 0.5, frame.height / 2.0 - 0.5
    M = np.eye(4)
    M[:3, :3] = R
    if frame.projection == "orthographic":
        M[:3, 3] = -R @ frame.p
        cam = (M @ np.c_[pts, np.ones(len(pts))].T).T
        x, y = cam[:, 0], cam[:, 1]
    else:
        M[:3, 3] = -R @ frame.e
        cam = (M @ np.c_[pts, np.ones(len(pts))].T).T          # eye space, looking along -z
        d_img = float((frame.e - frame.p) @ frame.w)
        P = np.array([[d_img, 0, 0, 0], [0, d_img, 0, 0], [0, 0, 1, 0], [0, 0, -1, 0]], float)
        h = (P @ cam.T).T
        x, y = h[:, 0] / h[:, 3], h[:, 1] / h[:, 3]
        # the image centre is where p projects
        pc = (M @ np.r_[frame.p, 1.0])
        x -= d_img * pc[0] / -pc[2]
        y -= d_img * pc[1] / -pc[2]
    return np.stack([cx + x / frame.pixel_size, cy - y / frame.pixel_size], axis=1)


# --- named anatomical views ---------------------------------------------------------------------------------------

# named view -> (towards the viewer, up), in patient LPS coordinates (isplat.orientation): the four side views
# have superior up; superior (from above) and inferior (from the feet, radiology's axial display) have anterior up
NAMED_VIEWS = {
    "anterior": ((0.0, -1.0, 0.0), (0.0, 0.0, 1.0)),
    "posterior": ((0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
    "left": ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
    "right": ((-1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
    "superior": ((0.0, 0.0, 1.0), (0.0, -1.0, 0.0)),
    "inferior": ((0.0, 0.0, -1.0), (0.0, -1.0, 0.0)),
}


def patient_to_world(axes_lps, unit_axes=None) -> np.ndarray:
    """3 x 3 matrix taking a patient (LPS) vector to world space, for a volume whose grid axes i, j, k are the
    rows of ``axes_lps`` in the patient and the rows of ``unit_axes`` (the scene's ``volume.axes``; default the
    identity) in the world. With ``unit_axes = axes_lps`` world space is patient space (the identity)."""
    a = np.asarray(axes_lps, dtype=np.float64)
    w = np.eye(3) if unit_axes is None else np.asarray(unit_axes, dtype=np.float64)
    # a patient vector p has grid coordinates c with a.T @ c = p; the world vector is w.T @ c
    return w.T @ np.linalg.solve(a.T, np.eye(3))


def named_view(view: str, axes_lps, azimuth: float = 0.0, elevation: float = 0.0,
               unit_axes=None) -> tuple[np.ndarray, np.ndarray]:
    """``(w, up)`` in world space for a named anatomical view of a volume oriented by ``axes_lps``.

    ``view`` is a key of :data:`NAMED_VIEWS`. ``w`` is the unit vector from the target towards the eye (the
    camera looks along ``-w``), ``up`` the frame's view-up (perpendicular to ``w``). ``azimuth`` turns the camera
    about the view's up (90 from ``anterior`` moves it to the patient's left), ``elevation`` lifts it towards
    the up (90 from ``anterior`` looks down from superior), as the orbit camera does about ``camera.up``.
    ``unit_axes`` are the world axes of i, j, k (see :func:`patient_to_world`): with the identity, a left-handed
    ``axes_lps`` shows the patient mirrored (no rotation undoes a mirror); place the volume with
    ``volume_geometry(..., axes=axes_lps)`` to see it as it is.
    """
    if view not in NAMED_VIEWS:
        raise IsplatError(f"camera.view = {view!r}: expected one of {', '.join(NAMED_VIEWS)}")
    if axes_lps is None:
        raise IsplatError(f"camera.view = {view!r} needs the scan's orientation, and the augmented file records "
                          "none (a .npy or raw input: augment it with --orientation, e.g. --orientation LPS)")
    m = patient_to_world(axes_lps, unit_axes)
    back, up = (np.asarray(x) for x in NAMED_VIEWS[view])
    # the third axis is taken in the patient, so azimuth 90 is the same side of the patient in a mirrored world
    e1, up, e2 = (_unit(m @ x, "view direction") for x in (back, up, np.cross(up, back)))
    az, el = math.radians(azimuth), math.radians(elevation)
    h = math.cos(az) * e1 + math.sin(az) * e2
    w = math.cos(el) * h + math.sin(el) * up
    v = -math.sin(el) * h + math.cos(el) * up
    return w / np.linalg.norm(w), v / np.linalg.norm(v)
