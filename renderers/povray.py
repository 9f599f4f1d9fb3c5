r'''POV-Ray 3.7 as a camval renderer: the paper's pinhole-then-warp path and a direct mesh camera

SYNOPSIS

    from renderers.base import get_renderer, RenderSettings

    r = get_renderer("povray")                      # camera="perspective" (then the warp)
    r = get_renderer("povray", camera="mesh")       # exact rays per (sub)pixel
    result = r.render(model, target.pattern(), Rt_cam_board, RenderSettings(spp=4))
    # result.image has shape (model.height, model.width), float32 in [0,1]

The scene is written as a .pov file in a temporary directory and `povray` is
run headless (-D, 16-bit linear PNG: +FN16 File_Gamma=1.0, assumed_gamma 1).
Materials are flat: ambient 1, diffuse 0, no lights, so a pixel is the albedo
of what it sees (the board of targets.pattern.Pattern: a polygon for the
board, a thin box per cell, a thin cylinder per dot; layers are separated by
LAYER_OFFSET = 1e-7 m along the board normal on both faces, which moves an
edge by less than 1e-4 px at 1 m for f < 2000 px).

POV-Ray's coordinates are the model's camera frame (x = H', y = A x H',
z = A, origin C) with y negated (POV-Ray's y is up).

Camera paths (option `camera`):

- "perspective" (the paper's ROAMS path): an oversized pinhole
  (renderers.warp.PinholeWarp) rendered by POV-Ray's perspective camera, then
  warped to the model with cv2.remap (option `interpolation`, bilinear or
  bicubic). Pixel convention, measured with POV-Ray 3.7.0.10 (tests): pixel
  (i, j) is traced through the screen point ((i+0.5)/W - 0.5,
  0.5 - (j+0.5)/H) of the right/up vectors, so the principal point is
  ((W-1)/2, (H-1)/2) in camval's convention; the direction vector is offset
  to put the pinhole's (cx, cy) where it belongs.
  Supersampling K x K: POV-Ray's anti-aliasing (+AM1 -J +R n, n <= 9)
  samples an n x n grid centred on the pixel and averages it with the
  pixel's centre sample (weights 1/(n^2+1), centre 2/(n^2+1)); K = n b with
  b > 1 renders b times finer and averages b x b blocks. Full sampling
  (RenderSettings.adaptive False) forces it on every pixel (+A0.0); adaptive
  lets POV-Ray supersample the pixels that differ from a neighbour by more
  than PERSPECTIVE_AA_THRESHOLD = 0.01 (+A0.01): 6x faster at K = 4, 19x at
  K = 16 on the 1024x1024 navcam (it compares pixel centres, so an edge that
  clips a pixel without changing its centre's colour is missed).
- "mesh": a smooth mesh_camera (distribution 3), the model's rays up to
  MESH_TOLERANCE = 0.001 px. Distribution 3 maps image pixel (I, J) to the
  uv point (I/W, 1 - J/H) of the mesh (measured; image row 0 is sampled half
  a row low, so row 0 is left empty), finds the face holding it and starts
  the ray at that point of the face, along the barycentric mix of the face's
  vertex normals (`smooth`), which POV-Ray normalises when it parses them
  and again after mixing (measured). The mesh's vertices sit on the model's
  pixel-corner grid every `step` pixels, at origin + s * v for the corner's
  unit ray direction v (so a ray starts on the interpolated ray through the
  interpolated origin; s is a quarter of the board plane's distance), with
  v as normal and uv placing each corner in an atlas image. The mix of unit
  vectors departs from the exact ray by mesh_interpolation_error (quadratic
  in the step: 0.0008 px at 2 px, 0.05 px at 16 px on the MER B navcam).
  Any block of model pixels can so be rendered at any K x K (fine pixel
  (a, b) of a block samples the sub-pixel centre
  (x0 + (a+0.5)/K - 0.5, y0 + (b+0.5)/K - 0.5)); scene files stay small.
  Adaptive sampling (the default) renders, in one POV-Ray run when the faces
  fit (MESH_RUN_FACES: distribution 3 finds a sample's face by a linear
  scan), the whole image at one ray per pixel on a coarse grid, and K x K in
  the 2x2-pixel cells that an edge of the pattern crosses (edge_pixels),
  on the 2- or 1-px grid that MESH_TOLERANCE needs (the coarse grid may be
  off by up to MESH_COARSE_TOLERANCE = 0.1 px: those pixels' centres lie
  >= 0.5 px from any edge). The ray caster's images are reproduced (tests:
  equal at K = 4 up to 2 pixels, full and adaptive, noncentral CAHVORE
  included).
  Distribution 0 (one face per ray, used before) needed K^2 triangles per
  pixel (4 GB of scene file at K = 4 for 1024x1024) and traced face row
  j - 1 for image row j in POV-Ray 3.7.0.10: the same row-0 clamp.

A missing `povray` binary raises RendererUnavailableError at construction.
'''

