r'''Terrain scenes through OpenGL (OSMesa, llvmpipe) with the paper's two-pass z-buffer shadows

SYNOPSIS

    from renderers.osmesa_terrain import render_terrain, cell_shadows
    from targets.terrain import make_terrain, ground_pose

    r = render_terrain(model, terrain, Rt_ref_terrain=ground_pose(1.9, pitch_deg=20), spp=1)
    r.image       # (H,W) float32 in [0,1], as renderers.raycast_terrain
    r.shadow      # (H,W) uint8: 0 lit, 1 facing away, 2 shadowed by the map, 255 sky
    r.range       # None
    r.metadata    # GL version, shadow-map size, bias, darkening factor, timings

    code = cell_shadows(terrain, map_size=4096)   # (Ny-1, Nx-1, 2) uint8 (terrain_shadows)

    r = OSMesaTerrainRenderer(map_size=4096).render_terrain(model, terrain, pose,
                                                            RenderSettings(spp=2))
    # the same through the registry: renderers.base.get_terrain_renderer("osmesa_terrain")

The paper's shadowing (section 3.5, the "Z-buffer shadowing algorithm [8]"
of ROAMS's Dspace): render the scene from the light and keep its z-buffer;
render it from the camera, transform every camera-view fragment into the
light's pixel coordinates and depth Ez, and if the light's z-buffer value Lz
there is less than Ez the fragment is in shadow; "shadowed pixels are
darkened according to a pre-determined shadowing factor".

Pass 1: the terrain (the same two triangles per cell as targets/terrain.py)
is drawn by an orthographic camera looking down the sun direction into a
map_size x map_size 32-bit float depth texture (a framebuffer object), the
view box fitted to the terrain's nodes. Pass 2 (GLSL 3.30): every fragment's
terrain-frame position is mapped to the light's texel (nearest) and depth Ez;
it is shadowed when Ez - bias > Lz. The bias keeps a lit surface from
shadowing itself between the texel centres where its depth was stored: for a
plane tilted by angle i from the sun, depth changes by tan i per metre across
the map, so bias = BIAS_CONSTANT + slope_bias * tan(i) * (texel diagonal),
tan i clamped at MAX_TAN; the default slope_bias = 0.5 covers the half-texel
offset of a plane (benchmarks/bench_render.py shadows: 0.5 disagreed with the exact
shadows less than 1.0 or 2.0 at every sun elevation on a 5 cm grid).

Shading: lit colour = exposure * albedo * (ambient + max(cos i, 0)) as
raycast_terrain; a shadowed fragment facing the sun is that colour times the
darkening factor. The paper does not give its value; the default
(shadow_factor=None) is the ratio of shadowed to lit flat ground under this
sun, ambient / (ambient + sin(elevation)), so flat ground in shadow has
raycast's value. Fragments facing away from the sun have no sun term and are
not darkened again. Albedo is the terrain's texture sampled bilinearly (a
float32 texture, texel centres as Terrain.albedo_at).

The camera view is the paper's pinhole render plus warp (as renderers/
osmesa.py: renderers.warp.PinholeWarp, K x K supersampling by a K-times finer
pinhole in tiles of at most TILE pixels); noncentral CAHVORE is warped at
warp.NONCENTRAL_RANGE, as for the board.

OpenGL runs in the worker process of renderers.gl_worker (the caller never
loads libOSMesa): render_terrain, cell_shadows and gl_version send their
arguments there, where render_terrain_here, cell_shadows_here and
gl_version_here run.

cell_shadows draws pass 2 with an orthographic top-down camera whose pixel
centres are the triangle centroids (pitch cell/3) and reads the shadow test
itself (not the darkened colour).
'''

import math
import time

import numpy as np

from renderers.base import (
    RendererError,
    RendererUnavailableError,
    RenderSettings,
    TerrainRender,
    merged_options,
)
from renderers.osmesa import projection_matrix
from renderers.terrain_shadows import centroid_pixels, top_down_size

NAME = "osmesa_terrain"
SKY = 255
TILE = 2048
DEFAULT_MAP_SIZE = 4096
BIAS_CONSTANT = 1e-6      # metres
MAX_TAN = 20.0
NEAR = 0.01

_STATE = {}

