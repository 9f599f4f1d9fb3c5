r'''Terrain scenes through POV-Ray 3.7, with POV-Ray's own shadows from a parallel sun

SYNOPSIS

    from renderers.povray_terrain import render_terrain, cell_shadows
    from targets.terrain import make_terrain, ground_pose

    r = render_terrain(model, terrain, Rt_ref_terrain=ground_pose(1.9, pitch_deg=20), spp=1)
    r.image       # (H,W) float32 in [0,1], as renderers.raycast_terrain
    r.range       # None: POV-Ray gives no per-pixel range
    r.shadow      # None, or with shadow_codes=True POV-Ray's per-pixel verdict (uint8,
                  # raycast_terrain's codes) from one more render
    r.metadata    # POV-Ray version, timings, the pinhole

    code = cell_shadows(terrain)   # (Ny-1, Nx-1, 2) uint8 per triangle centroid (terrain_shadows)
    albedo, code = shadow_texture(terrain)   # (Ty,Tx): the albedo darkened where cast-shadowed

    r = PovrayTerrainRenderer(camera="mesh").render_terrain(model, terrain, pose,
                                                            RenderSettings(spp=2))
    # the same through the registry: renderers.base.get_terrain_renderer("povray_terrain")

The terrain is a `mesh2` with one vertex per grid node (%.17g, full
precision) and the same two triangles per cell as targets/terrain.py: node
(i, j), (i+1, j), (i+1, j+1) (u >= v) and (i, j), (i+1, j+1), (i, j+1). The
albedo is a 16-bit grey image_map (gamma 1, bilinear `interpolate 2`) laid
over the grid's rectangle along z. The sun is a parallel light_source placed
SUN_DISTANCE scene sizes away along Sun.direction() (POV-Ray's parallel lights
cast no shadows from objects behind the light's location, so it must be far).

Shading matches raycast_terrain's: radiance = exposure * albedo * (ambient +
cos i * lit): finish { ambient exposure*ambient diffuse 1 } with
ambient_light 1, a light of colour `exposure`, assumed_gamma 1 and a linear
16-bit PNG. POV-Ray decides `lit` with its own shadow rays.

Camera: as renderers/povray.py's "perspective" path (the paper's): an
oversized pinhole (renderers.warp.PinholeWarp) rendered by POV-Ray's
perspective camera (renderers.povray.perspective_camera), then warped to the
model. A noncentral CAHVORE model is warped as if every pixel saw the point
warp.NONCENTRAL_RANGE metres along its ray (the warp cannot know the terrain's
depth), and a field of view past 88.8 deg cannot be warped. camera="mesh"
traces model.unproject's exact rays instead: a mesh_camera (distribution 0,
one unit triangle per sub-pixel ray, %.17g), with the face-row offset of
POV-Ray 3.7.0.10 probed once per binary (mesh_row_offset). Self-contained
here (renderers/povray.py is moving to another mesh camera). Measured: on
the MER hazcam (CAHVORE fisheye, 256x256, K = 2) the image equals
raycast_terrain's to 7e-6 on average (16-bit output) and 99.99% of the pixel
shadow codes are equal.

Measured: pixel rays that meet the surface exactly on a triangle edge (a
camera looking straight down with its pixel rays on the grid's lattice, e.g.
every ray on a cell diagonal) come out speckled, and points 0.07 mm from a
concave cell diagonal that the exact shadow ray finds shadowed by the
triangle across the fold are lit for POV-Ray (its shadow rays skip occluders
very close to their origin). Points a few mm from edges agree with
raycast_terrain exactly (tests/test_shadow_agreement.py: 0 of 12800 triangle
centroids, 0 of 25600 texels; 0 of 160000 on a 2 cm texture), and off the
lattice (any real pose) the image equals raycast_terrain's to 16-bit
precision away from edges.

cell_shadows renders the terrain from straight above with an orthographic
camera whose pixel centres are the triangle centroids (pitch cell/3), one
ray per pixel, white albedo and two suns so bright that any light saturates:
one casting shadows (red), one shadowless (green, i.e. facing the sun), plus
ambient (blue, i.e. terrain): POV-Ray's own verdict, lit / facing away / cast.
shadow_texture is the paper's first method: the same verdict at every texel,
baked into the albedo texture for a renderer without shadows.
'''

