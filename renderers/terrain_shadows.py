r'''Which terrain cells each renderer puts in shadow, and how far renderers disagree

SYNOPSIS

    from renderers.terrain_shadows import sample_points, compare
    from renderers.raycast_terrain import cell_shadows as raycast_cell_shadows
    from renderers.povray_terrain import cell_shadows as povray_cell_shadows
    from renderers.osmesa_terrain import cell_shadows as osmesa_cell_shadows

    code_r = raycast_cell_shadows(terrain)          # (Ny-1, Nx-1, 2) uint8
    code_p = povray_cell_shadows(terrain)           # same shape and codes
    code_o = osmesa_cell_shadows(terrain, map_size=4096)
    c = compare(code_r, code_o)                     # dict: fractions, where they differ

Every method is asked about the same points: the centroid of each of the two
triangles of every cell (targets/terrain.py: triangle 0, u >= v, has its
centroid at (u, v) = (2/3, 1/3); triangle 1 at (1/3, 2/3)), seen from straight
above. The codes are those of renderers.raycast_terrain: 0 lit, 1 facing away
from the sun (cos i <= 0), 2 in a cast shadow. "In shadow" means code != 0 (the
sun does not reach the point); a cast-shadow comparison (code 2 against 0)
restricted to triangles that face the sun is reported too, since facing away
is decided by the triangle's normal alone and every method gets it right.

The top-down views of the POV-Ray and OSMesa versions render an image with
pixel pitch cell/3 whose pixel centres are x0 + a cell/3, y0 + b cell/3: the
two centroids of cell (i, j) are pixels (3i+2, 3j+1) and (3i+1, 3j+2)
(`centroid_pixels`).
'''

import numpy as np

from reference_models.errors import CamvalError


class ShadowCompareError(CamvalError):
    '''Shadow codes that cannot be compared (shapes that do not match the terrain or each other)'''

CENTROIDS_UV = ((2.0 / 3.0, 1.0 / 3.0), (1.0 / 3.0, 2.0 / 3.0))


def sample_points(terrain):
    r'''(x, y) of the two triangle centroids of every cell

SYNOPSIS

    x, y = sample_points(terrain)      # each (Ny-1, Nx-1, 2) float64
'''
    ny, nx = terrain.heights.shape
    x0, y0 = terrain.origin
    i = np.arange(nx - 1)[None, :, None]
    j = np.arange(ny - 1)[:, None, None]
    u = np.array([c[0] for c in CENTROIDS_UV])[None, None, :]
    v = np.array([c[1] for c in CENTROIDS_UV])[None, None, :]
    x = x0 + (i + u) * terrain.cell
    y = y0 + (j + v) * terrain.cell
    shape = (ny - 1, nx - 1, 2)
    return np.broadcast_to(x, shape).copy(), np.broadcast_to(y, shape).copy()