_VS_DEPTH = """
#version 330 compatibility
layout(location = 0) in vec3 p;
uniform mat4 L;
void main() { gl_Position = L * vec4(p, 1.0); }
"""
_FS_DEPTH = """
#version 330 compatibility
void main() { }
"""
_VS_VIEW = """
#version 330 compatibility
layout(location = 0) in vec3 p;
layout(location = 1) in vec3 n;
uniform mat4 P;
out vec3 vp;
out vec3 vn;
void main() { vp = p; vn = n; gl_Position = P * vec4(p, 1.0); }
"""
_FS_VIEW = """
#version 330 compatibility
in vec3 vp;
in vec3 vn;
uniform mat4 L;
uniform sampler2D depthmap;
uniform sampler2D albedo;
uniform vec4 albedo_box;        // xmin, ymin, width, height of the albedo's rectangle
uniform vec3 sun;
uniform float ambient;
uniform float exposure;
uniform float factor;
uniform float shadows;
uniform float bias_metres;      // slope_bias * texel diagonal (m)
uniform float bias_constant;    // m
uniform float depth_range;      // m spanned by light depth 0..1
uniform float max_tan;
uniform int mapsize;
layout(location = 0) out vec4 colour;
void main() {
    float c = dot(normalize(vn), sun);
    vec4 l = L * vec4(vp, 1.0);
    vec3 s = l.xyz * 0.5 + 0.5;             // light texel coordinates in [0,1], depth Ez
    ivec2 texel = clamp(ivec2(floor(s.xy * float(mapsize))), ivec2(0), ivec2(mapsize - 1));
    float Lz = texelFetch(depthmap, texel, 0).r;
    float shadowed = 0.0;
    if (shadows > 0.5 && c > 0.0) {
        float tn = min(sqrt(max(1.0 - c * c, 0.0)) / c, max_tan);
        float bias = (bias_constant + bias_metres * tn) / depth_range;
        if (Lz < s.z - bias) shadowed = 1.0;
    }
    vec2 a = (vp.xy - albedo_box.xy) / albedo_box.zw;
    float alb = texture(albedo, a).r;
    float v = exposure * alb * (ambient + max(c, 0.0));
    if (shadowed > 0.5) v *= factor;
    colour = vec4(v, shadowed, c > 0.0 ? 1.0 : 0.0, 1.0);
}
"""


def _lock():
    r'''renderers.osmesa's lock: one thread at a time in OSMesa/OpenGL in this process'''
    from renderers.osmesa import _GL_LOCK

    return _GL_LOCK


def _gl():
    r'''(GL, osmesa) through renderers.osmesa's loader (PYOPENGL_PLATFORM=osmesa)'''
    from renderers.osmesa import _import_gl

    GL, _, osmesa = _import_gl()
    return GL, osmesa


def _context(width, height):
    r'''Make this module's OSMesa context current on a (height, width, 4) float32 buffer'''
    GL, osmesa = _gl()
    st = _STATE
    if "ctx" not in st:
        ctx = osmesa.OSMesaCreateContextExt(osmesa.OSMESA_RGBA, 32, 0, 0, None)
        if not ctx:
            raise RendererUnavailableError(
                "OSMesa could not create a context; install Debian package libosmesa6")
        st["ctx"] = ctx
    buf = st.get("buf")
    if buf is None or buf.shape != (height, width, 4):
        buf = st["buf"] = np.zeros((height, width, 4), np.float32)
    if not osmesa.OSMesaMakeCurrent(st["ctx"], buf, GL.GL_FLOAT, width, height):
        raise RendererError(f"OSMesaMakeCurrent failed for a {width}x{height} float buffer")
    if "programs" not in st:
        st["programs"] = (_program(GL, _VS_DEPTH, _FS_DEPTH), _program(GL, _VS_VIEW, _FS_VIEW))
        st["version"] = (f"{GL.glGetString(GL.GL_VERSION).decode()} "
                         f"({GL.glGetString(GL.GL_RENDERER).decode()})")
    return GL, buf


