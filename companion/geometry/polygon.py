"""Plane polygons: point inside, segment crossings, simplicity, distances.

Pure 2-D arithmetic on ``(x, y)`` pairs; the caller picks the plane (the geofence uses local
north/east metres). A polygon is its vertices in order, closed implicitly (last -> first).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

Point2 = tuple[float, float]


def _cross(o: Point2, a: Point2, b: Point2) -> float:
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def edges(poly: Sequence[Point2]) -> list[tuple[Point2, Point2]]:
    n = len(poly)
    return [(poly[i], poly[(i + 1) % n]) for i in range(n)]


def signed_area(poly: Sequence[Point2]) -> float:
    """Shoelace area, positive when the vertices run counter-clockwise in (x, y)."""
    return 0.5 * sum(a[0] * b[1] - b[0] * a[1] for a, b in edges(poly))


def point_in_polygon(p: Point2, poly: Sequence[Point2]) -> bool:
    """Even-odd rule (ray towards +x). A point on an edge counts as inside."""
    x, y = p
    inside = False
    for a, b in edges(poly):
        if point_segment_distance(p, a, b) < 1e-9:
            return True
        if (a[1] > y) != (b[1] > y):
            x_cross = a[0] + (y - a[1]) * (b[0] - a[0]) / (b[1] - a[1])
            if x < x_cross:
                inside = not inside
    return inside


def _on_segment(p: Point2, a: Point2, b: Point2) -> bool:
    return min(a[0], b[0]) - 1e-12 <= p[0] <= max(a[0], b[0]) + 1e-12 and (
        min(a[1], b[1]) - 1e-12 <= p[1] <= max(a[1], b[1]) + 1e-12
    )


def segments_intersect(p1: Point2, p2: Point2, q1: Point2, q2: Point2) -> bool:
    """Whether the closed segments p1-p2 and q1-q2 share a point (touching counts)."""
    d1, d2 = _cross(q1, q2, p1), _cross(q1, q2, p2)
    d3, d4 = _cross(p1, p2, q1), _cross(p1, p2, q2)
    if ((d1 > 0 > d2) or (d1 < 0 < d2)) and ((d3 > 0 > d4) or (d3 < 0 < d4)):
        return True
    return (
        (d1 == 0 and _on_segment(p1, q1, q2))
        or (d2 == 0 and _on_segment(p2, q1, q2))
        or (d3 == 0 and _on_segment(q1, p1, p2))
        or (d4 == 0 and _on_segment(q2, p1, p2))
    )


def segment_crossing_t(p1: Point2, p2: Point2, q1: Point2, q2: Point2) -> float | None:
    """Where along p1 -> p2 (t in [0, 1]) it meets q1-q2; None if they do not meet. Collinear
    overlaps give the first shared point."""
    if not segments_intersect(p1, p2, q1, q2):
        return None
    rx, ry = p2[0] - p1[0], p2[1] - p1[1]
    sx, sy = q2[0] - q1[0], q2[1] - q1[1]
    den = rx * sy - ry * sx
    if den != 0.0:
        t = ((q1[0] - p1[0]) * sy - (q1[1] - p1[1]) * sx) / den
        return min(1.0, max(0.0, t))
    rr = rx * rx + ry * ry
    if rr == 0.0:
        return 0.0
    ts = [((q[0] - p1[0]) * rx + (q[1] - p1[1]) * ry) / rr for q in (q1, q2)]
    ts = [t for t in ts if 0.0 <= t <= 1.0]
    return min(ts) if ts else 0.0


def point_segment_distance(p: Point2, a: Point2, b: Point2) -> float:
    ax, ay = b[0] - a[0], b[1] - a[1]
    L2 = ax * ax + ay * ay
    t = 0.0 if L2 == 0.0 else max(0.0, min(1.0, ((p[0] - a[0]) * ax + (p[1] - a[1]) * ay) / L2))
    return math.hypot(p[0] - a[0] - t * ax, p[1] - a[1] - t * ay)


def segment_distance(p1: Point2, p2: Point2, q1: Point2, q2: Point2) -> float:
    if segments_intersect(p1, p2, q1, q2):
        return 0.0
    return min(
        point_segment_distance(p1, q1, q2),
        point_segment_distance(p2, q1, q2),
        point_segment_distance(q1, p1, p2),
        point_segment_distance(q2, p1, p2),
    )


def polygon_problem(poly: Sequence[Point2]) -> str | None:
    """Why ``poly`` is not a simple polygon (None when it is): fewer than 3 vertices, a vertex
    repeated, no area, or two edges that cross or touch other than at their shared vertex."""
    n = len(poly)
    if n < 3:
        return f"{n} vertices: a polygon needs at least 3"
    for i in range(n):
        for j in range(i + 1, n):
            if poly[i] == poly[j]:
                return f"vertices {i} and {j} are the same point {poly[i]}"
    es = edges(poly)
    for i in range(n):
        for j in range(i + 1, n):
            if j == i + 1 or (i == 0 and j == n - 1):
                continue  # neighbours share a vertex
            if segments_intersect(*es[i], *es[j]):
                return f"edge {i}-{(i + 1) % n} crosses edge {j}-{(j + 1) % n}: not a simple polygon"
    if abs(signed_area(poly)) < 1e-12:
        return "its vertices are collinear: it has no area"
    return None
