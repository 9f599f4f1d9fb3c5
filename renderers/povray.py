r'''POV-Ray 3.7 as a camval renderer: the paper's pinhole-then-warp path and a direct mesh camera

SYNOPSIS

    from renderers.base import get_renderer, RenderSettings

    r = get_renderer("povray")                      # camera="perspective" (then the warp)
    r = get_renderer("povray", camera="mesh")       # one ray per (sub)pixel, exact rays
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
  Supersampling K x K: POV-Ray's non-adaptive anti-aliasing forced on every
  pixel (+AM1 +A0.0 -J +R n, n <= 9) samples an n x n grid centred on the
  pixel and averages it with the pixel's centre sample (weights 1/(n^2+1),
  centre 2/(n^2+1)); K = n b with b > 1 renders b times finer and averages
  b x b blocks.
- "mesh": mesh_camera, distribution type 0: one triangle per ray, whose
  centroid is the ray's origin and whose normal the ray's direction (from
  model.unproject: exact rays, noncentral CAHVORE included). POV-Ray maps
  pixel (x, y) to face y W + x after flooring x and y: anti-aliasing would
  pick neighbouring faces (a half-pixel shift and a blur), so it is never
  used; K x K supersampling renders the K-times finer image (one face per
  sub-pixel ray at the sub-pixel centres) and averages K x K blocks.
  Triangles have unit size around the ray origin and vertices are written
  with 17 significant digits: POV-Ray computes the face normal from the
  parsed (double) vertices, so small or rounded triangles tilt the rays.
  The one-row offset of FINDINGS.md: POV-Ray 3.7.0.10 traces face row j - 1
  for image row j (columns are right; image row 0 repeats face row 0, the
  row index being clamped at 0). The adapter probes the offset once per binary (a 2x4 image),
  renders that many extra rows and drops them; the dot-centroid test pins
  the result. `mesh2` is written, not mesh{triangle{}}: POV-Ray hashes every
  vertex of a `mesh` into 1000 buckets (quadratic: 10 minutes for 800k
  triangles).

A missing `povray` binary raises RendererUnavailableError at construction.
'''

import math
import os
import re
import shutil
import subprocess
import tempfile
import time
import weakref

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
DEFAULT_MAX_MESH_RAYS = 4_500_000
# POV-Ray 3.7.0.10's mesh_camera traces face row j - 1 for image row j: the "one-row
# offset" (measured here; probed once per binary by PovrayRenderer.mesh_row_offset())
MESH_ROW_OFFSET = 1
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