def _program(GL, vs, fs):
    from OpenGL.GL import shaders

    try:
        return shaders.compileProgram(shaders.compileShader(vs, GL.GL_VERTEX_SHADER),
                                      shaders.compileShader(fs, GL.GL_FRAGMENT_SHADER),
                                      validate=False)
    except Exception as e:   # shaders.ShaderCompilationError, GLError
        raise RendererUnavailableError(f"OSMesa cannot compile the shadow-map shaders: {e}") from e


def gl_version_here():
    r'''gl_version in this process (the OpenGL worker's side)'''
    with _lock():
        _context(1, 1)
        return _STATE["version"]


# ---------------------------------------------------------------------------
# geometry
def triangles(terrain):
    r'''Vertices (6 per cell, float32 (N,3)) and per-vertex flat normals of the terrain

Triangle 0 of cell (i, j): nodes (i, j), (i+1, j), (i+1, j+1); triangle 1:
(i, j), (i+1, j+1), (i, j+1) (targets/terrain.py). Positions are relative to
the grid's centre (float32 in GL: micrometres on a 20 m grid).
'''
    from renderers.terrain_shadows import triangle_normals

    h = terrain.heights
    ny, nx = h.shape
    x0, y0 = terrain.origin
    X, Y = np.meshgrid(x0 + terrain.cell * np.arange(nx), y0 + terrain.cell * np.arange(ny))
    P = np.stack((X, Y, h), axis=-1) - _centre(terrain)
    p00, p10, p01, p11 = P[:-1, :-1], P[:-1, 1:], P[1:, :-1], P[1:, 1:]
    tri = np.stack((np.stack((p00, p10, p11), axis=-2), np.stack((p00, p11, p01), axis=-2)),
                   axis=-3)                                   # (Ny-1, Nx-1, 2, 3, 3)
    n = np.broadcast_to(triangle_normals(terrain)[..., None, :], tri.shape)
    return (np.ascontiguousarray(tri.reshape(-1, 3), np.float32),
            np.ascontiguousarray(n.reshape(-1, 3), np.float32))


def _centre(terrain):
    xmin, xmax, ymin, ymax = terrain.extent()
    return np.array([(xmin + xmax) / 2, (ymin + ymax) / 2,
                     (terrain.heights.min() + terrain.heights.max()) / 2])