import os
import re
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass

import numpy as np

from .base import (
    RendererError,
    RendererUnavailableError,
    RenderResult,
    RenderSettings,
    merged_options,
)
from .warp import INTERPOLATIONS, PinholeWarp, box_downsample

CAMERAS = ("perspective", "mesh")
LAYER_OFFSET = 1e-7
MAX_AA_DEPTH = 9
# perspective path with adaptive sampling: POV-Ray supersamples the pixels whose colour
# differs from a neighbour's by more than this (+AM1 +A0.01); 0 (every pixel) when not adaptive
PERSPECTIVE_AA_THRESHOLD = 0.01
# mesh camera: the grid step (px) of its vertices where edges are: the coarsest of
# MESH_STEPS whose interpolated rays are within MESH_TOLERANCE px of the exact ones
# (MER B navcam: 7.7e-4 px at 2 px; Rocky8 hazcam: 9e-4 (CAHVOR), 5e-4 (CAHVORE) at 1 px)
MESH_TOLERANCE = 1e-3
MESH_STEPS = (2, 1)
# elsewhere (pixels that see one material) the coarsest of MESH_COARSE_STEPS within
# MESH_COARSE_TOLERANCE (edge_pixels leaves them >= 0.5 px from any edge)
MESH_COARSE_TOLERANCE = 0.1
MESH_COARSE_STEPS = (32, 16, 8, 4, 2, 1)
# adaptive supersampling in cells of MESH_CELL x MESH_CELL pixels
MESH_CELL = 2
# faces per POV-Ray run: distribution 3 finds a sample's face by a linear scan
MESH_RUN_FACES = 8192
# fine pixels per POV-Ray run (its image buffer takes ~20 bytes per pixel) and atlas width
MESH_RUN_PIXELS = 1 << 23
MESH_ATLAS_WIDTH = 2048
MESH_ATLAS_TOP = 1
INSTALL_HINT = "install Debian package povray (apt-get install povray)"


def _fmt(x):
    return f"{x:.17g}"


def _vec(v):
    return "<" + ",".join(_fmt(float(c)) for c in v) + ">"


def split_supersampling(K):
    r'''K -> (n, b): POV-Ray anti-aliasing n x n (n <= 9) on an image b times finer, K = n b'''
    K = int(K)
    for n in range(min(K, MAX_AA_DEPTH), 0, -1):
        if K % n == 0:
            return n, K // n
    return 1, K


def scene_objects(pattern, Rt_cam_board):
    r'''The board of a Pattern in POV-Ray scene language, placed by Rt_cam_board

The board is described in its own frame and moved by a `matrix` transform:
board -> camera frame (Rt_cam_board) -> POV-Ray (y negated).
'''
    Rt = np.asarray(Rt_cam_board, dtype=np.float64)
    if Rt.shape != (4, 3) or not np.all(np.isfinite(Rt)):
        raise RendererError(f"Rt_cam_board must be a finite (4,3) array; got shape {Rt.shape}")
    F = np.diag([1.0, -1.0, 1.0])
    M = F @ Rt[:3]
    t = F @ Rt[3]
    # POV matrix <a,b,c, d,e,f, g,h,i, tx,ty,tz>: x -> (a,b,c), y -> (d,e,f), z -> (g,h,i)
    mat = ",".join(_fmt(v) for v in (*M[:, 0], *M[:, 1], *M[:, 2], *t))

    def finish(value):
        return (f"pigment {{ rgb {_fmt(float(value))} }} "
                "finish { ambient 1 diffuse 0 specular 0 phong 0 reflection 0 }")

    xmin, xmax, ymin, ymax = (float(v) for v in pattern.extent)
    lines = ["union {"]
    lines.append(f"  polygon {{ 5, <{_fmt(xmin)},{_fmt(ymin)},0>, <{_fmt(xmax)},{_fmt(ymin)},0>, "
                 f"<{_fmt(xmax)},{_fmt(ymax)},0>, <{_fmt(xmin)},{_fmt(ymax)},0>, "
                 f"<{_fmt(xmin)},{_fmt(ymin)},0> {finish(pattern.board_value)} }}")
    d1, d2 = LAYER_OFFSET, 2 * LAYER_OFFSET
    if pattern.cells is not None:
        cells = np.asarray(pattern.cells, dtype=np.float64)
        s = float(pattern.cell_size)
        ox, oy = (float(v) for v in pattern.cell_origin)
        for iy, ix in zip(*np.nonzero(np.isfinite(cells)), strict=True):
            x0, y0 = ox + ix * s, oy + iy * s
            # cells are clipped to the board rectangle, as Pattern.albedo does
            x0c, x1c = max(x0, xmin), min(x0 + s, xmax)
            y0c, y1c = max(y0, ymin), min(y0 + s, ymax)
            if x1c <= x0c or y1c <= y0c:
                continue
            lines.append(f"  box {{ <{_fmt(x0c)},{_fmt(y0c)},{_fmt(-d1)}>, "
                         f"<{_fmt(x1c)},{_fmt(y1c)},{_fmt(d1)}> {finish(cells[iy, ix])} }}")
    if pattern.circles is not None and len(pattern.circles):
        board = (f"box {{ <{_fmt(xmin)},{_fmt(ymin)},{_fmt(-2 * d2)}>, "
                 f"<{_fmt(xmax)},{_fmt(ymax)},{_fmt(2 * d2)}> }}")
        for cx, cy, r in np.asarray(pattern.circles, dtype=np.float64):
            lines.append(f"  intersection {{ cylinder {{ <{_fmt(cx)},{_fmt(cy)},{_fmt(-d2)}>, "
                         f"<{_fmt(cx)},{_fmt(cy)},{_fmt(d2)}>, {_fmt(r)} }} {board} "
                         f"{finish(pattern.circle_value)} }}")
    lines.append(f"  matrix <{mat}>")
    lines.append("}")
    return "\n".join(lines)


