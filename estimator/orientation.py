"""Platform heading: angle wrapping, atan2 heading, and the dissertation's law-of-cosines
construction (000_8f82f8df647bf685.txt, Section 3.2, Eq. 3.10, Figure 3.1).

Conventions (project-wide, DESIGN.md): world x east, y north; yaw is counter-clockwise from
+x (east), wrapped to (-pi, pi]. The dissertation measures orientation from North = 0
(Section 3.2) in [0, 2 pi) with quadrants I..IV following each other clockwise like a
compass (I = between North and East). We read it as a compass bearing ``beta``; the mapping is

    yaw = wrap(pi/2 - beta),    beta = (pi/2 - yaw) mod 2 pi.

See :func:`yaw_from_bearing` / :func:`bearing_from_yaw`.
"""

from __future__ import annotations

from typing import overload

import numpy as np

__all__ = [
    "angle_diff",
    "bearing_from_yaw",
    "heading_from_points",
    "law_of_cosines_angle",
    "law_of_cosines_bearing",
    "law_of_cosines_heading",
    "unwrap_angle",
    "wrap_angle",
    "yaw_from_bearing",
]

_TWO_PI = 2.0 * np.pi
#: law_of_cosines_angle: largest |cos C| - 1 treated as rounding (clipped), not an error.
_COS_EXCESS_TOL = 1e-9


@overload
def wrap_angle(a: float) -> float: ...
@overload
def wrap_angle(a: np.ndarray) -> np.ndarray: ...
def wrap_angle(a: np.ndarray | float) -> np.ndarray | float:
    """Wrap angles (radians) to (-pi, pi]. Any shape; a Python float in gives a float out.

    Angles already in (-pi, pi] come back bit for bit; NaN stays NaN.
    """
    arr = np.asarray(a, dtype=float)
    w = np.pi - np.mod(np.pi - arr, _TWO_PI)  # np.mod -> [0, 2pi), so w in (-pi, pi]
    # np.mod can round up to exactly 2 pi for tiny negative arguments -> w = -pi
    w = np.where(w <= -np.pi, w + _TWO_PI, w)
    # angles already in range are returned unchanged (the formula rounds them to ~1e-16)
    w = np.where((arr > -np.pi) & (arr <= np.pi), arr, w)
    if np.ndim(a) == 0 and not isinstance(a, np.ndarray):
        return float(w)
    return w


def angle_diff(a: np.ndarray | float, b: np.ndarray | float) -> np.ndarray | float:
    """Signed difference a - b wrapped to (-pi, pi] (used for Eq. 4.2 heading errors)."""
    return wrap_angle(np.asarray(a, dtype=float) - np.asarray(b, dtype=float)) if (
        np.ndim(a) or np.ndim(b)) else wrap_angle(float(a) - float(b))


def unwrap_angle(a: np.ndarray, axis: int = -1) -> np.ndarray:
    """Continuous version of a wrapped angle sequence (numpy.unwrap), NaN-tolerant.

    NaN entries stay NaN and are skipped when unwrapping the finite ones.
    """
    a = np.asarray(a, dtype=float)
    if a.ndim != 1:
        return np.unwrap(a, axis=axis)
    out = np.full_like(a, np.nan)
    ok = np.isfinite(a)
    if ok.any():
        out[ok] = np.unwrap(a[ok])
    return out


def heading_from_points(front: np.ndarray, rear: np.ndarray) -> np.ndarray:
    """Yaw of the line rear -> front: atan2(dy, dx), wrapped to (-pi, pi].

    front, rear : (..., 2) or (..., 3) metres (z ignored), broadcastable.
    Returns (...) radians, CCW from +x (east). NaN where either point is NaN.
    """
    front = np.asarray(front, dtype=float)
    rear = np.asarray(rear, dtype=float)
    if front.shape[-1:] not in ((2,), (3,)) or rear.shape[-1:] not in ((2,), (3,)):
        raise ValueError(
            f"front/rear: last axis must be 2 or 3 (x, y[, z]), got shapes {front.shape} "
            f"and {rear.shape}")
    d = front[..., :2] - rear[..., :2]
    return wrap_angle(np.arctan2(d[..., 1], d[..., 0]))


def yaw_from_bearing(bearing: np.ndarray | float) -> np.ndarray | float:
    """Compass bearing (North = 0, clockwise, radians) -> yaw (CCW from east, (-pi, pi]).

    bearing : scalar or array of any shape (...), radians (any value; wrapped).
    Returns the same shape (a Python float for a scalar), radians in (-pi, pi].
    Section 3.2 measures orientation from North; see the module docstring for the mapping.
    """
    return wrap_angle(np.pi / 2 - np.asarray(bearing, dtype=float)) if np.ndim(bearing) else \
        wrap_angle(np.pi / 2 - float(bearing))


def bearing_from_yaw(yaw: np.ndarray | float) -> np.ndarray | float:
    """Yaw (CCW from east) -> compass bearing in [0, 2 pi) (North = 0, clockwise).

    yaw : scalar or array of any shape (...), radians (any value).
    Returns the same shape (a Python float for a scalar), radians in [0, 2 pi): the
    orientation of Section 3.2 (the inverse of :func:`yaw_from_bearing`).
    """
    b = np.mod(np.pi / 2 - np.asarray(yaw, dtype=float), _TWO_PI)
    return b if np.ndim(yaw) else float(b)