def light_matrix(terrain):
    r'''The sun's orthographic view: (4,4) terrain (centred) -> clip, and its box

RETURNED VALUE: (L, (width_a, width_b, depth_range)) with the view box fitted
to the grid nodes; clip z = -1 nearest the sun.
'''
    w = terrain.sun.direction()
    # light-plane axes: e1 horizontal, perpendicular to the sun's azimuth; e2 completes it
    e1 = np.cross([0.0, 0.0, 1.0], w)
    if np.linalg.norm(e1) < 1e-12:
        e1 = np.array([1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(w, e1)
    ny, nx = terrain.heights.shape
    x0, y0 = terrain.origin
    X, Y = np.meshgrid(x0 + terrain.cell * np.arange(nx), y0 + terrain.cell * np.arange(ny))
    P = np.stack((X, Y, terrain.heights), axis=-1).reshape(-1, 3) - _centre(terrain)
    a, b, d = P @ e1, P @ e2, P @ w
    pad = 1e-3 * max(np.ptp(a), np.ptp(b), 1e-3)
    alo, ahi = a.min() - pad, a.max() + pad
    blo, bhi = b.min() - pad, b.max() + pad
    dlo, dhi = d.min() - pad, d.max() + pad
    L = np.zeros((4, 4))
    L[0, :3] = 2.0 * e1 / (ahi - alo)
    L[0, 3] = -(ahi + alo) / (ahi - alo)
    L[1, :3] = 2.0 * e2 / (bhi - blo)
    L[1, 3] = -(bhi + blo) / (bhi - blo)
    # nearest the sun (largest d) -> -1
    L[2, :3] = -2.0 * w / (dhi - dlo)
    L[2, 3] = (dhi + dlo) / (dhi - dlo)
    L[3, 3] = 1.0
    return L, (ahi - alo, bhi - blo, dhi - dlo)


def default_shadow_factor(terrain):
    r'''The darkening factor that gives flat ground in shadow raycast's value:
ambient / (ambient + sin(sun elevation))'''
    s = math.sin(math.radians(terrain.sun.elevation_deg))
    return terrain.ambient / (terrain.ambient + s)


# ---------------------------------------------------------------------------
# the two passes
class _Scene:
    r'''GL objects of one terrain: vertex arrays, the sun's depth map, the albedo texture'''

    def __init__(self, terrain, map_size, slope_bias, shadows):
        GL, _ = _context(1, 1)
        if not (isinstance(map_size, int) and 16 <= map_size <= 16384):
            raise RendererError(f"shadow map_size must be an integer in [16, 16384]; "
                                f"got {map_size!r}")
        if not (slope_bias >= 0 and math.isfinite(slope_bias)):
            raise RendererError(f"slope_bias must be >= 0; got {slope_bias!r}")
        self.terrain = terrain
        self.map_size = map_size
        self.V, self.N = triangles(terrain)
        self.L, (wa, wb, self.depth_range) = light_matrix(terrain)
        self.texel_diag = math.hypot(wa / map_size, wb / map_size)
        self.bias_metres = slope_bias * self.texel_diag
        self.shadows = shadows
        t0 = time.perf_counter()
        self.depth_tex = self._depth_pass(GL) if shadows else None
        self.seconds_depth = time.perf_counter() - t0
        self.albedo_tex = self._albedo_texture(GL)

    def _draw(self, GL, with_normals):
        GL.glEnableVertexAttribArray(0)
        GL.glVertexAttribPointer(0, 3, GL.GL_FLOAT, GL.GL_FALSE, 0, self.V)
        if with_normals:
            GL.glEnableVertexAttribArray(1)
            GL.glVertexAttribPointer(1, 3, GL.GL_FLOAT, GL.GL_FALSE, 0, self.N)
        GL.glDrawArrays(GL.GL_TRIANGLES, 0, len(self.V))
        GL.glDisableVertexAttribArray(0)
        if with_normals:
            GL.glDisableVertexAttribArray(1)

    def _depth_pass(self, GL):
        S = self.map_size
        tex = GL.glGenTextures(1)
        GL.glBindTexture(GL.GL_TEXTURE_2D, tex)
        GL.glTexImage2D(GL.GL_TEXTURE_2D, 0, GL.GL_DEPTH_COMPONENT32F, S, S, 0,
                        GL.GL_DEPTH_COMPONENT, GL.GL_FLOAT, None)
        for k, v in ((GL.GL_TEXTURE_MIN_FILTER, GL.GL_NEAREST),
                     (GL.GL_TEXTURE_MAG_FILTER, GL.GL_NEAREST),
                     (GL.GL_TEXTURE_WRAP_S, GL.GL_CLAMP_TO_EDGE),
                     (GL.GL_TEXTURE_WRAP_T, GL.GL_CLAMP_TO_EDGE),
                     (GL.GL_TEXTURE_COMPARE_MODE, GL.GL_NONE)):
            GL.glTexParameteri(GL.GL_TEXTURE_2D, k, v)
        fbo = GL.glGenFramebuffers(1)
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, fbo)
        GL.glFramebufferTexture2D(GL.GL_FRAMEBUFFER, GL.GL_DEPTH_ATTACHMENT, GL.GL_TEXTURE_2D,
                                  tex, 0)
        GL.glDrawBuffer(GL.GL_NONE)
        GL.glReadBuffer(GL.GL_NONE)
        status = GL.glCheckFramebufferStatus(GL.GL_FRAMEBUFFER)
        if status != GL.GL_FRAMEBUFFER_COMPLETE:
            raise RendererError(f"OSMesa: the shadow-map framebuffer is incomplete ({status})")
        GL.glViewport(0, 0, S, S)
        GL.glEnable(GL.GL_DEPTH_TEST)
        GL.glDepthFunc(GL.GL_LESS)
        GL.glDisable(GL.GL_CULL_FACE)
        GL.glClearDepth(1.0)
        GL.glClear(GL.GL_DEPTH_BUFFER_BIT)
        prog = _STATE["programs"][0]
        GL.glUseProgram(prog)
        GL.glUniformMatrix4fv(GL.glGetUniformLocation(prog, "L"), 1, GL.GL_TRUE,
                              self.L.astype(np.float32))
        self._draw(GL, False)
        GL.glFinish()
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, 0)
        GL.glDeleteFramebuffers(1, [fbo])
        GL.glUseProgram(0)
        return tex

    def depth_map(self):
        r'''The sun's z-buffer (map_size, map_size) float32, row 0 at the bottom'''
        GL, _ = _context(1, 1)
        GL.glBindTexture(GL.GL_TEXTURE_2D, self.depth_tex)
        return GL.glGetTexImage(GL.GL_TEXTURE_2D, 0, GL.GL_DEPTH_COMPONENT, GL.GL_FLOAT)

    def _albedo_texture(self, GL):
        a = np.ascontiguousarray(self.terrain.albedo, np.float32)
        tex = GL.glGenTextures(1)
        GL.glBindTexture(GL.GL_TEXTURE_2D, tex)
        GL.glPixelStorei(GL.GL_UNPACK_ALIGNMENT, 1)
        GL.glTexImage2D(GL.GL_TEXTURE_2D, 0, GL.GL_R32F, a.shape[1], a.shape[0], 0,
                        GL.GL_RED, GL.GL_FLOAT, a)
        for k, v in ((GL.GL_TEXTURE_MIN_FILTER, GL.GL_LINEAR),
                     (GL.GL_TEXTURE_MAG_FILTER, GL.GL_LINEAR),
                     (GL.GL_TEXTURE_WRAP_S, GL.GL_CLAMP_TO_EDGE),
                     (GL.GL_TEXTURE_WRAP_T, GL.GL_CLAMP_TO_EDGE)):
            GL.glTexParameteri(GL.GL_TEXTURE_2D, k, v)
        return tex

    def view(self, P, width, height, factor, exposure=1.0, background=0.0):
        r'''Pass 2 into a (height, width) window; P (4,4) maps centred terrain -> clip.
Returns the float buffer (height, width, 4), row 0 at the BOTTOM:
colour, shadow-test flag, facing-the-sun flag, coverage.'''
        GL, buf = _context(width, height)
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, 0)
        GL.glViewport(0, 0, width, height)
        GL.glClampColor(GL.GL_CLAMP_READ_COLOR, GL.GL_FALSE)
        GL.glEnable(GL.GL_DEPTH_TEST)
        GL.glDepthFunc(GL.GL_LESS)
        GL.glDisable(GL.GL_CULL_FACE)
        GL.glDisable(GL.GL_BLEND)
        GL.glDisable(GL.GL_DITHER)
        GL.glDisable(GL.GL_MULTISAMPLE)
        GL.glClearColor(background, 0.0, 0.0, 0.0)
        GL.glClearDepth(1.0)
        GL.glClear(GL.GL_COLOR_BUFFER_BIT | GL.GL_DEPTH_BUFFER_BIT)
        prog = _STATE["programs"][1]
        GL.glUseProgram(prog)

        def u(name):
            return GL.glGetUniformLocation(prog, name)

        GL.glUniformMatrix4fv(u("P"), 1, GL.GL_TRUE, P.astype(np.float32))
        GL.glUniformMatrix4fv(u("L"), 1, GL.GL_TRUE, self.L.astype(np.float32))
        t = self.terrain
        xmin, xmax, ymin, ymax = t.extent()
        c = _centre(t)
        GL.glUniform4f(u("albedo_box"), xmin - c[0], ymin - c[1], xmax - xmin, ymax - ymin)
        GL.glUniform3f(u("sun"), *(float(v) for v in t.sun.direction()))
        GL.glUniform1f(u("ambient"), float(t.ambient))
        GL.glUniform1f(u("exposure"), float(exposure))
        GL.glUniform1f(u("factor"), float(factor))
        GL.glUniform1f(u("shadows"), 1.0 if self.shadows else 0.0)
        GL.glUniform1f(u("bias_metres"), float(self.bias_metres))
        GL.glUniform1f(u("bias_constant"), BIAS_CONSTANT)
        GL.glUniform1f(u("depth_range"), float(self.depth_range))
        GL.glUniform1f(u("max_tan"), MAX_TAN)
        GL.glUniform1i(u("mapsize"), self.map_size)
        GL.glActiveTexture(GL.GL_TEXTURE0)
        GL.glBindTexture(GL.GL_TEXTURE_2D, self.depth_tex or 0)
        GL.glUniform1i(u("depthmap"), 0)
        GL.glActiveTexture(GL.GL_TEXTURE1)
        GL.glBindTexture(GL.GL_TEXTURE_2D, self.albedo_tex)
        GL.glUniform1i(u("albedo"), 1)
        self._draw(GL, True)
        GL.glFinish()
        GL.glActiveTexture(GL.GL_TEXTURE0)
        GL.glUseProgram(0)
        return buf.copy()

    def release(self):
        GL, _ = _context(1, 1)
        texs = [x for x in (self.depth_tex, self.albedo_tex) if x]
        if texs:
            GL.glDeleteTextures(texs)