def scene_header(pattern):
    return ("#version 3.7;\n"
            "global_settings { assumed_gamma 1.0 ambient_light rgb 1 max_trace_level 5 }\n"
            f"background {{ rgb {_fmt(float(pattern.background_value))} }}\n")


def perspective_camera(pinhole):
    r'''POV-Ray perspective camera reproducing a renderers.warp.Pinhole exactly'''
    W, H = pinhole.width, pinhole.height
    # POV-Ray 3.7.0: ray = direction + ((i+0.5)/W - 0.5) right + (0.5 - (j+0.5)/H) up for
    # pixel (i, j): the principal point is ((W-1)/2, (H-1)/2) in camval's convention
    dx = ((W - 1) / 2.0 - pinhole.cx) / pinhole.fx
    dy_pov = (pinhole.cy - (H - 1) / 2.0) / pinhole.fy
    return ("camera { perspective location <0,0,0> "
            f"direction <{_fmt(dx)},{_fmt(dy_pov)},1> "
            f"right <{_fmt(W / pinhole.fx)},0,0> up <0,{_fmt(H / pinhole.fy)},0> }}\n")


def _corner_rays(model):
    r'''Rays of the pixel-corner grid: origins and unit directions (H+1, W+1, 3), camera frame

Corner (i, j) is the camval point (i - 0.5, j - 0.5). Cached per model.
'''
    key = repr(model)
    hit = _CORNER_RAYS.get(key)
    if hit is None:
        W, H = model.width, model.height
        x = np.arange(W + 1, dtype=np.float64) - 0.5
        y = np.arange(H + 1, dtype=np.float64) - 0.5
        q = np.stack(np.meshgrid(x, y), axis=-1)
        Rt = model.Rt_ref_cam()
        origin, v = model.unproject(q)
        o_cam = (origin - Rt[3]) @ Rt[:3]
        v_cam = v @ Rt[:3]
        if not np.all(np.isfinite(v_cam)):
            raise RendererError(f"{model.family} model: some pixel corners have no ray "
                                "(unprojection failed); the mesh camera needs a ray for "
                                "every corner")
        if len(_CORNER_RAYS) > 8:
            _CORNER_RAYS.clear()
        hit = _CORNER_RAYS[key] = (o_cam, v_cam)
    return hit


_CORNER_RAYS = {}
_MESH_STEPS = {}


def _interpolated_rays(o, n, b):
    r'''POV-Ray's smooth mesh_camera ray at barycentric b (...,3) of triangles o, n (...,3,3)

POV-Ray 3.7 normalises the vertex normals when it parses the mesh, mixes them
barycentrically and normalises the result (measured: normals scaled to z = 1,
which would make a pinhole's interpolation exact, gave a CAHV camera 0.1 px
errors on an 8-px grid and 1.8 px on a 64-px grid, as predicted for unit
normals).
'''
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    d = (b[..., :, None] * n).sum(-2)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return (b[..., :, None] * o).sum(-2), d