import functools
import math
import os
import shutil
import tempfile
import time

import numpy as np

from renderers.base import (
    RendererError,
    RendererUnavailableError,
    RenderSettings,
    TerrainRender,
    merged_options,
)
from renderers.terrain_shadows import centroid_pixels, top_down_size

NAME = "povray_terrain"
SUN_DISTANCE = 100.0
INSTALL_HINT = "install Debian package povray (apt-get install povray)"


def _fmt(x):
    return f"{x:.17g}"


def _vec(v):
    return "<" + ",".join(_fmt(float(c)) for c in v) + ">"


def find_povray(binary="povray"):
    r'''Path of the POV-Ray binary; RendererUnavailableError with the fix if missing'''
    path = shutil.which(binary)
    if path is None:
        raise RendererUnavailableError(
            f"renderer '{NAME}': the POV-Ray binary {binary!r} is not on PATH; {INSTALL_HINT}")
    return path


@functools.lru_cache(maxsize=4)
def povray_version(binary="povray"):
    from renderers.povray import PovrayRenderer

    return PovrayRenderer(binary=binary).version()


def write_mesh2(f, terrain, name="CamvalTerrain"):
    r'''Declare the terrain's surface as a POV-Ray mesh2 named `name` (terrain frame, z up)

The vertices are the grid nodes at full precision; faces are the two
triangles of each cell of targets/terrain.py. No normals: flat triangles.
'''
    h = terrain.heights
    ny, nx = h.shape
    x0, y0 = terrain.origin
    x = x0 + terrain.cell * np.arange(nx)
    y = y0 + terrain.cell * np.arange(ny)
    X, Y = np.meshgrid(x, y)
    V = np.stack((X, Y, h), axis=-1).reshape(-1, 3)
    f.write(f"#declare {name} = mesh2 {{\n")
    f.write(f"vertex_vectors {{ {len(V)},\n")
    chunk = 65536
    flat = V.tolist()
    for k in range(0, len(flat), chunk):
        f.write("".join(f"<{a:.17g},{b:.17g},{c:.17g}>\n" for a, b, c in flat[k:k + chunk]))
    f.write("}\n")
    jj, ii = np.meshgrid(np.arange(ny - 1), np.arange(nx - 1), indexing="ij")
    n00 = (jj * nx + ii).ravel()
    n10, n01, n11 = n00 + 1, n00 + nx, n00 + nx + 1
    faces = np.stack((np.stack((n00, n10, n11), -1), np.stack((n00, n11, n01), -1)),
                     axis=1).reshape(-1, 3).tolist()
    f.write(f"face_indices {{ {len(faces)},\n")
    for k in range(0, len(faces), chunk):
        f.write("".join(f"<{a},{b},{c}>\n" for a, b, c in faces[k:k + chunk]))
    f.write("}\n}\n")


def write_albedo_png(terrain, path):
    r'''The albedo as a 16-bit grey PNG oriented for POV-Ray's image_map (top row = max y)'''
    import cv2

    img = np.clip(np.rint(np.asarray(terrain.albedo, np.float64) * 65535.0), 0, 65535)
    if not cv2.imwrite(str(path), img[::-1].astype(np.uint16)):
        raise RendererError(f"cannot write the albedo texture {path}")


def _albedo_pigment(terrain, png_name):
    xmin, xmax, ymin, ymax = terrain.extent()
    # image_map (map_type 0) covers x, y in [0,1]^2 with the image's top row at y = 1
    return (f'pigment {{ image_map {{ png "{png_name}" gamma 1.0 interpolate 2 map_type 0 }} '
            f"scale <{_fmt(xmax - xmin)},{_fmt(ymax - ymin)},1> "
            f"translate <{_fmt(xmin)},{_fmt(ymin)},0> }}")


def _sun_light(terrain, M, t, colour, shadowless=False):
    r'''A parallel light along the sun direction, in POV coordinates p_pov = M p + t'''
    xmin, xmax, ymin, ymax = terrain.extent()
    zlo, zhi = float(terrain.heights.min()), float(terrain.heights.max())
    centre = np.array([(xmin + xmax) / 2, (ymin + ymax) / 2, (zlo + zhi) / 2])
    size = math.hypot(xmax - xmin, ymax - ymin, zhi - zlo)
    s = terrain.sun.direction()
    loc = M @ (centre + SUN_DISTANCE * max(size, 1.0) * s) + t
    at = M @ centre + t
    return (f"light_source {{ {_vec(loc)} color rgb {_fmt(colour)} parallel point_at {_vec(at)}"
            f"{' shadowless' if shadowless else ''} }}\n")


