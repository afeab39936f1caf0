"""The outline of an antenna layout: the convex hull of its points, in counter-clockwise order.

Every drawing of a layout as a polygon (the page's replay, the rendered clips' estimate ghost,
the stationary configuration figures) uses these indices. Ordering the points by their angle
round the body origin (or round their mean) is not an outline: a point at (or near) that centre
has no meaningful angle and the polygon crosses itself (a "bow-tie"); points inside the hull
(an antenna at the body origin) are drawn as points, not as corners of the outline.
"""

from __future__ import annotations

import numpy as np

__all__ = ["is_simple_polygon", "layout_outline"]


def _cross(o: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    return float((a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]))


def _chain(p: np.ndarray, order: np.ndarray, tol: float) -> list[int]:
    """One half of Andrew's monotone chain: keeps only strict left turns."""
    out: list[int] = []
    for i in order:
        while len(out) >= 2 and _cross(p[out[-2]], p[out[-1]], p[i]) <= tol:
            out.pop()
        out.append(int(i))
    return out


def layout_outline(points) -> list[int]:
    """Indices of the convex hull of ``points`` (m, 2) (metres, any frame), counter-clockwise,
    starting at the point with the smallest x (then y). Interior points and points on an edge
    are left out; coincident points count once. One distinct point gives one index, points on
    a line the two ends. Andrew's monotone chain (O(m log m)); a turn counts as straight when
    its cross product is within 1e-12 x the squared size of the layout (rounding, not
    geometry). Raises ValueError for a non-(m, 2) array or a non-finite coordinate."""
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 2 or p.shape[0] == 0:
        raise ValueError(f"points: must be an (m, 2) array with m >= 1, got shape {p.shape}")
    if not np.isfinite(p).all():
        bad = np.argwhere(~np.isfinite(p))[0]
        raise ValueError(f"points[{bad[0]}]: must be finite, got {p[bad[0]].tolist()}")
    order = np.lexsort((p[:, 1], p[:, 0]))
    _, first = np.unique(p[order], axis=0, return_index=True)
    order = order[np.sort(first)]                # one index per distinct point, sorted x, y
    if len(order) <= 2:
        return [int(i) for i in order]
    tol = 1e-12 * float(np.ptp(p, axis=0).max()) ** 2
    lower, upper = _chain(p, order, tol), _chain(p, order[::-1], tol)
    return lower[:-1] + upper[:-1]


def _segments_cross(a, b, c, d) -> bool:
    """Whether the closed segments ab and cd share a point."""
    d1, d2 = _cross(c, d, a), _cross(c, d, b)
    d3, d4 = _cross(a, b, c), _cross(a, b, d)
    if ((d1 > 0) != (d2 > 0)) and ((d3 > 0) != (d4 > 0)) and 0 not in (d1, d2, d3, d4):
        return True
    def on(p, q, r) -> bool:       # r, collinear with pq, lies within the segment pq
        return (min(p[0], q[0]) <= r[0] <= max(p[0], q[0])
                and min(p[1], q[1]) <= r[1] <= max(p[1], q[1]))

    return any(v == 0 and on(*s) for v, s in ((d1, (c, d, a)), (d2, (c, d, b)),
                                               (d3, (a, b, c)), (d4, (a, b, d))))


def is_simple_polygon(vertices) -> bool:
    """Whether the closed polygon through ``vertices`` (k, 2) in order is simple: no two
    non-adjacent edges share a point (adjacent edges share only their common vertex). A
    polygon with fewer than 3 vertices is not simple."""
    v = np.asarray(vertices, dtype=float)
    k = len(v)
    if k < 3:
        return False
    edges = [(v[i], v[(i + 1) % k]) for i in range(k)]
    for i in range(k):
        for j in range(i + 1, k):
            if j == i + 1 or (i == 0 and j == k - 1):
                continue
            if _segments_cross(*edges[i], *edges[j]):
                return False
    return True
