"""Convex decomposition of 2D polygons, extrusion to 3D prisms, and triangle meshes of extruded outlines.

A dynamic PhysX body collides only as convex hulls, so every non-convex shape
in the kit task (the L/T/star shapes) is handed to SAPIEN as a list of convex
pieces; the static board collides as one triangle mesh of its surface
(board.py says why) and keeps its convex decomposition as data.  All solids
here are vertical extrusions of 2D outlines, so a 2D convex decomposition
extruded over a z range is exact.

The decomposition is the classic Hertel-Mehlhorn scheme: triangulate the
polygon (holes included), then greedily delete internal diagonals whose
removal keeps the merged piece convex.  It is at most 4x the optimal piece
count and, unlike approximate decompositions (V-HACD, CoACD), the union of the
pieces is the polygon exactly, so slots keep their clearance and the board
keeps its walls.  The triangulation is GEOS's constrained Delaunay one: it
maximises the smallest angle, which keeps pieces from degenerating into
slivers (over the 300 default kit boards the thinnest piece is 0.42 mm wide,
against 0.05 mm with ear clipping); a sliver is what PhysX cooks worst.
"""

from __future__ import annotations

import math

import numpy as np
import shapely
from shapely.geometry import MultiPolygon, Polygon
from shapely.geometry.polygon import orient

# Relative tolerance (w.r.t. the polygon's size squared) for "this turn is straight".
_COLLINEAR_RTOL = 1e-12


def _polygon_scale(poly: Polygon) -> float:
    minx, miny, maxx, maxy = poly.bounds
    return max(maxx - minx, maxy - miny, 1e-12)


def _clean_ring(coords: np.ndarray, scale: float) -> np.ndarray:
    """Drop the closing point, repeated points and straight-through vertices.

    Earcut leaves collinear vertices in place and they would only add
    degenerate triangles; removing them up front keeps the triangulation and
    the resulting convex pieces minimal.
    """
    pts = np.asarray(coords, dtype=np.float64)[:, :2]
    if len(pts) > 1 and np.allclose(pts[0], pts[-1]):
        pts = pts[:-1]
    tol = _COLLINEAR_RTOL * scale * scale
    changed = True
    while changed and len(pts) > 3:
        changed = False
        keep = np.ones(len(pts), dtype=bool)
        for i in range(len(pts)):
            if not keep[i - 1]:
                continue  # re-examine neighbours on the next sweep
            prev_pt, pt, next_pt = pts[i - 1], pts[i], pts[(i + 1) % len(pts)]
            d1, d2 = pt - prev_pt, next_pt - pt
            cross = d1[0] * d2[1] - d1[1] * d2[0]
            if abs(cross) <= tol and (np.dot(d1, d2) >= 0 or np.dot(d1, d1) <= tol):
                keep[i] = False
                changed = True
        pts = pts[keep]
    return pts


def polygon_rings(poly: Polygon) -> list[np.ndarray]:
    """Cleaned rings of `poly`: exterior counter-clockwise, holes clockwise."""
    poly = orient(poly, sign=1.0)
    scale = _polygon_scale(poly)
    rings = [_clean_ring(np.asarray(poly.exterior.coords), scale)]
    rings += [_clean_ring(np.asarray(r.coords), scale) for r in poly.interiors]
    return rings


def triangulate(poly: Polygon) -> tuple[np.ndarray, np.ndarray]:
    """Constrained Delaunay triangulation of a polygon with holes, triangles counter-clockwise.

    Returns (vertices (N,2) float64, triangles (M,3) int64).  The polygon is
    rebuilt from its cleaned rings first (no repeated or straight-through
    vertices), and GEOS returns the input coordinates bit for bit, so
    triangles that share an edge share its two vertex indices, which the
    diagonal bookkeeping in hertel_mehlhorn() relies on.
    """
    rings = polygon_rings(poly)
    verts = np.ascontiguousarray(np.vstack(rings))
    triangles = shapely.get_parts(shapely.constrained_delaunay_triangles(Polygon(rings[0], rings[1:])))
    corners = shapely.get_coordinates(shapely.get_exterior_ring(triangles)).reshape(len(triangles), 4, 2)[:, :3]
    # Look the corners up among the vertices as complex numbers, which numpy sorts lexicographically.
    keys = verts.view(np.complex128).ravel()
    order = np.argsort(keys)
    wanted = np.ascontiguousarray(corners).view(np.complex128).reshape(-1)
    tris = order[np.searchsorted(keys[order], wanted)].reshape(-1, 3).astype(np.int64)
    if not np.array_equal(keys[tris].ravel(), wanted):
        raise AssertionError("triangulation returned a vertex that is not one of the polygon's")
    a, b, c = verts[tris[:, 0]], verts[tris[:, 1]], verts[tris[:, 2]]
    signed = 0.5 * ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))
    tol = _COLLINEAR_RTOL * _polygon_scale(poly) ** 2
    keep = np.abs(signed) > tol
    tris, signed = tris[keep], signed[keep]
    flip = signed < 0
    tris[flip] = tris[flip][:, [0, 2, 1]]
    return verts, tris