def top_down_matrix(terrain, ox=0, oy=0, width=None, height=None):
    r'''(4,4) centred terrain -> clip of a top-down window: its pixel (a, b) is centred on
(x0 + (ox + a) cell/3, y0 + (oy + b) cell/3); width, height default to the whole grid'''
    W, H = top_down_size(terrain)
    W = W if width is None else width
    H = H if height is None else height
    d = terrain.cell / 3.0
    x0, y0 = terrain.origin
    c = _centre(terrain)
    zlo, zhi = terrain.heights.min() - c[2] - 1.0, terrain.heights.max() - c[2] + 1.0
    P = np.zeros((4, 4))
    # window x_w = (x - x0)/d - ox + 1/2; ndc = 2 x_w / W - 1
    P[0, 0] = 2.0 / (d * W)
    P[0, 3] = 2.0 * ((c[0] - x0) / d - ox + 0.5) / W - 1.0
    P[1, 1] = 2.0 / (d * H)
    P[1, 3] = 2.0 * ((c[1] - y0) / d - oy + 0.5) / H - 1.0
    # highest -> nearest (ndc -1)
    P[2, 2] = -2.0 / (zhi - zlo)
    P[2, 3] = (zhi + zlo) / (zhi - zlo)
    P[3, 3] = 1.0
    return P