def mesh_interpolation_error(model, step, ncells=96):
    r'''Largest error (px) of the smooth mesh camera's interpolated rays for a grid step

SYNOPSIS

    err = mesh_interpolation_error(model, 4)   # px

The mesh camera's vertices sit on the pixel-corner grid every `step` pixels
(two triangles per square, split along the main diagonal); POV-Ray
interpolates the vertex normals barycentrically and normalises. This projects
interpolated rays at the centroid and edge midpoints of the triangles of up to
ncells x ncells grid squares spread over the image (the first and last rows
and columns included) and returns the largest distance to the image point
they stand for.
'''
    o, n = _corner_rays(model)
    W, H = model.width, model.height
    ix = np.unique(np.minimum(np.arange(0, W + step, step), W))
    iy = np.unique(np.minimum(np.arange(0, H + step, step), H))
    # a spread of squares (index of the top-left corner in ix, iy)
    sx = np.unique(np.linspace(0, len(ix) - 2, min(ncells, len(ix) - 1)).round().astype(int))
    sy = np.unique(np.linspace(0, len(iy) - 2, min(ncells, len(iy) - 1)).round().astype(int))
    Sx, Sy = np.meshgrid(sx, sy)
    tri_idx = (((0, 0), (0, 1), (1, 1)), ((0, 0), (1, 1), (1, 0)))
    bary = np.array([[1, 1, 1], [1, 1, 0], [0, 1, 1], [1, 0, 1]], dtype=np.float64)
    bary /= bary.sum(-1, keepdims=True)
    Rt = model.Rt_ref_cam()
    worst = 0.0
    for tri in tri_idx:
        cx = np.stack([ix[Sx + dx] for dy, dx in tri], axis=-1)      # (..., 3) corner indices
        cy = np.stack([iy[Sy + dy] for dy, dx in tri], axis=-1)
        To, Tn = o[cy, cx], n[cy, cx]
        Tq = np.stack((cx, cy), -1).astype(np.float64) - 0.5
        for b in bary:
            oi, di = _interpolated_rays(To, Tn, np.broadcast_to(b, To.shape[:-1]))
            q_true = (b[:, None] * Tq).sum(-2)
            p_ref = (oi + di) @ Rt[:3].T + Rt[3]
            d = np.linalg.norm(model.project(p_ref) - q_true, axis=-1)
            worst = max(worst, float(np.max(np.where(np.isfinite(d), d, np.inf))))
    return worst


def mesh_grid_step(model, tolerance=MESH_TOLERANCE, steps=MESH_STEPS):
    r'''(step, error px): the coarsest of `steps` within `tolerance` (else the finest)'''
    key = (repr(model), float(tolerance), tuple(steps))
    hit = _MESH_STEPS.get(key)
    if hit is None:
        for step in steps:
            err = mesh_interpolation_error(model, step)
            if err <= tolerance:
                break
        hit = _MESH_STEPS[key] = (step, err)
    return hit


def edge_pixels(model, pattern, Rt_cam_board, spacing_px=0.25):
    r'''Pixels that an edge of the board pattern crosses

SYNOPSIS

    mask = edge_pixels(model, pattern, Rt_cam_board)   # (H, W) bool

Every edge of the scene (board outline, cell outlines, dot circles) is sampled
every <= spacing_px in the image; each sample s marks the pixels holding
s + (+-0.3, +-0.3): a pixel that the curve crosses at c holds one of them,
since |c - s| <= spacing_px / 2 per axis. Pixels outside the mask see one
material over their whole area, and their centres lie >= 0.5 px from any edge.
'''
    W, H = model.width, model.height
    Rt = np.asarray(Rt_cam_board, dtype=np.float64)
    Rr = model.Rt_ref_cam()
    M = Rr[:3] @ Rt[:3]
    t = Rr[:3] @ Rt[3] + Rr[3]
    mask = np.zeros((H, W), dtype=bool)

    def mark(curves):
        # curves (N, n, 2): board-frame polylines, refined until samples are close in the image
        while True:
            n = curves.shape[1]
            p = np.concatenate((curves, np.zeros(curves.shape[:-1] + (1,))), -1) @ M.T + t
            q = model.project(p)
            gap = np.linalg.norm(np.diff(q, axis=1), axis=-1)
            if not np.any(gap > spacing_px) or n >= 1 << 16:
                break
            s = np.linspace(0.0, n - 1.0, 2 * n - 1)
            i0 = np.minimum(s.astype(np.int64), n - 2)
            f = (s - i0)[None, :, None]
            curves = curves[:, i0] * (1 - f) + curves[:, i0 + 1] * f
        q = q.reshape(-1, 2)
        q = q[np.all(np.isfinite(q), axis=-1)]
        for d in ((-0.3, -0.3), (-0.3, 0.3), (0.3, -0.3), (0.3, 0.3)):
            i = np.floor(q + d + 0.5).astype(np.int64)
            ok = (i[:, 0] >= 0) & (i[:, 0] < W) & (i[:, 1] >= 0) & (i[:, 1] < H)
            mask[i[ok, 1], i[ok, 0]] = True

    def sides(x0, x1, y0, y1):
        c = np.array([(x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0)])
        return np.stack((c[:-1], c[1:]), axis=1)

    xmin, xmax, ymin, ymax = (float(v) for v in pattern.extent)
    segs = [sides(xmin, xmax, ymin, ymax)]
    if pattern.cells is not None:
        cells = np.asarray(pattern.cells, dtype=np.float64)
        s = float(pattern.cell_size)
        ox, oy = (float(v) for v in pattern.cell_origin)
        for iy, ix in zip(*np.nonzero(np.isfinite(cells)), strict=True):
            x0c, x1c = max(ox + ix * s, xmin), min(ox + (ix + 1) * s, xmax)
            y0c, y1c = max(oy + iy * s, ymin), min(oy + (iy + 1) * s, ymax)
            if x1c > x0c and y1c > y0c:
                segs.append(sides(x0c, x1c, y0c, y1c))
    mark(np.concatenate(segs))
    if pattern.circles is not None and len(pattern.circles):
        c = np.asarray(pattern.circles, dtype=np.float64)
        a = np.linspace(0.0, 2 * np.pi, 65)
        mark(np.stack((c[:, None, 0] + c[:, None, 2] * np.cos(a),
                       c[:, None, 1] + c[:, None, 2] * np.sin(a)), axis=-1))
    return mask