def mesh_camera_triangles(origin, v):
    r'''Triangles whose centroids are `origin` and whose POV-Ray normals are `v`

SYNOPSIS

    P = mesh_camera_triangles(origin, v)   # origin, v (N,3) -> P (N,3,3) vertices

POV-Ray computes a mesh face's normal as normalise((P3-P1) x (P2-P1)) before
it reorders the vertices, and mesh_camera uses it as the ray direction.
'''
    v = v / np.linalg.norm(v, axis=-1, keepdims=True)
    # a unit vector perpendicular to each v
    helper = np.where(np.abs(v[:, 0:1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    a = np.cross(v, helper)
    a /= np.linalg.norm(a, axis=-1, keepdims=True)
    b = np.cross(v, a)
    # three points at 120 deg on a unit circle about the origin, in the plane ⟂ v
    c, s = -0.5, math.sqrt(3.0) / 2.0
    p1 = a
    p2 = c * a + s * b
    p3 = c * a - s * b
    n = np.cross(p3 - p1, p2 - p1)
    flip = (n * v).sum(-1) < 0
    p2[flip], p3[flip] = p3[flip].copy(), p2[flip].copy()
    return origin[:, None, :] + np.stack((p1, p2, p3), axis=1)


def _write_mesh2(f, P):
    # mesh2 reads its vertex array as given (mesh{triangle{}} hashes every vertex into
    # 1000 buckets: quadratic time, 10 minutes for 800k triangles); 17 significant digits
    N = len(P)
    f.write(f"vertex_vectors {{ {3 * N},\n")
    fmt = "<%.17g,%.17g,%.17g>,<%.17g,%.17g,%.17g>,<%.17g,%.17g,%.17g>\n"
    flat = P.reshape(-1, 9)
    chunk = 65536
    for i in range(0, N, chunk):
        f.write("".join(fmt % tuple(row) for row in flat[i:i + chunk].tolist()))
    f.write("}\n")
    f.write(f"face_indices {{ {N},\n")
    for i in range(0, N, chunk):
        idx = np.arange(i, min(N, i + chunk))
        f.write("".join(f"<{3 * k},{3 * k + 1},{3 * k + 2}>\n" for k in idx.tolist()))
    f.write("}\n")


class PovrayRenderer:
    r'''POV-Ray 3.7 renderer (see the module docstring)

ARGUMENTS (defaults for every render; RenderSettings.options override them)

- camera: "perspective" (oversized pinhole + warp, the paper's path) or "mesh"
- interpolation: warp interpolation, "bilinear" or "bicubic"
- warp_scale: pinhole resolution relative to the model's finest pixel (>= 1)
- warp_samples: n, average n x n remaps per model pixel (use with warp_scale = n)
- binary: the POV-Ray executable
- threads: POV-Ray work threads (None: POV-Ray's default, all cores)
- max_mesh_rays: refuse mesh-camera renders with more rays than this (scene
  files take ~250 bytes per ray)
- legacy / fault: render a defective model (renderers.legacy)
'''

    name = "povray"

    def __init__(self, camera="perspective", interpolation="bilinear", warp_scale=1.0,
                 warp_samples=1,
                 binary="povray", threads=None, max_mesh_rays=DEFAULT_MAX_MESH_RAYS,
                 legacy=None, fault=None, keep_dir=None):
        path = shutil.which(binary)
        if path is None:
            raise RendererUnavailableError(
                f"renderer 'povray': the POV-Ray binary {binary!r} is not on PATH; {INSTALL_HINT}")
        self.binary = path
        self.defaults = dict(camera=camera, interpolation=interpolation, warp_scale=warp_scale,
                             warp_samples=warp_samples,
                             threads=threads, max_mesh_rays=max_mesh_rays, legacy=legacy,
                             fault=fault, keep_dir=keep_dir)
        self._check_options(self.defaults)
        self._version = None
        self._mesh_cache = {}
        self._mesh_count = 0
        self._cache_dir = None

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
    def _run(self, workdir, scene_text_writer, width, height, aa_depth, threads):
        pov = os.path.join(workdir, "scene.pov")
        png = os.path.join(workdir, "image.png")
        with open(pov, "w") as f:
            scene_text_writer(f)
        cmd = [self.binary, "-D", "-V", "-P", "+FN16", "File_Gamma=1.0", "Output_Alpha=off",
               f"+W{width}", f"+H{height}", "+Oimage.png", "scene.pov"]
        if aa_depth > 1:
            cmd[1:1] = ["+A0.0", "+AM1", f"+R{aa_depth}", "-J"]
        else:
            cmd[1:1] = ["-A"]
        if threads:
            cmd.insert(1, f"+WT{int(threads)}")
        t0 = time.perf_counter()
        try:
            proc = subprocess.run(cmd, cwd=workdir, capture_output=True, text=True)
        except OSError as e:
            raise RendererUnavailableError(f"cannot run {self.binary}: {e}; {INSTALL_HINT}") from e
        seconds = time.perf_counter() - t0
        if proc.returncode != 0 or not os.path.exists(png):
            tail = "\n".join((proc.stderr or proc.stdout).strip().splitlines()[-8:])
            raise RendererError(f"povray failed (exit {proc.returncode}) on {pov}: {tail}")
        import cv2
        img = cv2.imread(png, cv2.IMREAD_UNCHANGED)
        if img is None or img.shape[:2] != (height, width):
            raise RendererError(f"povray wrote an unreadable or mis-sized image {png}: "
                                f"{None if img is None else img.shape}, expected {(height, width)}")
        if img.ndim == 3:
            img = img[..., 1]
        scale = 65535.0 if img.dtype == np.uint16 else 255.0
        return img.astype(np.float64) / scale, seconds, os.path.getsize(pov)

    # --- the two camera paths -----------------------------------------------------
    def render_pinhole(self, pinhole, pattern, Rt_cam_board, K, workdir, threads=None):
        r'''Render the pinhole view (pinhole.height, pinhole.width) with K x K supersampling'''
        n, b = split_supersampling(K)
        fine = pinhole.scaled(b)

        def write(f):
            f.write(scene_header(pattern))
            f.write(perspective_camera(fine))
            f.write(scene_objects(pattern, Rt_cam_board))

        img, seconds, nbytes = self._run(workdir, write, fine.width, fine.height, n, threads)
        return box_downsample(img, b), dict(povray_seconds=seconds, aa_depth=n, finer=b,
                                            scene_bytes=nbytes)

    def render_mesh(self, model, pattern, Rt_cam_board, K, workdir, threads=None,
                    max_rays=DEFAULT_MAX_MESH_RAYS):
        r'''Render the model directly: one mesh_camera ray per sub-pixel'''
        W, H = model.width, model.height
        nrays = W * H * K * K
        if nrays > max_rays:
            raise RendererError(
                f"povray mesh camera: {W}x{H} px at K={K} needs {nrays} rays "
                f"(~{nrays * 250 / 1e9:.1f} GB of scene file); the limit is {max_rays} "
                "(option max_mesh_rays); use camera='perspective' or a smaller K")
        rays = os.path.join(workdir, "rays.inc")
        self._mesh_include(model, K, rays)

        def write(f):
            f.write(scene_header(pattern))
            f.write('#include "rays.inc"\n')
            f.write("camera { mesh_camera { 1 0 mesh { CamvalRays } } "
                    "location <0,0,0> direction <0,0,1> }\n")
            f.write(scene_objects(pattern, Rt_cam_board))

        # POV-Ray 3.7.0 shows face row j - 1 in image row j: render one more row and drop
        # the first (the offset is probed once per binary)
        off = self.mesh_row_offset()
        img, seconds, nbytes = self._run(workdir, write, W * K, H * K + off, 1, threads)
        img = img[off:]
        nbytes += os.path.getsize(rays)
        return box_downsample(img, K), dict(povray_seconds=seconds, finer=K, scene_bytes=nbytes)

    _row_offsets = {}

    def mesh_row_offset(self):
        r"""Which face row this POV-Ray's mesh_camera traces for image row j: j - offset

Probed with a 2x4 image whose faces of row 0 look at a white box and the
others away from it; cached per binary. 1 for POV-Ray 3.7.0.10 (Debian 12).
"""
        off = self._row_offsets.get(self.binary)
        if off is not None:
            return off
        W, H = 2, 4
        v = np.tile([0.0, 0.0, -1.0], (W * H, 1))
        v[:W] = (0.0, 0.0, 1.0)
        P = mesh_camera_triangles(np.zeros_like(v), v)

        def write(f):
            f.write("#version 3.7;\nglobal_settings { assumed_gamma 1.0 }\n"
                    "background { rgb 0 }\n#declare CamvalRays = mesh2 {\n")
            _write_mesh2(f, P)
            f.write("}\ncamera { mesh_camera { 1 0 mesh { CamvalRays } } "
                    "location <0,0,0> direction <0,0,1> }\n"
                    "box { <-1,-1,1>, <1,1,2> pigment { rgb 1 } finish { ambient 1 diffuse 0 } }\n")

        workdir = tempfile.mkdtemp(prefix="camval-povray-probe-")
        try:
            img, _, _ = self._run(workdir, write, W, H + 2, 1, None)
        finally:
            shutil.rmtree(workdir, ignore_errors=True)
        # face row 0 shows in image row `off`; rows above it are clamped to face row 0
        # (3.7.0.10: rows 0 and 1 are white)
        white = np.nonzero(img.min(axis=1) > 0.5)[0].tolist()
        if not white or white[-1] > 2 or white not in ([white[-1]], list(range(white[-1] + 1))):
            raise RendererError(f"povray mesh_camera probe: face row 0 shows in image rows "
                                f"{white} of {img.shape[0]}; expected one row, or rows 0..n "
                                "with n <= 2: this POV-Ray maps mesh faces to pixels in an "
                                "unknown way")
        off = self._row_offsets[self.binary] = white[-1]
        return off

    def _mesh_include(self, model, K, path):
        r"""Write (or link from the per-renderer cache) the camera mesh declaring CamvalRays

The mesh depends on the camera and K only; the most recent one is kept in a
temporary directory for the renderer's lifetime (~250 bytes per ray).
"""
        key = (repr(model), int(K))
        cached = self._mesh_cache.get(key)
        if cached is None or not os.path.exists(cached):
            if self._cache_dir is None:
                self._cache_dir = tempfile.mkdtemp(prefix="camval-povray-mesh-")
                weakref.finalize(self, shutil.rmtree, self._cache_dir, True)
            for old in self._mesh_cache.values():
                if os.path.exists(old):
                    os.remove(old)
            self._mesh_cache.clear()
            self._mesh_count += 1
            cached = os.path.join(self._cache_dir, f"rays-{self._mesh_count}.inc")
            W, H = model.width, model.height
            # sub-pixel centres of the K-times finer image, in model pixels
            u = (np.arange(W * K) + 0.5) / K - 0.5
            w = (np.arange(H * K) + 0.5) / K - 0.5
            q = np.stack(np.meshgrid(u, w), axis=-1).reshape(-1, 2)
            Rt = model.Rt_ref_cam()
            origin, v = model.unproject(q)
            o_cam = (origin - Rt[3]) @ Rt[:3]
            v_cam = v @ Rt[:3]
            if not np.all(np.isfinite(v_cam)):
                raise RendererError(f"{model.family} model: some pixels have no ray; cannot "
                                    "build a mesh camera")
            F = np.array([1.0, -1.0, 1.0])
            P = mesh_camera_triangles(o_cam * F, v_cam * F)
            with open(cached, "w") as f:
                f.write("#declare CamvalRays = mesh2 {\n")
                _write_mesh2(f, P)
                f.write("}\n")
            self._mesh_cache[key] = cached
        try:
            os.link(cached, path)
        except OSError:
            shutil.copyfile(cached, path)

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
                img, info = self.render_mesh(render_model, scene, Rt_cam_board, K, workdir,
                                             o["threads"], o["max_mesh_rays"])
                warp_info = {}
            else:
                warp = PinholeWarp.for_model(render_model, scale=float(o["warp_scale"]),
                                         samples=int(o["warp_samples"]))
                pin_img, info = self.render_pinhole(warp.pinhole, scene, Rt_cam_board, K,
                                                    workdir, o["threads"])
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
