r'''OpenGL (Mesa llvmpipe through OSMesa, headless) as a camval renderer: Dspace's path

SYNOPSIS

    from renderers.base import get_renderer, RenderSettings

    r = get_renderer("osmesa")
    result = r.render(model, target.pattern(), Rt_cam_board, RenderSettings(spp=4))
    # result.image has shape (model.height, model.width), float32 in [0,1]

As in ROAMS's Dspace, OpenGL rasterises the pinhole view of the board (a
triangle mesh: the board quad, one quad per cell, a 512-gon per dot whose
area equals the disc's), then renderers.warp maps it to the CAHV/CAHVOR/
CAHVORE model. K x K supersampling renders the pinhole K times finer (in
tiles of at most TILE fine pixels, each its own viewport) and averages K x K
blocks. The colour buffer is float32 RGBA (OSMesaMakeCurrent with GL_FLOAT),
so albedo is not quantised to 8 bits; no depth test: the board's layers are
painted in the Pattern's order (board, cells, dots). Dots are not clipped to
the board rectangle.

Pixel convention. OpenGL samples pixel (i, j) at window coordinates
(i + 0.5, j + 0.5), window y up from the bottom row; camval puts the centre of
the top-left pixel at q = (0, 0). The projection matrix maps camera-frame
points straight to clip space with x_w = u + 0.5, y_w = H - 0.5 - v for
camval pinhole pixel (u, v), and the buffer (row 0 at the bottom, OSMesa's
default Y_UP) is flipped once when read. No other flip (FINDINGS: with
OSMESA_Y_UP = 0 a first attempt came out upside down).

OpenGL runs in a child process (renderers.gl_worker: the process that renders
never loads libOSMesa, whose llvmpipe brings a second LLVM beside numba's);
the pinhole view is drawn there, the warp here. In that process
PYOPENGL_PLATFORM is set to "osmesa" before OpenGL is imported, unless the
environment already sets it. Missing libOSMesa raises
RendererUnavailableError at construction with the fix.
'''

import math
import os
import threading
import time

import numpy as np

from .base import (
    RendererError,
    RendererUnavailableError,
    RenderResult,
    RenderSettings,
    merged_options,
)
from .warp import INTERPOLATIONS, PinholeWarp

INSTALL_HINT = "install Debian package libosmesa6 (apt-get install libosmesa6)"
TILE = 2048
DOT_SEGMENTS = 512
NEAR, FAR = 1e-3, 1e4

_GL = None
_GL_LOCK = threading.RLock()


def _import_gl():
    global _GL
    if _GL is None:
        os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
        if os.environ["PYOPENGL_PLATFORM"] != "osmesa":
            raise RendererUnavailableError(
                f"renderer 'osmesa' needs PYOPENGL_PLATFORM=osmesa; the environment sets "
                f"{os.environ['PYOPENGL_PLATFORM']!r} (unset it or set it to osmesa)")
        try:
            from OpenGL import GL, arrays, osmesa
        except Exception as e:  # ImportError, or PyOpenGL failing to load libOSMesa
            raise RendererUnavailableError(
                f"renderer 'osmesa': cannot load OSMesa through PyOpenGL ({e}); {INSTALL_HINT}"
            ) from e
        _GL = (GL, arrays, osmesa)
    return _GL


def projection_matrix(pinhole, near=NEAR, far=FAR):
    r'''The OpenGL projection (4,4) of a renderers.warp.Pinhole, camera frame -> clip

Camera frame: x = H', y = A x H' (down the image), z = A (forward); clip w = z;
depth from the near to the far plane (m).
'''
    W, H = pinhole.width, pinhole.height
    P = np.zeros((4, 4))
    P[0, 0] = 2.0 * pinhole.fx / W
    P[0, 2] = 2.0 * (pinhole.cx + 0.5) / W - 1.0
    P[1, 1] = -2.0 * pinhole.fy / H
    P[1, 2] = 1.0 - (2.0 * pinhole.cy + 1.0) / H
    P[2, 2] = (far + near) / (far - near)
    P[2, 3] = -2.0 * far * near / (far - near)
    P[3, 2] = 1.0
    return P