def cell_shadows_here(terrain, map_size=DEFAULT_MAP_SIZE, slope_bias=0.5, tile_size=TILE):
    r'''cell_shadows in this process (the OpenGL worker's side)

The shadow-map verdict at every triangle centroid, seen from straight above

SYNOPSIS

    code = cell_shadows(terrain, map_size=4096)   # (Ny-1, Nx-1, 2) uint8: 0 lit, 1 away, 2 cast

Pass 2 is drawn by an orthographic top-down camera whose pixel centres are
the centroids (pitch cell/3), in tiles of at most TILE x TILE pixels; a
pixel's shadow-test flag and facing flag (cos i > 0, float32 in the shader)
give the code.
'''
    W, H = top_down_size(terrain)
    col, row = centroid_pixels(terrain)
    px = np.full(col.shape + (4,), np.nan, np.float32)
    with _lock():
        scene = _Scene(terrain, map_size, slope_bias, True)
        try:
            for oy in range(0, H, tile_size):
                for ox in range(0, W, tile_size):
                    tw, th = min(tile_size, W - ox), min(tile_size, H - oy)
                    buf = scene.view(top_down_matrix(terrain, ox, oy, tw, th), tw, th, 1.0)
                    inside = (col >= ox) & (col < ox + tw) & (row >= oy) & (row < oy + th)
                    px[inside] = buf[row[inside] - oy, col[inside] - ox]
        finally:
            scene.release()
    if not np.all(px[..., 3] == 1.0):
        raise RendererError("OSMesa top-down view: some triangle centroids were not drawn")
    return np.where(px[..., 2] < 0.5, 1, np.where(px[..., 1] > 0.5, 2, 0)).astype(np.uint8)


def _camera_matrix(model, Rt_ref_terrain, terrain):
    r'''(4,4): centred terrain -> the model's camera frame'''
    import mrcal

    Rt = np.vstack((np.eye(3), np.zeros(3))) if Rt_ref_terrain is None else \
        np.asarray(Rt_ref_terrain, np.float64)
    if Rt.shape != (4, 3) or not np.all(np.isfinite(Rt)):
        raise RendererError(f"Rt_ref_terrain must be a finite (4,3) array; got shape {Rt.shape}")
    Rt_cam_terrain = mrcal.compose_Rt(mrcal.invert_Rt(model.Rt_ref_cam()), Rt)
    M = np.eye(4)
    M[:3, :3] = Rt_cam_terrain[:3]
    M[:3, 3] = Rt_cam_terrain[3] + Rt_cam_terrain[:3] @ _centre(terrain)
    return M