@dataclass(frozen=True)
class MeshRect:
    r'''A block of model pixels (x0..x0+w-1, y0..y0+h-1) rendered k x k per pixel'''
    x0: int
    y0: int
    w: int
    h: int
    k: int


def rect_faces(r, step):
    r'''Number of mesh faces of a MeshRect at a grid step'''
    return 2 * -(-r.w // step) * -(-r.h // step)


def pack_rects(rects, steps, max_pixels=MESH_RUN_PIXELS, max_faces=MESH_RUN_FACES,
               width=MESH_ATLAS_WIDTH):
    r'''Shelf-pack rects into atlases: [(atlas width, height, [(rect, step, ax, ay), ...]), ...]

Each atlas is one POV-Ray run of at most max_pixels fine pixels and max_faces
faces (a rect larger than that gets a run of its own); steps[i] is rect i's
mesh grid step. Rects keep their order; a rect of another height starts a new
shelf; an atlas is as wide as its first rect when that is >= 256 fine pixels
wide (an image tile: the cells that follow fill the rows below it), else
`width`. Atlas pixels that no face covers cost POV-Ray a scan of every face,
so the packing leaves few. Row 0 of an atlas is left empty: POV-Ray 3.7.0
samples image row 0 half a row low (measured: rows j >= 1 are sampled at
y = j, row 0 at y = 0.5; the clamp that also gives distribution 0 its
one-row offset).
'''
    runs = []
    top = MESH_ATLAS_TOP

    cur, Wa, H, x, y, shelf_h, nf = [], 0, top, 0, top, 0, 0
    for r, step in zip(rects, steps, strict=True):
        fw, fh = r.w * r.k, r.h * r.k
        f = rect_faces(r, step)
        if cur:
            if x > 0 and (x + fw > Wa or fh != shelf_h):     # next shelf
                x, y, shelf_h = 0, y + shelf_h, fh
            if fw > Wa or (y + fh) * Wa > max_pixels or nf + f > max_faces:
                runs.append((Wa, H, cur))
                cur = []
        if not cur:
            Wa = fw if fw >= 256 else max(fw, width)
            H, x, y, shelf_h, nf = top, 0, top, fh, 0
        cur.append((r, step, x, y))
        H = max(H, y + fh)
        nf += f
        x += fw
    if cur:
        runs.append((Wa, H, cur))
    return runs


def _rows(a):
    r'''Rows of a (N, n) array as POV-Ray vectors <a,b,...> (repr: shortest exact form)'''
    s = list(map(repr, a.ravel().tolist()))
    n = a.shape[1]
    return ",\n".join("<" + ",".join(s[i:i + n]) + ">" for i in range(0, len(s), n))


def mesh_camera_text(model, placed, atlas_w, atlas_h, surface):
    r'''The mesh2 CamvalRays of a smooth mesh_camera (distribution 3) rendering `placed`

SYNOPSIS

    text, nfaces = mesh_camera_text(model, [(MeshRect, step, ax, ay), ...], Wa, Ha, surface)

Vertices sit on the pixel-corner grid of each rect every `step` pixels, at
origin + surface * normal of that corner's ray (camera frame, y negated;
_corner_rays), with the normal as vertex normal and the corner's atlas
position as uv. POV-Ray 3.7 samples atlas pixel (I, J) at uv
(I/Wa, 1 - J/Ha) (measured), so fine pixel (a, b) of a rect stands for the
model point (x0 + (a + 0.5)/k - 0.5, y0 + (b + 0.5)/k - 0.5): k x k
sub-pixel centres. Numbers are written exactly (repr).
'''
    o, n = _corner_rays(model)
    F = np.array([1.0, -1.0, 1.0])
    groups = {}
    for r, step, ax, ay in placed:
        groups.setdefault((r.w, r.h, r.k, step), []).append((r.x0, r.y0, ax, ay))
    P, N, UV, faces = [], [], [], []
    nv = 0
    for (w, h, k, step), where in groups.items():
        xs = np.unique(np.minimum(np.arange(0, w + step, step), w))
        ys = np.unique(np.minimum(np.arange(0, h + step, step), h))
        gx, gy = np.meshgrid(xs, ys)                       # (ny, nx) corner offsets
        x0, y0, ax, ay = (c[:, None, None] for c in np.array(where, dtype=np.int64).T)
        cx, cy = x0 + gx, y0 + gy                          # (R, ny, nx) corner indices
        P.append(((o[cy, cx] + surface * n[cy, cx]) * F).reshape(-1, 3))
        N.append((n[cy, cx] * F).reshape(-1, 3))
        # corner (cx, cy) is the model point (cx - 0.5, cy - 0.5): atlas I = ax + k gx - 0.5
        I = ax + k * gx - 0.5
        J = ay + k * gy - 0.5
        UV.append(np.stack((I / atlas_w, 1.0 - J / atlas_h), -1).reshape(-1, 2))
        idx = np.arange(gx.size).reshape(gx.shape)
        a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]
        tmpl = np.concatenate((np.stack((a, b, c), -1).reshape(-1, 3),
                               np.stack((a, c, d), -1).reshape(-1, 3)))
        R = len(where)
        faces.append((nv + gx.size * np.arange(R)[:, None, None] + tmpl).reshape(-1, 3))
        nv += R * gx.size
    P, N, UV, faces = (np.concatenate(x) for x in (P, N, UV, faces))
    out = ["#declare CamvalRays = mesh2 {",
           f"vertex_vectors {{ {len(P)},", _rows(P), "}",
           f"normal_vectors {{ {len(N)},", _rows(N), "}",
           f"uv_vectors {{ {len(UV)},", _rows(UV), "}",
           f"face_indices {{ {len(faces)},", _rows(faces), "}", "}", ""]
    return "\n".join(out), len(faces)