def _is_convex_turn(p0: np.ndarray, p1: np.ndarray, p2: np.ndarray, tol: float) -> bool:
    """Left turn or straight continuation at p1 (a 180-degree fold is not convex)."""
    d1, d2 = p1 - p0, p2 - p1
    cross = d1[0] * d2[1] - d1[1] * d2[0]
    if cross > tol:
        return True
    return abs(cross) <= tol and float(np.dot(d1, d2)) > 0


def _try_merge(p: list[int], q: list[int], a: int, b: int, verts: np.ndarray, tol: float) -> list[int] | None:
    """Merge CCW pieces p (holding edge a->b) and q (holding b->a) if the result is convex.

    Only the turns at a and b change, so only those are tested; a vertex shared
    elsewhere would make the union pinch, so that is rejected too.
    """
    if len((set(p) & set(q)) - {a, b}) > 0:
        return None
    ib, ia = p.index(b), q.index(a)
    p_rot = p[ib:] + p[:ib]  # b ... a
    q_rot = q[ia:] + q[:ia]  # a ... b
    merged = p_rot + q_rot[1:-1]
    k_a = len(p_rot) - 1
    n = len(merged)
    for k in (0, k_a):
        if not _is_convex_turn(verts[merged[k - 1]], verts[merged[k]], verts[merged[(k + 1) % n]], tol):
            return None
    return merged


def hertel_mehlhorn(verts: np.ndarray, tris: np.ndarray) -> list[list[int]]:
    """Greedily merge triangles across internal diagonals while pieces stay convex.

    Diagonals are visited longest first (a cheap heuristic that tends to remove
    the diagonals spanning the widest areas first, giving fewer pieces).  One
    pass suffices: a rejected diagonal can never become removable later because
    merging only widens the interior angles at its endpoints.
    """
    pieces: dict[int, list[int]] = {i: [int(v) for v in t] for i, t in enumerate(tris)}
    owner: dict[tuple[int, int], int] = {}
    for tri_id, tri in pieces.items():
        for k in range(3):
            owner[(tri[k], tri[(k + 1) % 3])] = tri_id
    diagonals = [(a, b) for (a, b) in owner if a < b and (b, a) in owner]
    diagonals.sort(key=lambda e: (-float(np.linalg.norm(verts[e[0]] - verts[e[1]])), e))
    scale = float(np.ptp(verts, axis=0).max()) if len(verts) else 1.0
    tol = _COLLINEAR_RTOL * scale * scale
    for a, b in diagonals:
        pid, qid = owner.get((a, b)), owner.get((b, a))
        if pid is None or qid is None or pid == qid:
            continue
        merged = _try_merge(pieces[pid], pieces[qid], a, b, verts, tol)
        if merged is None:
            continue
        del pieces[qid]
        del owner[(a, b)], owner[(b, a)]
        pieces[pid] = merged
        for k in range(len(merged)):
            owner[(merged[k], merged[(k + 1) % len(merged)])] = pid
    return [pieces[k] for k in sorted(pieces)]


def _drop_straight_vertices(pts: np.ndarray, tol: float) -> np.ndarray:
    """Remove vertices where a merged piece runs straight through (keeps hulls minimal)."""
    keep = [i for i in range(len(pts)) if _is_strict_turn(pts[i - 1], pts[i], pts[(i + 1) % len(pts)], tol)]
    return pts[keep]


def _is_strict_turn(p0: np.ndarray, p1: np.ndarray, p2: np.ndarray, tol: float) -> bool:
    d1, d2 = p1 - p0, p2 - p1
    return abs(d1[0] * d2[1] - d1[1] * d2[0]) > tol


def convex_decompose(geom: Polygon | MultiPolygon) -> list[np.ndarray]:
    """Split a polygon (holes allowed) or multipolygon into convex CCW pieces, (k,2) float64 each."""
    polys = list(geom.geoms) if isinstance(geom, MultiPolygon) else [geom]
    out: list[np.ndarray] = []
    for poly in polys:
        if poly.is_empty or poly.area <= 0:
            continue
        verts, tris = triangulate(poly)
        tol = _COLLINEAR_RTOL * _polygon_scale(poly) ** 2
        out.extend(_drop_straight_vertices(verts[piece], tol) for piece in hertel_mehlhorn(verts, tris))
    return out