def _run(binary, workdir, scene, width, height, aa_depth=1, threads=None, rgb=False):
    r'''renderers.povray.run_povray on `scene` (text): (image, seconds)'''
    from renderers.povray import run_povray
    img, seconds, _ = run_povray(binary, workdir, lambda f: f.write(scene), width, height,
                                 aa_depth, threads, rgb=rgb)
    return img, seconds


def top_down_codes(terrain, first, step, size, binary="povray", threads=None, keep_dir=None):
    r'''POV-Ray's shadow code at every pixel of an orthographic view from straight above

SYNOPSIS

    code = top_down_codes(terrain, first=(x, y), step=(dx, dy), size=(W, H))
    # (H, W) uint8: 0 lit, 1 facing away from the sun, 2 cast shadow, 255 no terrain;
    # pixel (a, b) is the surface point above (x + a dx, y + b dy)

One render of code_scene_text (one ray per pixel, no anti-aliasing): a sun
that casts shadows lights the red channel, a shadowless one the green
channel, ambient light the blue one, each saturating.
'''
    bin_path = find_povray(binary)
    (xf, yf), (dx, dy), (W, H) = first, step, size
    zhi = float(terrain.heights.max())
    # pixel (a, b) is traced from location + ((a+1/2)/W - 1/2) right + (1/2 - (b+1/2)/H) up:
    # up = -H dy y puts row b at yf + b dy
    loc = (xf + (W - 1) / 2.0 * dx, yf + (H - 1) / 2.0 * dy, zhi + 10.0)
    camera = (f"camera {{ orthographic location {_vec(loc)} direction <0,0,-1> "
              f"right <{_fmt(W * dx)},0,0> up <0,{_fmt(-H * dy)},0> }}\n")
    workdir = keep_dir or tempfile.mkdtemp(prefix="camval-povray-terrain-")
    os.makedirs(workdir, exist_ok=True)
    try:
        c, _ = _run(bin_path, workdir, code_scene_text(terrain, np.eye(3), np.zeros(3), camera),
                    int(W), int(H), 1, threads, rgb=True)
    finally:
        if not keep_dir:
            shutil.rmtree(workdir, ignore_errors=True)
    return np.where(c[..., 2] < 0.5, 255, np.where(
        c[..., 1] < 0.5, 1, np.where(c[..., 0] < 0.5, 2, 0))).astype(np.uint8)


def cell_shadows(terrain, binary="povray", threads=None, keep_dir=None):
    r'''POV-Ray's shadow verdict at every triangle centroid, seen from straight above

SYNOPSIS

    code = cell_shadows(terrain)   # (Ny-1, Nx-1, 2) uint8: 0 lit, 1 facing away, 2 cast

top_down_codes over the grid with pixel pitch cell/3: the centroids are
pixel centres (renderers.terrain_shadows.centroid_pixels).
'''
    W, H = top_down_size(terrain)
    d = terrain.cell / 3.0
    img = top_down_codes(terrain, terrain.origin, (d, d), (W, H), binary, threads, keep_dir)
    col, row = centroid_pixels(terrain)
    code = img[row, col]
    if np.any(code == 255):
        raise RendererError("POV-Ray's top-down view missed the terrain at some centroids")
    return code


