"""A scan's orientation in the patient: the LPS directions of its grid axes (formats/augmented.md §3, ``axes_lps``).

isplat's patient coordinates are **LPS**, as DICOM and ITK use them: +x towards the patient's **l**eft, +y
**p**osterior, +z **s**uperior (head). ``axes_lps`` is a 3 x 3 matrix whose rows are the unit vectors, in LPS,
of the grid axes i, j, k (the same row convention as the scene's ``volume.axes``). Readers convert to it: NIfTI's
RAS (x right->left and y anterior->posterior negated), DICOM's LPS as is, an NRRD ``space`` of RAS, LAS or LPS,
MetaImage / ITK directions (LPS). A matrix that is not exactly orthonormal (a sheared affine, a gantry tilt) is
replaced by the nearest orthonormal one (polar decomposition), keeping its handedness.

Orientation codes name, for i, j, k in turn, the patient direction the axis points *to* (nibabel's ``aff2axcodes``
convention): ``LPS`` is the identity, ``RAS`` is NIfTI's identity affine, ``LIP`` means i towards the left, j
inferior, k posterior.

>>> axes_from_code("RAS").tolist()
[[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]]
>>> code_of(axes_from_code("LIP"))
'LIP'
"""

from __future__ import annotations

import numpy as np

from .errors import IsplatError

_LETTERS = {"L": (0, 1.0), "R": (0, -1.0), "P": (1, 1.0), "A": (1, -1.0), "S": (2, 1.0), "I": (2, -1.0)}
# the patient frames isplat converts to LPS: the sign of each axis
_SPACES = {"left-posterior-superior": (1, 1, 1), "lps": (1, 1, 1), "right-anterior-superior": (-1, -1, 1),
           "ras": (-1, -1, 1), "left-anterior-superior": (1, -1, 1), "las": (1, -1, 1)}
ORTHONORMAL_TOLERANCE = 1e-3


def axes_from_code(code: str, what: str = "orientation") -> np.ndarray:
    """Rows i, j, k of ``axes_lps`` for a three-letter code such as ``LPS`` or ``RAS``; one error line if bad."""
    c = str(code).strip().upper()
    if len(c) != 3 or any(x not in _LETTERS for x in c) or len({_LETTERS[x][0] for x in c}) != 3:
        raise IsplatError(f"{what} {code!r} invalid; expected three letters, one of L/R, one of A/P and one of "
                          "S/I, naming where i, j and k point (LPS: i to the patient's left, j posterior, "
                          "k superior; RAS: NIfTI's identity)")
    out = np.zeros((3, 3))
    for row, x in enumerate(c):
        axis, sign = _LETTERS[x]
        out[row, axis] = sign
    return out


def code_of(axes_lps) -> str:
    """The nearest orientation code of ``axes_lps`` (each axis named by its largest LPS component)."""
    names = (("R", "L"), ("A", "P"), ("I", "S"))
    out = ""
    for row in np.asarray(axes_lps, dtype=np.float64):
        a = int(np.argmax(np.abs(row)))
        out += names[a][int(row[a] > 0)]
    return out


def orthonormal(m, what: str = "orientation") -> np.ndarray:
    """The orthonormal matrix nearest ``m`` (rows), same handedness; one error line for a singular ``m``."""
    a = np.asarray(m, dtype=np.float64)
    if a.shape != (3, 3) or not np.all(np.isfinite(a)):
        raise IsplatError(f"{what} {np.asarray(m).tolist()} is not a finite 3 x 3 matrix")
    u, s, vt = np.linalg.svd(a)
    if s[-1] <= 1e-6 * max(s[0], 1e-300):
        raise IsplatError(f"{what} {a.tolist()} is singular: its axes do not span space")
    return u @ vt


def in_lps(rows, space: str, what: str) -> np.ndarray:
    """Axis rows given in the patient frame ``space`` (an NRRD ``space`` name, or ``ras``/``lps``/``las``) as LPS,
    normalised to an orthonormal set."""
    sign = _SPACES.get(str(space).strip().lower())
    if sign is None:
        raise IsplatError(f"{what}: patient space {space!r} unknown; expected one of {', '.join(_SPACES)}")
    return orthonormal(np.asarray(rows, dtype=np.float64) * np.asarray(sign, dtype=np.float64), what)


def check_axes_lps(path, a) -> np.ndarray:
    """An ``axes_lps`` attribute as read: 3 x 3, orthonormal to :data:`ORTHONORMAL_TOLERANCE`."""
    err = float(np.max(np.abs(a @ a.T - np.eye(3))))
    if not err <= ORTHONORMAL_TOLERANCE:
        raise IsplatError(f"{path}: attribute 'axes_lps' is {a.tolist()}, expected orthonormal rows (A·Aᵀ = I "
                          f"to within {ORTHONORMAL_TOLERANCE:g}; off by {err:.3g})")
    return a


def describe(axes_lps) -> str:
    """One phrase for a log line: the code, and the matrix when it is oblique."""
    if axes_lps is None:
        return "orientation unknown"
    a = np.asarray(axes_lps, dtype=np.float64)
    code = code_of(a)
    exact = np.allclose(a, axes_from_code(code), atol=1e-6)
    hand = "" if np.linalg.det(a) > 0 else ", left-handed"
    rows = "" if exact else " (oblique: " + "; ".join(",".join(f"{x:.3f}" for x in r) for r in a) + ")"
    return f"orientation {code}{rows}{hand}: i, j, k point to the patient's {_words(code)}"


def _words(code: str) -> str:
    names = {"L": "left", "R": "right", "A": "anterior", "P": "posterior", "S": "superior", "I": "inferior"}
    return ", ".join(names[c] for c in code)