def is_convex_polygon(pts: np.ndarray, rtol: float = 1e-12) -> bool:
    """True if the CCW vertex loop `pts` turns left (or straight) everywhere and winds once."""
    pts = np.asarray(pts, dtype=np.float64)
    if len(pts) < 3:
        return False
    scale = float(np.ptp(pts, axis=0).max())
    tol = rtol * scale * scale
    n = len(pts)
    if not all(_is_convex_turn(pts[i - 1], pts[i], pts[(i + 1) % n], tol) for i in range(n)):
        return False
    edges = np.roll(pts, -1, axis=0) - pts
    angles = np.arctan2(edges[:, 1], edges[:, 0])
    turning = np.mod(np.diff(np.append(angles, angles[0])) + math.pi, 2 * math.pi) - math.pi
    return abs(turning.sum() - 2 * math.pi) < 1e-6


def extrude_convex(pts2d: np.ndarray, z0: float, z1: float) -> np.ndarray:
    """Vertices (2k,3) float32 of the prism over a convex 2D polygon between z0 and z1.

    SAPIEN/PhysX builds the hull itself from a point cloud, so the vertex set is
    all a convex collision shape needs.
    """
    pts = np.asarray(pts2d, dtype=np.float64)
    lo = np.column_stack([pts, np.full(len(pts), z0)])
    hi = np.column_stack([pts, np.full(len(pts), z1)])
    return np.vstack([lo, hi]).astype(np.float32)


def extrude_mesh(geom: Polygon | MultiPolygon, z0: float, z1: float) -> tuple[np.ndarray, np.ndarray]:
    """Closed triangle mesh of `geom` extruded from z0 to z1: (vertices float32 (N,3), faces int32 (M,3)).

    Used for visual meshes.  Faces wind counter-clockwise seen from outside.
    Caps and every side quad get their own vertices, so renderers that derive
    vertex normals shade the prism flat instead of smearing normals across
    its sharp edges.  Built directly on the triangulation above rather
    than trimesh.creation.extrude_polygon: same result, without importing
    trimesh (seconds of import time) into the data layer.
    """
    polys = list(geom.geoms) if isinstance(geom, MultiPolygon) else [geom]
    parts = []
    for poly in polys:
        if poly.is_empty or poly.area <= 0:
            continue
        parts.append(_extrude_caps(poly, z0, z1))
        parts.extend(wall_mesh(ring, z0, z1) for ring in polygon_rings(poly))
    return merge_meshes(parts)


def _extrude_caps(poly: Polygon, z0: float, z1: float) -> tuple[np.ndarray, np.ndarray]:
    verts, tris = triangulate(poly)
    n = len(verts)
    v = np.vstack([np.column_stack([verts, np.full(n, z1)]), np.column_stack([verts, np.full(n, z0)])])
    f = np.vstack([tris, tris[:, ::-1] + n])  # top faces up, bottom faces down
    return v, f


def wall_mesh(ring: np.ndarray, z0: float, z1: float) -> tuple[np.ndarray, np.ndarray]:
    """One quad per ring edge; exterior CCW / holes CW puts the material on the left, so normals face out."""
    p = np.asarray(ring, dtype=np.float64)
    q = np.roll(p, -1, axis=0)
    m = len(p)
    quads = np.stack(
        [
            np.column_stack([p, np.full(m, z0)]),
            np.column_stack([q, np.full(m, z0)]),
            np.column_stack([q, np.full(m, z1)]),
            np.column_stack([p, np.full(m, z1)]),
        ],
        axis=1,
    ).reshape(-1, 3)
    base = 4 * np.arange(m)[:, None]
    f = np.vstack([base + [0, 1, 2], base + [0, 2, 3]])
    return quads, f


def merge_meshes(parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Concatenate (vertices, faces) meshes into one (float32, int32) pair."""
    verts, faces, offset = [], [], 0
    for v, f in parts:
        verts.append(np.asarray(v, dtype=np.float64))
        faces.append(np.asarray(f, dtype=np.int64) + offset)
        offset += len(v)
    return np.vstack(verts).astype(np.float32), np.vstack(faces).astype(np.int32)


def cap_mesh(poly: Polygon, z: float, up: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The triangulated polygon (holes allowed) at height z, facing up (or down)."""
    verts, tris = triangulate(poly)
    return np.column_stack([verts, np.full(len(verts), z)]), (tris if up else tris[:, ::-1])


def weld_mesh(vertices: np.ndarray, faces: np.ndarray, grid: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """One vertex per position (positions within `grid` metres of a grid point merge), faces re-indexed: what a
    collision mesh needs for PhysX to see which triangles are neighbours."""
    v = np.asarray(vertices, dtype=np.float64)
    keys = np.round(v / grid).astype(np.int64)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    return v[first].astype(np.float32), inverse.reshape(-1)[np.asarray(faces)].astype(np.int32)


def box_mesh(x0: float, y0: float, x1: float, y1: float, z0: float, z1: float) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box as a closed, outward-facing triangle mesh."""
    return extrude_mesh(Polygon([(x0, y0), (x1, y0), (x1, y1), (x0, y1)]), z0, z1)


def mesh_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Signed volume of a closed triangle mesh (positive when faces wind outward)."""
    v = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]
    return float(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0)