def board_triangles(pattern):
    r'''[(albedo, triangles (N,3,3) in the board frame)] in painting order'''
    xmin, xmax, ymin, ymax = (float(v) for v in pattern.extent)

    def quad(x0, x1, y0, y1):
        a, b, c, d = (x0, y0, 0.0), (x1, y0, 0.0), (x1, y1, 0.0), (x0, y1, 0.0)
        return np.array([[a, b, c], [a, c, d]])

    layers = [(float(pattern.board_value), quad(xmin, xmax, ymin, ymax))]
    if pattern.cells is not None:
        cells = np.asarray(pattern.cells, dtype=np.float64)
        s = float(pattern.cell_size)
        ox, oy = (float(v) for v in pattern.cell_origin)
        by_value = {}
        for iy, ix in zip(*np.nonzero(np.isfinite(cells)), strict=True):
            x0, y0 = ox + ix * s, oy + iy * s
            x0c, x1c = max(x0, xmin), min(x0 + s, xmax)
            y0c, y1c = max(y0, ymin), min(y0 + s, ymax)
            if x1c > x0c and y1c > y0c:
                by_value.setdefault(float(cells[iy, ix]), []).append(quad(x0c, x1c, y0c, y1c))
        for value, quads in by_value.items():
            layers.append((value, np.concatenate(quads)))
    if pattern.circles is not None and len(pattern.circles):
        n = DOT_SEGMENTS
        # radius of the n-gon with the disc's area
        k = math.sqrt(math.pi / (0.5 * n * math.sin(2 * math.pi / n)))
        a = np.linspace(0, 2 * np.pi, n + 1)
        tris = []
        for cx, cy, r in np.asarray(pattern.circles, dtype=np.float64):
            x = cx + k * r * np.cos(a)
            y = cy + k * r * np.sin(a)
            t = np.zeros((n, 3, 3))
            t[:, 0, :2] = (cx, cy)
            t[:, 1, 0], t[:, 1, 1] = x[:-1], y[:-1]
            t[:, 2, 0], t[:, 2, 1] = x[1:], y[1:]
            tris.append(t)
        layers.append((float(pattern.circle_value), np.concatenate(tris)))
    return layers