def triangle_normals(terrain):
    r'''Unit upward normals of the two triangles of every cell: (Ny-1, Nx-1, 2, 3)'''
    h = terrain.heights
    c = terrain.cell
    h00, h10, h01, h11 = h[:-1, :-1], h[:-1, 1:], h[1:, :-1], h[1:, 1:]
    # triangle 0: z = h00 + u (h10 - h00) + v (h11 - h10)
    # triangle 1: z = h00 + v (h01 - h00) + u (h11 - h01)
    b0, c0 = (h10 - h00) / c, (h11 - h10) / c
    b1, c1 = (h11 - h01) / c, (h01 - h00) / c
    b = np.stack((b0, b1), axis=-1)
    cc = np.stack((c0, c1), axis=-1)
    n = np.stack((-b, -cc, np.ones_like(b)), axis=-1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def facing_away(terrain):
    r'''(Ny-1, Nx-1, 2) bool: triangles whose normal makes cos i <= 0 with the sun'''
    return triangle_normals(terrain) @ terrain.sun.direction() <= 0.0


def centroid_pixels(terrain):
    r'''(Ny-1, Nx-1, 2) column and row indices of the centroids in a cell/3 top-down image

SYNOPSIS

    col, row = centroid_pixels(terrain)
    W, H = top_down_size(terrain)
'''
    ny, nx = terrain.heights.shape
    i = np.arange(nx - 1)[None, :, None]
    j = np.arange(ny - 1)[:, None, None]
    col = 3 * i + np.array([2, 1])[None, None, :]
    row = 3 * j + np.array([1, 2])[None, None, :]
    shape = (ny - 1, nx - 1, 2)
    return np.broadcast_to(col, shape), np.broadcast_to(row, shape)


def top_down_size(terrain):
    r'''(W, H) of the top-down image with pixel pitch cell/3 (pixel (a, b) centred at
x0 + a cell/3, y0 + b cell/3)'''
    ny, nx = terrain.heights.shape
    return 3 * (nx - 1), 3 * (ny - 1)


def compare(code_a, code_b, terrain=None, grazing_cos=0.1):
    r'''How two methods' shadow codes disagree

SYNOPSIS

    c = compare(code_a, code_b)            # both (Ny-1, Nx-1, 2) uint8
    c = compare(code_a, code_b, terrain)   # also the figures that need the triangles' cos i

RETURNED VALUE: a dict with
- n_triangles, n_cells
- shadowed_fraction_a, shadowed_fraction_b: fraction of triangles with code != 0
- disagree_fraction: triangles where (code != 0) differs / all triangles
- disagree_cells_fraction: cells where either triangle differs / all cells
- facing_sun_disagree_fraction: among triangles that face the sun in both, where
  cast shadow (code 2) differs / those triangles
- facing_disagree: triangles where one says "facing away" and the other does not
- near_edge_fraction: of the disagreeing triangles, those within one cell
  (a 3x3 cell neighbourhood) of a shadow edge of method a
- max_edge_distance_cells: the largest Chebyshev distance (in cells) of a
  disagreeing triangle from the nearest shadow edge of method a
With the terrain (i the angle between a triangle's normal and the sun):
- grazing_fraction: of the disagreeing triangles, those with 0 < cos i < grazing_cos
  (nearly edge-on to the sun, i > 84 deg at 0.1: there a shadow map's bias hides
  occluders a few cm away, and the sun adds < 10% of its full light)
- edge_or_grazing_fraction: of the disagreeing triangles, those near an edge
  (as near_edge_fraction) or grazing
- disagree_fraction_not_grazing: triangles with cos i >= grazing_cos that differ / all
  triangles with cos i >= grazing_cos
- sunlight_weighted_disagreement: sum of cos i over differing triangles / sum of
  cos i over triangles facing the sun: the share of direct sunlight that the two
  methods put in different places
'''
    a = np.asarray(code_a)
    b = np.asarray(code_b)
    if a.shape != b.shape or a.ndim != 3 or a.shape[-1] != 2:
        raise ShadowCompareError(f"shadow codes must both be (Ny-1, Nx-1, 2); got {a.shape} "
                                 f"and {b.shape}")
    sa, sb = a != 0, b != 0
    diff = sa != sb
    facing = (a != 1) & (b != 1)
    n_facing = int(facing.sum())
    cast_diff = (a == 2) != (b == 2)
    dist = _chebyshev_distance(_edge_cells(sa))
    diff_cells = diff.any(axis=-1)
    nd = int(diff.sum())
    near = int((diff & (dist <= 1)[..., None]).sum())
    out = {
        "n_triangles": int(a.size), "n_cells": int(a.shape[0] * a.shape[1]),
        "shadowed_fraction_a": float(sa.mean()), "shadowed_fraction_b": float(sb.mean()),
        "cast_fraction_a": float((a == 2).mean()), "cast_fraction_b": float((b == 2).mean()),
        "disagree_triangles": nd,
        "disagree_fraction": nd / a.size,
        "disagree_cells_fraction": float(diff_cells.mean()),
        "facing_sun_triangles": n_facing,
        "facing_sun_disagree_fraction": float((cast_diff & facing).sum() / max(n_facing, 1)),
        "facing_disagree": int(((a == 1) != (b == 1)).sum()),
        "near_edge_fraction": near / nd if nd else 1.0,
        "max_edge_distance_cells": int(dist[diff_cells].max()) if nd else 0,
    }
    if terrain is not None:
        cosi = triangle_normals(terrain) @ terrain.sun.direction()
        if cosi.shape != a.shape:
            raise ShadowCompareError(f"the terrain has {cosi.shape} triangles; the codes "
                                     f"{a.shape}")
        grazing = (cosi > 0) & (cosi < grazing_cos)
        steep = cosi >= grazing_cos
        lit_w = np.where(cosi > 0, cosi, 0.0)
        out.update({
            "grazing_cos": grazing_cos,
            "grazing_fraction": float((diff & grazing).sum() / nd) if nd else 0.0,
            "edge_or_grazing_fraction":
                float((diff & (grazing | (dist <= 1)[..., None])).sum() / nd) if nd else 1.0,
            "disagree_fraction_not_grazing": float((diff & steep).sum() / max(steep.sum(), 1)),
            "sunlight_weighted_disagreement":
                float((lit_w * diff).sum() / max(lit_w.sum(), 1e-300)),
        })
    return out


def _edge_cells(s):
    r'''Cells (Ny-1, Nx-1) bool on a shadow edge: their two triangles differ, or a
4-neighbour cell differs (a cell counts as shadowed when either triangle is)'''
    c = s.any(axis=-1)
    e = s.any(axis=-1) != s.all(axis=-1)
    e[1:, :] |= c[1:, :] != c[:-1, :]
    e[:-1, :] |= c[1:, :] != c[:-1, :]
    e[:, 1:] |= c[:, 1:] != c[:, :-1]
    e[:, :-1] |= c[:, 1:] != c[:, :-1]
    return e


def _chebyshev_distance(edge):
    r'''Chebyshev distance (cells) of every cell to the nearest True cell of `edge`'''
    import cv2

    if not edge.any():
        return np.full(edge.shape, np.iinfo(np.int32).max // 2, np.int32)
    # distance transform of the non-edge cells, chessboard metric (C = 8 neighbours)
    free = (~edge).astype(np.uint8)
    d = cv2.distanceTransform(free, cv2.DIST_C, 3)
    return np.rint(d).astype(np.int32)