def run_povray(binary, workdir, scene_text_writer, width, height, aa_depth=1, threads=None,
               aa_threshold=0.0, rgb=False):
    r'''Run POV-Ray headless on the scene scene_text_writer(f) writes, in workdir

SYNOPSIS

    img, seconds, scene_bytes = run_povray("povray", workdir, write, W, H, aa_depth=4)
    # img (H,W) float64 in [0,1]: the 16-bit linear image's green channel
    # (rgb=True: (H,W,3) R, G, B)

aa_depth > 1: anti-aliasing method 1 with aa_depth x aa_depth samples where
neighbours differ by more than aa_threshold (0: every pixel, full supersampling).
'''
    import cv2
    pov = os.path.join(workdir, "scene.pov")
    png = os.path.join(workdir, "image.png")
    with open(pov, "w") as f:
        scene_text_writer(f)
    cmd = [binary, "-D", "-V", "-P", "+FN16", "File_Gamma=1.0", "Output_Alpha=off",
           f"+W{width}", f"+H{height}", "+Oimage.png", "scene.pov"]
    if aa_depth > 1:
        cmd[1:1] = [f"+A{float(aa_threshold)!r}", "+AM1", f"+R{aa_depth}", "-J"]
    else:
        cmd[1:1] = ["-A"]
    if threads:
        cmd.insert(1, f"+WT{int(threads)}")
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(cmd, cwd=workdir, capture_output=True, text=True)
    except OSError as e:
        raise RendererUnavailableError(f"cannot run {binary}: {e}; {INSTALL_HINT}") from e
    seconds = time.perf_counter() - t0
    if proc.returncode != 0 or not os.path.exists(png):
        tail = "\n".join((proc.stderr or proc.stdout).strip().splitlines()[-8:])
        raise RendererError(f"povray failed (exit {proc.returncode}) on {pov}: {tail}")
    img = cv2.imread(png, cv2.IMREAD_UNCHANGED)
    if img is None or img.shape[:2] != (height, width):
        raise RendererError(f"povray wrote an unreadable or mis-sized image {png}: "
                            f"{None if img is None else img.shape}, expected {(height, width)}")
    if rgb:
        if img.ndim != 3:
            raise RendererError(f"povray wrote a grey image {png}; expected colour")
        img = img[..., 2::-1]           # OpenCV reads B, G, R
    elif img.ndim == 3:
        img = img[..., 1]
    scale = 65535.0 if img.dtype == np.uint16 else 255.0
    return img.astype(np.float64) / scale, seconds, os.path.getsize(pov)