class GLRasteriser:
    r'''The pinhole raster in this process: an OSMesa context and its float32 buffer

Runs in the OpenGL worker process (renderers.gl_worker), never in a process
that compiles with numba (see there).
'''

    def __init__(self):
        self.GL, self.arrays, self.osmesa = _import_gl()
        with _GL_LOCK:
            self._ctx = self.osmesa.OSMesaCreateContextExt(self.osmesa.OSMESA_RGBA, 0, 0, 0,
                                                           None)
        if not self._ctx:
            raise RendererUnavailableError(f"OSMesa could not create a context; {INSTALL_HINT}")
        self._version = None
        self._buf = None

    def version(self):
        if self._version is None:
            with _GL_LOCK:
                self._make_current(1, 1)
                GL = self.GL
                self._version = (f"{GL.glGetString(GL.GL_VERSION).decode()} "
                                 f"({GL.glGetString(GL.GL_RENDERER).decode()})")
        return self._version

    def _make_current(self, width, height):
        if self._buf is None or self._buf.shape != (height, width, 4):
            self._buf = np.zeros((height, width, 4), dtype=np.float32)
        buf = self._buf
        if not self.osmesa.OSMesaMakeCurrent(self._ctx, buf, self.GL.GL_FLOAT, width, height):
            raise RendererError(f"OSMesaMakeCurrent failed for a {width}x{height} float buffer")
        return buf

    def _draw_tile(self, tile, layers_cam, background):
        GL = self.GL
        buf = self._make_current(tile.width, tile.height)
        GL.glViewport(0, 0, tile.width, tile.height)
        GL.glDisable(GL.GL_DEPTH_TEST)
        GL.glDisable(GL.GL_CULL_FACE)
        GL.glDisable(GL.GL_DITHER)
        GL.glDisable(GL.GL_BLEND)
        GL.glDisable(GL.GL_MULTISAMPLE)
        GL.glClearColor(background, background, background, 1.0)
        GL.glClear(GL.GL_COLOR_BUFFER_BIT)
        GL.glMatrixMode(GL.GL_PROJECTION)
        GL.glLoadMatrixd(projection_matrix(tile).T.copy())
        GL.glMatrixMode(GL.GL_MODELVIEW)
        GL.glLoadIdentity()
        GL.glEnableClientState(GL.GL_VERTEX_ARRAY)
        for value, tris in layers_cam:
            v = np.ascontiguousarray(tris.reshape(-1, 3), dtype=np.float64)
            GL.glColor4d(value, value, value, 1.0)
            GL.glVertexPointer(3, GL.GL_DOUBLE, 0, v)
            GL.glDrawArrays(GL.GL_TRIANGLES, 0, len(v))
        GL.glDisableClientState(GL.GL_VERTEX_ARRAY)
        GL.glFinish()
        # red channel, top row first (float32; averaged in float64 by the caller)
        return np.ascontiguousarray(buf[::-1, :, 0])

    def render_pinhole(self, pinhole, pattern, Rt_cam_board, K, tile_size=TILE):
        r'''Render the pinhole view (pinhole.height, pinhole.width), K x K supersampled'''
        Rt = np.asarray(Rt_cam_board, dtype=np.float64)
        if Rt.shape != (4, 3) or not np.all(np.isfinite(Rt)):
            raise RendererError(f"Rt_cam_board must be a finite (4,3) array; got shape {Rt.shape}")
        layers = [(v, t @ Rt[:3].T + Rt[3]) for v, t in board_triangles(pattern)]
        fine = pinhole.scaled(K)
        step = max(1, tile_size // K) * K       # fine pixels per tile side, a multiple of K
        out = np.empty((pinhole.height, pinhole.width))
        with _GL_LOCK:
            for oy in range(0, fine.height, step):
                for ox in range(0, fine.width, step):
                    tw, th = min(step, fine.width - ox), min(step, fine.height - oy)
                    tile = fine.shifted(ox, oy, tw, th)
                    img = self._draw_tile(tile, layers, float(pattern.background_value))
                    blk = img.reshape(th // K, K, tw // K, K).mean(axis=(1, 3),
                                                                   dtype=np.float64)
                    out[oy // K:(oy + th) // K, ox // K:(ox + tw) // K] = blk
        return out


class OSMesaRenderer:
    r'''OpenGL/OSMesa pinhole render + warp (see the module docstring)

The raster runs in the OpenGL worker process (renderers.gl_worker); the warp
runs here.

ARGUMENTS (defaults; RenderSettings.options override them)

- interpolation: warp interpolation, "bilinear" or "bicubic"
- warp_scale: pinhole resolution relative to the model's finest pixel
- warp_samples: n, average n x n remaps per model pixel (use with warp_scale = n)
- legacy / fault: render a defective model (renderers.legacy)
'''

    name = "osmesa"

    def __init__(self, interpolation="bilinear", warp_scale=1.0, warp_samples=1, legacy=None,
                 fault=None):
        from .gl_worker import call
        self._call = call
        self.defaults = dict(interpolation=interpolation, warp_scale=warp_scale,
                             warp_samples=warp_samples, legacy=legacy,
                             fault=fault)
        self._check(self.defaults)
        # loads OSMesa in the worker: RendererUnavailableError with the fix when it cannot
        self._version = call("osmesa.version")

    @staticmethod
    def _check(o):
        if o["interpolation"] not in INTERPOLATIONS:
            raise RendererError(f"osmesa interpolation {o['interpolation']!r} is unknown; "
                                f"known: {', '.join(INTERPOLATIONS)}")

    def version(self):
        return self._version

    def render_pinhole(self, pinhole, pattern, Rt_cam_board, K):
        r'''Render the pinhole view (pinhole.height, pinhole.width), K x K supersampled'''
        return self._call("osmesa.render_pinhole", pinhole, pattern,
                          np.asarray(Rt_cam_board), int(K), TILE)

    def render(self, model, scene, Rt_cam_board, settings=None):
        from .legacy import apply_defects

        settings = RenderSettings() if settings is None else settings
        o = merged_options("osmesa", self.defaults, settings)
        self._check(o)
        render_model, defects = apply_defects(model, o["legacy"], o["fault"])
        t0 = time.perf_counter()
        warp = PinholeWarp.for_model(render_model, scale=float(o["warp_scale"]),
                                         samples=int(o["warp_samples"]))
        t1 = time.perf_counter()
        pin = self.render_pinhole(warp.pinhole, scene, Rt_cam_board, settings.spp)
        t2 = time.perf_counter()
        img = warp.apply(pin, o["interpolation"], Rt_cam_board=Rt_cam_board)
        image = np.clip(np.asarray(img, dtype=np.float32), 0.0, 1.0)
        meta = dict(renderer=self.name, version=self.version(), settings=settings.as_dict(),
                    seconds=time.perf_counter() - t0, samples=settings.spp ** 2,
                    pinhole=warp.pinhole.as_dict(), interpolation=o["interpolation"],
                    warp_seconds=t1 - t0, raster_seconds=t2 - t1, defects=defects)
        return RenderResult(image=image, metadata=meta)