def render_terrain_here(model, terrain, Rt_ref_terrain=None, spp=1, shadows=True, exposure=1.0,
                        sky=0.0, shadow_factor=None, map_size=DEFAULT_MAP_SIZE, slope_bias=0.5,
                        interpolation="bilinear", warp_scale=1.0, tile_size=TILE):
    r'''render_terrain in this process (the OpenGL worker's side)

Render a terrain through a camera model with OpenGL and the two-pass shadow map

SYNOPSIS

    r = render_terrain(model, terrain, Rt_ref_terrain, spp=1, shadows=True)
    # r.image (H,W) float32 in [0,1]; r.range is None
    # r.shadow (H,W) uint8 as raycast_terrain's: 0 lit, 1 facing away, 2 shadow-map
    # shadow, 255 sky (the pinhole pixel nearest each pixel centre's ray)

Arguments as renderers.raycast_terrain.render_terrain, plus shadow_factor
(the paper's darkening factor; None: default_shadow_factor(terrain)),
map_size (the sun's z-buffer is map_size^2), slope_bias (in texel
diagonals, see the module docstring), and the warp's interpolation and
warp_scale.
'''
    import cv2

    from renderers.warp import PinholeWarp, box_downsample

    if isinstance(spp, bool) or not isinstance(spp, int) or spp < 1:
        raise RendererError(f"supersampling K must be a positive integer; got {spp!r}")
    factor = default_shadow_factor(terrain) if shadow_factor is None else float(shadow_factor)
    if not (0.0 <= factor <= 1.0):
        raise RendererError(f"shadow_factor must be in [0,1]; got {shadow_factor!r}")
    t0 = time.perf_counter()
    M = _camera_matrix(model, Rt_ref_terrain, terrain)
    warp = PinholeWarp.for_model(model, scale=float(warp_scale))
    fine = warp.pinhole.scaled(spp)
    xmin, xmax, ymin, ymax = terrain.extent()
    far = 2.0 * (np.linalg.norm(M[:3, 3]) + math.hypot(xmax - xmin, ymax - ymin,
                                                         np.ptp(terrain.heights))) + 1.0
    K = spp
    step = max(1, tile_size // K) * K
    pin = np.empty((warp.pinhole.height, warp.pinhole.width))
    pin_code = np.empty(pin.shape, np.uint8)
    with _lock():
        scene = _Scene(terrain, map_size, slope_bias, shadows)
        t1 = time.perf_counter()
        try:
            for oy in range(0, fine.height, step):
                for ox in range(0, fine.width, step):
                    tw, th = min(step, fine.width - ox), min(step, fine.height - oy)
                    tile = fine.shifted(ox, oy, tw, th)
                    P = projection_matrix(tile, near=NEAR, far=far)
                    buf = scene.view(P @ M, tw, th, factor, exposure, sky)
                    buf = buf[::-1]                              # top row first
                    img = buf[..., 0].astype(np.float64)
                    blk = np.s_[oy // K:(oy + th) // K, ox // K:(ox + tw) // K]
                    pin[blk] = box_downsample(img, K)
                    # the shadow code of the (K//2, K//2) sub-pixel: the centre for odd K
                    c = buf[K // 2::K, K // 2::K]
                    pin_code[blk] = np.where(c[..., 3] < 0.5, SKY, np.where(
                        c[..., 2] < 0.5, 1, np.where(c[..., 1] > 0.5, 2, 0)))
        finally:
            scene.release()
    t2 = time.perf_counter()
    image = warp.apply(pin, interpolation)
    map_x, map_y = warp.map()
    shadow = cv2.remap(pin_code, map_x, map_y, cv2.INTER_NEAREST,
                       borderMode=cv2.BORDER_CONSTANT, borderValue=SKY)
    t3 = time.perf_counter()
    return TerrainRender(
        image=np.clip(image, 0.0, 1.0).astype(np.float32), range=None, shadow=shadow,
        metadata={"renderer": NAME, "version": gl_version_here(), "spp": spp,
                  "shadows": bool(shadows), "exposure": exposure, "shadow_factor": factor,
                  "map_size": map_size, "slope_bias": slope_bias,
                  "shadow_texel_diagonal_m": scene.texel_diag, "seconds": t3 - t0,
                  "seconds_depth_pass": scene.seconds_depth, "seconds_view": t2 - t1,
                  "seconds_warp": t3 - t2, "pinhole": warp.pinhole.as_dict(),
                  "interpolation": interpolation,
                  "surface": "triangle pair per cell", "terrain": terrain.as_dict()})


# --- the public functions: OpenGL runs in the worker process (renderers.gl_worker) -----
def gl_version():
    r'''The OpenGL version and renderer string (RendererUnavailableError with the fix when
OSMesa cannot be loaded)'''
    from renderers.gl_worker import call
    return call("terrain.version")


def cell_shadows(terrain, map_size=DEFAULT_MAP_SIZE, slope_bias=0.5):
    r'''The shadow-map verdict at every triangle centroid, seen from straight above

SYNOPSIS

    code = cell_shadows(terrain, map_size=4096)   # (Ny-1, Nx-1, 2) uint8: 0 lit, 1 away, 2 cast

Drawn in the OpenGL worker process (cell_shadows_here there).
'''
    from renderers.gl_worker import call
    return call("terrain.cell_shadows", terrain, map_size=map_size, slope_bias=slope_bias,
                tile_size=TILE)


def render_terrain(model, terrain, Rt_ref_terrain=None, spp=1, shadows=True, exposure=1.0,
                   sky=0.0, shadow_factor=None, map_size=DEFAULT_MAP_SIZE, slope_bias=0.5,
                   interpolation="bilinear", warp_scale=1.0):
    r'''Render a terrain through a camera model with OpenGL and the two-pass shadow map

SYNOPSIS

    r = render_terrain(model, terrain, Rt_ref_terrain, spp=1, shadows=True)
    # a TerrainRender, as render_terrain_here's; rendered in the OpenGL worker process
'''
    from renderers.gl_worker import call
    return call("terrain.render", model, terrain, Rt_ref_terrain, spp=spp, shadows=shadows,
                exposure=exposure, sky=sky, shadow_factor=shadow_factor, map_size=map_size,
                slope_bias=slope_bias, interpolation=interpolation, warp_scale=warp_scale,
                tile_size=TILE)


class OSMesaTerrainRenderer:
    r'''OpenGL (OSMesa) with the two-pass shadow map as a renderer of terrain scenes
(renderers.base.TerrainRenderer)

SYNOPSIS

    r = OSMesaTerrainRenderer(map_size=4096, slope_bias=0.5)
    result = r.render_terrain(model, terrain, Rt_ref_terrain, RenderSettings(spp=2))
    code = r.cell_shadows(terrain)

ARGUMENTS (defaults for every render; RenderSettings.options override them):
render_terrain's shadows, exposure, sky, shadow_factor, map_size,
slope_bias, interpolation and warp_scale. OpenGL is loaded here
(RendererUnavailableError with the fix). settings.spp is K (settings None:
K = 1); RenderSettings.adaptive does not apply.
'''

    name = NAME
    scenes = ("terrain",)

    def __init__(self, shadows=True, exposure=1.0, sky=0.0, shadow_factor=None,
                 map_size=DEFAULT_MAP_SIZE, slope_bias=0.5, interpolation="bilinear",
                 warp_scale=1.0):
        gl_version()
        self.defaults = dict(shadows=shadows, exposure=exposure, sky=sky,
                             shadow_factor=shadow_factor, map_size=map_size,
                             slope_bias=slope_bias, interpolation=interpolation,
                             warp_scale=warp_scale)

    def version(self):
        return gl_version()

    def render_terrain(self, model, terrain, Rt_ref_terrain=None, settings=None):
        settings = settings or RenderSettings(spp=1)
        return render_terrain(model, terrain, Rt_ref_terrain, spp=settings.spp,
                              **merged_options(self.name, self.defaults, settings))

    def cell_shadows(self, terrain):
        return cell_shadows(terrain, map_size=self.defaults["map_size"],
                            slope_bias=self.defaults["slope_bias"])