class PovrayRenderer:
    r'''POV-Ray 3.7 renderer (see the module docstring)

ARGUMENTS (defaults for every render; RenderSettings.options override them)

- camera: "perspective" (oversized pinhole + warp, the paper's path) or "mesh"
- interpolation: warp interpolation, "bilinear" or "bicubic"
- warp_scale: pinhole resolution relative to the model's finest pixel (>= 1)
- warp_samples: n, average n x n remaps per model pixel (use with warp_scale = n)
- binary: the POV-Ray executable
- threads: POV-Ray work threads (None: POV-Ray's default, all cores)
- legacy / fault: render a defective model (renderers.legacy)
'''

    name = "povray"

    def __init__(self, camera="perspective", interpolation="bilinear", warp_scale=1.0,
                 warp_samples=1,
                 binary="povray", threads=None,
                 legacy=None, fault=None, keep_dir=None):
        path = shutil.which(binary)
        if path is None:
            raise RendererUnavailableError(
                f"renderer 'povray': the POV-Ray binary {binary!r} is not on PATH; {INSTALL_HINT}")
        self.binary = path
        self.defaults = dict(camera=camera, interpolation=interpolation, warp_scale=warp_scale,
                             warp_samples=warp_samples,
                             threads=threads, legacy=legacy,
                             fault=fault, keep_dir=keep_dir)
        self._check_options(self.defaults)
        self._version = None

    @staticmethod
    def _check_options(o):
        if o["camera"] not in CAMERAS:
            raise RendererError(f"povray camera {o['camera']!r} is unknown; "
                                f"known: {', '.join(CAMERAS)}")
        if o["interpolation"] not in INTERPOLATIONS:
            raise RendererError(f"povray interpolation {o['interpolation']!r} is unknown; "
                                f"known: {', '.join(INTERPOLATIONS)}")

    def version(self):
        if self._version is None:
            try:
                out = subprocess.run([self.binary, "--version"], capture_output=True, text=True,
                                     timeout=30)
                m = re.search(r"POV-Ray\s+([0-9][^\s]*)", out.stdout + out.stderr)
                self._version = f"POV-Ray {m.group(1)}" if m else "POV-Ray (unknown version)"
            except (OSError, subprocess.SubprocessError) as e:
                self._version = f"POV-Ray (version query failed: {e})"
        return self._version

    # --- running POV-Ray ----------------------------------------------------------
    def _run(self, workdir, scene_text_writer, width, height, aa_depth, threads,
             aa_threshold=0.0):
        return run_povray(self.binary, workdir, scene_text_writer, width, height, aa_depth,
                          threads, aa_threshold)

    # --- the two camera paths -----------------------------------------------------
    def render_pinhole(self, pinhole, pattern, Rt_cam_board, K, workdir, threads=None,
                       aa_threshold=0.0):
        r'''Render the pinhole view (pinhole.height, pinhole.width) with K x K supersampling

aa_threshold > 0: POV-Ray supersamples only the pixels whose colour differs
from a neighbour's by more than that (its adaptive anti-aliasing, method 1).
'''
        n, b = split_supersampling(K)
        fine = pinhole.scaled(b)

        def write(f):
            f.write(scene_header(pattern))
            f.write(perspective_camera(fine))
            f.write(scene_objects(pattern, Rt_cam_board))

        img, seconds, nbytes = self._run(workdir, write, fine.width, fine.height, n, threads,
                                         aa_threshold)
        return box_downsample(img, b), dict(povray_seconds=seconds, aa_depth=n, finer=b,
                                            aa_threshold=aa_threshold, scene_bytes=nbytes)

    def render_mesh(self, model, pattern, Rt_cam_board, K, adaptive, workdir, threads=None):
        r'''Render the model directly through a smooth mesh_camera, K x K per pixel

With adaptive, one run renders the whole image at one ray per pixel and the
MESH_CELL-pixel cells that an edge of the pattern crosses (edge_pixels) at K x K.
'''
        W, H = model.width, model.height
        Rt = np.asarray(Rt_cam_board, dtype=np.float64)
        if Rt.shape != (4, 3) or not np.all(np.isfinite(Rt)):
            raise RendererError(f"Rt_cam_board must be a finite (4,3) array; got shape {Rt.shape}")
        step, interp_err = mesh_grid_step(model)
        coarse, _ = mesh_grid_step(model, MESH_COARSE_TOLERANCE, MESH_COARSE_STEPS)
        # the rays start on the mesh, `surface` metres out: well short of the board's plane
        plane = abs(float(Rt[3] @ Rt[:3, 2]))
        if not plane > 1e-6:
            raise RendererError(f"the board plane passes {plane:.2g} m from the camera centre; "
                                "the mesh camera needs it in front of the camera")
        _, n = _corner_rays(model)
        surface = 0.25 * plane / float(np.linalg.norm(n, axis=-1).max())

        def tiles(k, side):
            return [MeshRect(x, y, min(side, W - x), min(side, H - y), k)
                    for y in range(0, H, side) for x in range(0, W, side)]

        if adaptive:
            C = MESH_CELL
            mask = edge_pixels(model, pattern, Rt)
            Hc, Wc = -(-H // C), -(-W // C)
            padded = np.zeros((Hc * C, Wc * C), dtype=bool)
            padded[:H, :W] = mask
            cells = padded.reshape(Hc, C, Wc, C).any(axis=(1, 3))
            base = tiles(1, MESH_ATLAS_WIDTH)
            fine = [MeshRect(int(cx) * C, int(cy) * C, min(C, W - int(cx) * C),
                             min(C, H - int(cy) * C), K)
                    for cy, cx in zip(*np.nonzero(cells), strict=True)]
            rects, steps = base + fine, [coarse] * len(base) + [step] * len(fine)
            supersampled = sum(r.w * r.h for r in fine) if K > 1 else 0
        else:
            # tiles of at most MESH_RUN_FACES / 2 squares of the fine step
            side = min(max(MESH_CELL, MESH_ATLAS_WIDTH // K),
                       step * int(np.sqrt(MESH_RUN_FACES / 2)))
            rects = tiles(K, side)
            steps = [step] * len(rects)
            supersampled = W * H if K > 1 else 0
        out = np.zeros((H, W))
        seconds, nbytes, nfaces, nruns, traced = 0.0, 0, 0, 0, 0
        for Wa, Ha, placed in pack_rects(rects, steps):
            text, nf = mesh_camera_text(model, placed, Wa, Ha, surface)

            def write(f, text=text):
                f.write(scene_header(pattern))
                f.write(text)
                f.write("camera { mesh_camera { 1 3 mesh { CamvalRays } smooth } "
                        "location <0,0,0> direction <0,0,1> }\n")
                f.write(scene_objects(pattern, Rt))

            img, sec, nb = self._run(workdir, write, Wa, Ha, 1, threads)
            for r, _, ax, ay in placed:
                blk = img[ay:ay + r.h * r.k, ax:ax + r.w * r.k]
                out[r.y0:r.y0 + r.h, r.x0:r.x0 + r.w] = box_downsample(blk, r.k)
                traced += r.w * r.h * r.k * r.k
            seconds += sec
            nbytes = max(nbytes, nb)
            nfaces = max(nfaces, nf)
            nruns += 1
        return out, dict(povray_seconds=seconds, scene_bytes=nbytes, mesh_faces=nfaces,
                         povray_runs=nruns, mesh_step=step, mesh_coarse_step=coarse,
                         mesh_interpolation_px=interp_err, rays_traced=traced,
                         adaptive_fraction=supersampled / (W * H))

    def render(self, model, scene, Rt_cam_board, settings=None):
        from .legacy import apply_defects

        settings = RenderSettings() if settings is None else settings
        o = merged_options("povray", self.defaults, settings)
        self._check_options(o)
        K = settings.spp
        render_model, defects = apply_defects(model, o["legacy"], o["fault"])
        t0 = time.perf_counter()
        workdir = o["keep_dir"] or tempfile.mkdtemp(prefix="camval-povray-")
        os.makedirs(workdir, exist_ok=True)
        try:
            if o["camera"] == "mesh":
                img, info = self.render_mesh(render_model, scene, Rt_cam_board, K,
                                             bool(settings.adaptive), workdir, o["threads"])
                warp_info = {}
            else:
                warp = PinholeWarp.for_model(render_model, scale=float(o["warp_scale"]),
                                         samples=int(o["warp_samples"]))
                thr = PERSPECTIVE_AA_THRESHOLD if settings.adaptive else 0.0
                pin_img, info = self.render_pinhole(warp.pinhole, scene, Rt_cam_board, K,
                                                    workdir, o["threads"], thr)
                img = warp.apply(pin_img, o["interpolation"], Rt_cam_board=Rt_cam_board)
                warp_info = dict(pinhole=warp.pinhole.as_dict(), interpolation=o["interpolation"])
        finally:
            if not o["keep_dir"]:
                shutil.rmtree(workdir, ignore_errors=True)
        image = np.clip(np.asarray(img, dtype=np.float32), 0.0, 1.0)
        meta = dict(renderer=self.name, version=self.version(), settings=settings.as_dict(),
                    camera=o["camera"], seconds=time.perf_counter() - t0, samples=K * K,
                    defects=defects, **warp_info, **info)
        return RenderResult(image=image, metadata=meta)