def law_of_cosines_angle(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Eq. 3.10: C = arccos((a^2 + b^2 - c^2) / (2 a b)), the angle opposite side c.

    a, b, c : side lengths (metres), broadcastable; returns their broadcast shape, radians in
    [0, pi]. The cosine is clipped to [-1, 1] only to absorb floating-point rounding
    (``|cos C| - 1 <= 1e-9``, :data:`_COS_EXCESS_TOL`); a larger excess means the three
    lengths do not form a triangle and raises ValueError. NaN where a or b is 0 or NaN.
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    c = np.asarray(c, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos_c = (a * a + b * b - c * c) / (2.0 * a * b)
    excess = np.abs(cos_c) - 1.0
    if np.any(np.isfinite(excess) & (excess > _COS_EXCESS_TOL)):
        raise ValueError(f"a, b, c: side lengths violate the triangle inequality "
                         f"(max |cos C| - 1 = {float(np.nanmax(excess)):.3g})")
    with np.errstate(invalid="ignore"):
        return np.arccos(np.clip(cos_c, -1.0, 1.0))


def law_of_cosines_bearing(vec: np.ndarray, reference: np.ndarray | None = None) -> np.ndarray:
    """Bearing of ``vec`` relative to ``reference`` by Eq. 3.10 and the quadrant rules of
    Figure 3.1 (Section 3.2), in [0, 2 pi), measured clockwise (compass sense).

    vec : (..., 2) metres, a side of the platform translated to the origin.
    reference : (..., 2) the reference direction translated to the origin; default North
        (0, 1), which gives the absolute compass bearing.

    Construction (our reading of Section 3.2): a = |reference|, b = |vec|,
    c = |vec - reference|, C_t from Eq. 3.10 (angle at the origin between the two rays).
    The quadrant rules "I: C, II: pi - C, III: pi + C, IV: 2 pi - C" are consistent only if C is
    the acute angle between ``vec`` and the reference *line*, so we use
    C' = min(C, pi - C); quadrants are counted clockwise from the reference (I between the
    reference and its clockwise perpendicular, "East" when the reference is North). With this
    reading the rules return the full-circle bearing; agreement with atan2 is tested.
    A vector on an axis goes to the quadrant the axis opens (the rules agree there).
    Returns (...) radians in [0, 2 pi); NaN where vec (or reference) is NaN or zero.
    """
    v = np.asarray(vec, dtype=float)
    if v.shape[-1:] != (2,):
        raise ValueError(f"vec: last axis must be 2 (x, y), got shape {v.shape}")
    if reference is None:
        r = np.broadcast_to(np.array([0.0, 1.0]), v.shape)
    else:
        r = np.asarray(reference, dtype=float)
        if r.shape[-1:] != (2,):
            raise ValueError(f"reference: last axis must be 2 (x, y), got shape {r.shape}")
        v, r = np.broadcast_arrays(v, r)
    a = np.hypot(r[..., 0], r[..., 1])
    b = np.hypot(v[..., 0], v[..., 1])
    c = np.hypot(v[..., 0] - r[..., 0], v[..., 1] - r[..., 1])
    C = law_of_cosines_angle(a, b, c)  # Eq. 3.10, in [0, pi]
    Cp = np.minimum(C, np.pi - C)  # acute angle to the reference line
    # clockwise perpendicular of the reference ("East" of North): (ry, -rx)
    along = v[..., 0] * r[..., 0] + v[..., 1] * r[..., 1]
    across = v[..., 0] * r[..., 1] - v[..., 1] * r[..., 0]
    q1 = (along > 0) & (across >= 0)
    q2 = (along <= 0) & (across > 0)
    q3 = (along < 0) & (across <= 0)
    out = np.select([q1, q2, q3], [Cp, np.pi - Cp, np.pi + Cp], default=_TWO_PI - Cp)
    out = np.where((a > 0) & (b > 0), out, np.nan)
    out = np.mod(out, _TWO_PI)
    return out


def law_of_cosines_heading(side: np.ndarray, body_angle: float = 0.0) -> np.ndarray:
    """Platform yaw (CCW from east, (-pi, pi]) from a sequence of platform sides, the way
    Section 3.2 describes it: relative to the initial estimate.

    side : (n, 2) world vectors of one platform side (e.g. rear sensor -> front sensor of
        each estimate), NaN rows allowed.
    body_angle : angle of that side in the body frame (radians, CCW from body +x), so that a
        side that is not along the body axis still gives the heading of body +x.

    Steps: the initial (first finite) side's bearing from North, beta_0, comes from
    :func:`law_of_cosines_bearing` with the North reference; every later side's change of
    orientation, delta_t, from the same construction with the initial side as reference
    ("using the initial estimate as a reference orientation"); beta_t = beta_0 + delta_t.
    The bearing is mapped to our yaw (module docstring) and the body angle removed.
    Returns (n,) radians; NaN rows stay NaN.
    """
    side = np.asarray(side, dtype=float)
    if side.ndim != 2 or side.shape[1] != 2:
        raise ValueError(f"side: expected shape (n, 2), got {side.shape}")
    out = np.full(side.shape[0], np.nan)
    ok = np.all(np.isfinite(side), axis=1) & (np.hypot(side[:, 0], side[:, 1]) > 0)
    if not ok.any():
        return out
    ref = side[np.argmax(ok)]
    beta0 = law_of_cosines_bearing(ref)  # absolute bearing of the initial estimate
    delta = law_of_cosines_bearing(side[ok], ref[None, :])  # change relative to it
    out[ok] = wrap_angle(yaw_from_bearing(beta0 + delta) - body_angle)
    return out