def shadow_texture(terrain, shadow_factor=None, binary="povray", threads=None,
                   nudge=(0.25, -0.25)):
    r'''The paper's first method: POV-Ray's shadow map of the terrain baked into its texture

SYNOPSIS

    albedo, code = shadow_texture(terrain)     # each (Ty, Tx): float32, uint8 codes
    r = osmesa_terrain.render_terrain(model, terrain.replace(albedo=albedo), pose,
                                      shadows=False)

"Povray ... render[s] a shadow map of the terrain, which is then combined
with the terrain's original colour texture image. Dspace uses this augmented
texture to render the terrain" (section 3.5). Every texel centre is asked
(top_down_codes); texels in a cast shadow are multiplied by shadow_factor
(None: ambient / (ambient + sin(elevation)), as osmesa_terrain's default).
Facing away from the sun is left to the renderer's lighting. The sample
points are (xmin + (ti + 1/2 + nudge[0]) dx, ymin + (tj + 1/2 + nudge[1]) dy),
off the texel centres: at the centres themselves many lie exactly on cell
diagonals, where POV-Ray's shadow rays misbehave (see the module docstring).
'''
    if shadow_factor is None:
        s = math.sin(math.radians(terrain.sun.elevation_deg))
        shadow_factor = terrain.ambient / (terrain.ambient + s)
    if not (0.0 <= shadow_factor <= 1.0):
        raise RendererError(f"shadow_factor must be in [0,1]; got {shadow_factor!r}")
    xmin, xmax, ymin, ymax = terrain.extent()
    ty, tx = terrain.albedo.shape
    dx, dy = (xmax - xmin) / tx, (ymax - ymin) / ty
    first = (xmin + (0.5 + nudge[0]) * dx, ymin + (0.5 + nudge[1]) * dy)
    code = top_down_codes(terrain, first, (dx, dy), (tx, ty), binary, threads)
    albedo = np.where(code == 2, shadow_factor, 1.0) * terrain.albedo
    return albedo.astype(np.float32), code


def scene_text(terrain, M, t, camera, png_name, exposure=1.0, sky=0.0, shadows=True):
    r'''The POV-Ray scene of a terrain placed by p_pov = M p_terrain + t, with `camera` (text)'''
    from io import StringIO

    s = StringIO()
    s.write("#version 3.7;\n"
            "global_settings { assumed_gamma 1.0 ambient_light rgb 1 max_trace_level 5 }\n"
            f"background {{ rgb {_fmt(sky)} }}\n")
    s.write(camera)
    s.write(_sun_light(terrain, M, t, exposure, shadowless=not shadows))
    write_mesh2(s, terrain)
    mat = ",".join(_fmt(v) for v in (*M[:, 0], *M[:, 1], *M[:, 2], *t))
    s.write(f"object {{ CamvalTerrain {_albedo_pigment(terrain, png_name)} "
            f"finish {{ ambient {_fmt(exposure * terrain.ambient)} diffuse 1 specular 0 phong 0 "
            f"reflection 0 }} matrix <{mat}> }}\n")
    return s.getvalue()


def code_scene_text(terrain, M, t, camera):
    r'''The scene whose colours tell the shadow code: red from a sun casting shadows,
green from a shadowless sun (facing the sun), blue from ambient (terrain, not sky);
both suns so bright that any light saturates'''
    from io import StringIO

    s = StringIO()
    s.write("#version 3.7;\n"
            "global_settings { assumed_gamma 1.0 ambient_light rgb 1 max_trace_level 5 }\n"
            "background { rgb 0 }\n")
    s.write(camera)
    s.write(_sun_light(terrain, M, t, 1.0).replace("color rgb 1", "color rgb <1e9,0,0>"))
    s.write(_sun_light(terrain, M, t, 1.0, shadowless=True).replace("color rgb 1",
                                                                    "color rgb <0,1e9,0>"))
    write_mesh2(s, terrain)
    mat = ",".join(_fmt(v) for v in (*M[:, 0], *M[:, 1], *M[:, 2], *t))
    s.write("object { CamvalTerrain pigment { rgb 1 } finish { ambient rgb <0,0,1> diffuse 1 "
            f"specular 0 phong 0 reflection 0 }} matrix <{mat}> }}\n")
    return s.getvalue()


def _Rt_cam_terrain(model, Rt_ref_terrain):
    import mrcal

    Rt = np.vstack((np.eye(3), np.zeros(3))) if Rt_ref_terrain is None else \
        np.asarray(Rt_ref_terrain, np.float64)
    if Rt.shape != (4, 3) or not np.all(np.isfinite(Rt)):
        raise RendererError(f"Rt_ref_terrain must be a finite (4,3) array; got shape {Rt.shape}")
    return mrcal.compose_Rt(mrcal.invert_Rt(model.Rt_ref_cam()), Rt)


MAX_MESH_RAYS = 4_500_000
_ROW_OFFSETS = {}


def mesh_camera_triangles(origin, v):
    r'''Triangles (N,3,3) whose centroids are origin (N,3) and whose POV-Ray normals are v

POV-Ray's mesh_camera (distribution 0) shoots one ray per face from its
centroid along its normal, normalise((P3-P1) x (P2-P1)); unit-size triangles
written at full precision keep that normal exact (renderers/povray.py).
'''
    v = v / np.linalg.norm(v, axis=-1, keepdims=True)
    helper = np.where(np.abs(v[:, 0:1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    a = np.cross(v, helper)
    a /= np.linalg.norm(a, axis=-1, keepdims=True)
    b = np.cross(v, a)
    c, s = -0.5, math.sqrt(3.0) / 2.0
    p1, p2, p3 = a, c * a + s * b, c * a - s * b
    flip = (np.cross(p3 - p1, p2 - p1) * v).sum(-1) < 0
    p2[flip], p3[flip] = p3[flip].copy(), p2[flip].copy()
    return origin[:, None, :] + np.stack((p1, p2, p3), axis=1)


def _write_faces_mesh2(f, P, name):
    N = len(P)
    f.write(f"#declare {name} = mesh2 {{\nvertex_vectors {{ {3 * N},\n")
    flat = P.reshape(-1, 3).tolist()
    chunk = 65536
    for k in range(0, len(flat), chunk):
        f.write("".join(f"<{a:.17g},{b:.17g},{c:.17g}>\n" for a, b, c in flat[k:k + chunk]))
    f.write(f"}}\nface_indices {{ {N},\n")
    for k in range(0, N, chunk):
        f.write("".join(f"<{3 * i},{3 * i + 1},{3 * i + 2}>\n"
                        for i in range(k, min(N, k + chunk))))
    f.write("}\n}\n")


def write_camera_rays(model, K, path):
    r'''Write the mesh_camera mesh `CamvalRays`: one face per sub-pixel ray of model

Sub-pixel (a, b) of the K-times finer image is the model point
((a + 1/2)/K - 1/2, (b + 1/2)/K - 1/2); its exact ray (model.unproject, in
the camera frame with y negated, as the scene) becomes face b W K + a.
'''
    W, H = model.width, model.height
    u = (np.arange(W * K) + 0.5) / K - 0.5
    w = (np.arange(H * K) + 0.5) / K - 0.5
    q = np.stack(np.meshgrid(u, w), axis=-1).reshape(-1, 2)
    Rt = model.Rt_ref_cam()
    origin, v = model.unproject(q)
    o_cam = (origin - Rt[3]) @ Rt[:3]
    v_cam = v @ Rt[:3]
    if not np.all(np.isfinite(v_cam)):
        raise RendererError(f"{model.family} model: some pixels have no ray; cannot build a "
                            "mesh camera")
    F = np.array([1.0, -1.0, 1.0])
    with open(path, "w") as f:
        _write_faces_mesh2(f, mesh_camera_triangles(o_cam * F, v_cam * F), "CamvalRays")


def mesh_row_offset(bin_path):
    r'''Which face row POV-Ray's mesh_camera traces for image row j: j - offset

Probed once per binary with a 2x4 image whose faces of row 0 look at a white
box (POV-Ray 3.7.0.10: 1, the "one-row offset" of FINDINGS.md).
'''
    off = _ROW_OFFSETS.get(bin_path)
    if off is not None:
        return off
    W, H = 2, 4
    v = np.tile([0.0, 0.0, -1.0], (W * H, 1))
    v[:W] = (0.0, 0.0, 1.0)
    from io import StringIO
    s = StringIO()
    s.write("#version 3.7;\nglobal_settings { assumed_gamma 1.0 }\nbackground { rgb 0 }\n")
    _write_faces_mesh2(s, mesh_camera_triangles(np.zeros_like(v), v), "CamvalRays")
    s.write("camera { mesh_camera { 1 0 mesh { CamvalRays } } location <0,0,0> "
            "direction <0,0,1> }\n"
            "box { <-1,-1,1>, <1,1,2> pigment { rgb 1 } finish { ambient 1 diffuse 0 } }\n")
    workdir = tempfile.mkdtemp(prefix="camval-povray-probe-")
    try:
        img, _ = _run(bin_path, workdir, s.getvalue(), W, H + 2, 1, None)
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    white = np.nonzero(img.min(axis=1) > 0.5)[0].tolist()
    if not white or white[-1] > 2 or white != list(range(white[0], white[-1] + 1)):
        raise RendererError(f"povray mesh_camera probe: face row 0 shows in image rows {white}; "
                            "this POV-Ray maps mesh faces to pixels in an unknown way")
    off = _ROW_OFFSETS[bin_path] = white[-1]
    return off


def _codes_from_rgb(c):
    return np.where(c[..., 2] < 0.5, 255, np.where(
        c[..., 1] < 0.5, 1, np.where(c[..., 0] < 0.5, 2, 0))).astype(np.uint8)


def render_terrain(model, terrain, Rt_ref_terrain=None, spp=1, shadows=True, exposure=1.0,
                   sky=0.0, camera="perspective", interpolation="bilinear", warp_scale=1.0,
                   binary="povray", threads=None, keep_dir=None, shadow_codes=False,
                   max_mesh_rays=None):
    r'''Render a terrain through a camera model with POV-Ray

SYNOPSIS

    r = render_terrain(model, terrain, Rt_ref_terrain, spp=1, shadows=True)
    # r.image (H,W) float32 in [0,1]; r.range is None
    r = render_terrain(model, terrain, Rt_ref_terrain, shadow_codes=True)
    # r.shadow (H,W) uint8 as raycast_terrain's: 0 lit, 1 facing away, 2 cast, 255 sky
    r = render_terrain(fisheye, terrain, Rt_ref_terrain, camera="mesh")

Arguments as renderers.raycast_terrain.render_terrain, plus:

- camera: "perspective" (the paper's path: oversized pinhole, then the warp with
  `interpolation` and `warp_scale`; spp = K is POV-Ray's non-adaptive
  anti-aliasing n x n, n <= 9, on a b times finer image, K = n b, as
  renderers/povray.py) or "mesh" (POV-Ray's mesh_camera with one exact ray
  per sub-pixel from model.unproject, built by renderers.povray.PovrayRenderer:
  any field of view, noncentral CAHVORE exact; K x K sub-pixels averaged;
  at most max_mesh_rays rays, ~250 bytes of scene file each)
- shadow_codes: render once more with code_scene_text (one ray per pixel)
  for POV-Ray's per-pixel verdict: with "perspective" at the pinhole pixel
  nearest each model pixel's ray, with "mesh" along the pixel-centre ray;
  otherwise r.shadow is None
- binary, threads, keep_dir (keep the scene files there)
'''
    from renderers.povray import perspective_camera, split_supersampling
    from renderers.warp import PinholeWarp, box_downsample

    if isinstance(spp, bool) or not isinstance(spp, int) or spp < 1:
        raise RendererError(f"supersampling K must be a positive integer; got {spp!r}")
    if camera not in ("perspective", "mesh"):
        raise RendererError(f"povray_terrain camera {camera!r} is unknown; "
                            "known: perspective, mesh")
    bin_path = find_povray(binary)
    t0 = time.perf_counter()
    Rt = _Rt_cam_terrain(model, Rt_ref_terrain)
    F = np.diag([1.0, -1.0, 1.0])          # POV-Ray's y is up: the camera frame with y negated
    M, t = F @ Rt[:3], F @ Rt[3]
    workdir = keep_dir or tempfile.mkdtemp(prefix="camval-povray-terrain-")
    os.makedirs(workdir, exist_ok=True)
    shadow = None
    meta = {}
    try:
        write_albedo_png(terrain, os.path.join(workdir, "albedo.png"))
        if camera == "perspective":
            warp = PinholeWarp.for_model(model, scale=float(warp_scale))
            n, b = split_supersampling(spp)
            fine = warp.pinhole.scaled(b)
            scene = scene_text(terrain, M, t, perspective_camera(fine), "albedo.png",
                               exposure=exposure, sky=sky, shadows=shadows)
            img, pov_seconds = _run(bin_path, workdir, scene, fine.width, fine.height, n,
                                    threads)
            image = warp.apply(box_downsample(img, b), interpolation)
            if shadow_codes:
                import cv2
                c, s2 = _run(bin_path, workdir,
                             code_scene_text(terrain, M, t, perspective_camera(warp.pinhole)),
                             warp.pinhole.width, warp.pinhole.height, 1, threads, rgb=True)
                pov_seconds += s2
                map_x, map_y = warp.map()
                shadow = cv2.remap(_codes_from_rgb(c), map_x, map_y, cv2.INTER_NEAREST,
                                   borderMode=cv2.BORDER_CONSTANT, borderValue=255)
            meta = {"pinhole": warp.pinhole.as_dict(), "interpolation": interpolation,
                    "aa_depth": n, "finer": b}
        else:
            W, H = model.width, model.height
            limit = MAX_MESH_RAYS if max_mesh_rays is None else int(max_mesh_rays)
            if W * H * spp * spp > limit:
                raise RendererError(
                    f"povray_terrain mesh camera: {W}x{H} px at K={spp} needs "
                    f"{W * H * spp * spp} rays (~250 bytes of scene file each); the limit is "
                    f"{limit} (max_mesh_rays)")
            off = mesh_row_offset(bin_path)
            mesh_cam = ('#include "rays.inc"\ncamera { mesh_camera { 1 0 mesh { CamvalRays } } '
                        "location <0,0,0> direction <0,0,1> }\n")
            rays = os.path.join(workdir, "rays.inc")
            write_camera_rays(model, spp, rays)
            scene = scene_text(terrain, M, t, mesh_cam, "albedo.png", exposure=exposure,
                               sky=sky, shadows=shadows)
            # POV-Ray 3.7.0 shows face row j - off in image row j: render off more rows
            img, pov_seconds = _run(bin_path, workdir, scene, W * spp, H * spp + off, 1,
                                    threads)
            image = box_downsample(img[off:], spp)
            if shadow_codes:
                write_camera_rays(model, 1, rays)
                c, s2 = _run(bin_path, workdir, code_scene_text(terrain, M, t, mesh_cam),
                             W, H + off, 1, threads, rgb=True)
                pov_seconds += s2
                shadow = _codes_from_rgb(c[off:])
            meta = {"mesh_row_offset": off}
    finally:
        if not keep_dir:
            shutil.rmtree(workdir, ignore_errors=True)
    t1 = time.perf_counter()
    return TerrainRender(
        image=np.clip(image, 0.0, 1.0).astype(np.float32), range=None, shadow=shadow,
        metadata={"renderer": NAME, "version": povray_version(binary), "camera": camera,
                  "spp": spp, "shadows": bool(shadows), "exposure": exposure,
                  "seconds": t1 - t0, "povray_seconds": pov_seconds, **meta,
                  "surface": "triangle pair per cell (mesh2)", "terrain": terrain.as_dict()})


class PovrayTerrainRenderer:
    r'''POV-Ray as a renderer of terrain scenes (renderers.base.TerrainRenderer)

SYNOPSIS

    r = PovrayTerrainRenderer(camera="perspective", binary="povray")
    result = r.render_terrain(model, terrain, Rt_ref_terrain, RenderSettings(spp=2))
    code = r.cell_shadows(terrain)

ARGUMENTS (defaults for every render; RenderSettings.options override them):
render_terrain's shadows, exposure, sky, camera, interpolation, warp_scale,
threads, keep_dir, shadow_codes and max_mesh_rays; binary, the POV-Ray
executable, is checked here (RendererUnavailableError with the fix).
settings.spp is K (settings None: K = 1); RenderSettings.adaptive does not
apply.
'''

    name = NAME
    scenes = ("terrain",)

    def __init__(self, shadows=True, exposure=1.0, sky=0.0, camera="perspective",
                 interpolation="bilinear", warp_scale=1.0, binary="povray", threads=None,
                 keep_dir=None, shadow_codes=False, max_mesh_rays=None):
        find_povray(binary)
        self.binary = binary
        self.defaults = dict(shadows=shadows, exposure=exposure, sky=sky, camera=camera,
                             interpolation=interpolation, warp_scale=warp_scale,
                             threads=threads, keep_dir=keep_dir, shadow_codes=shadow_codes,
                             max_mesh_rays=max_mesh_rays)

    def version(self):
        return povray_version(self.binary)

    def render_terrain(self, model, terrain, Rt_ref_terrain=None, settings=None):
        settings = settings or RenderSettings(spp=1)
        return render_terrain(model, terrain, Rt_ref_terrain, spp=settings.spp,
                              binary=self.binary,
                              **merged_options(self.name, self.defaults, settings))

    def cell_shadows(self, terrain):
        return cell_shadows(terrain, binary=self.binary, threads=self.defaults["threads"],
                            keep_dir=self.defaults["keep_dir"])
