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
depth); the raycast renderer is exact for those.

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
import subprocess
import tempfile
import time

import numpy as np

from renderers.base import RendererError, RendererUnavailableError
from renderers.raycast_terrain import TerrainRender
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
    r'''Run POV-Ray on `scene` (text) in workdir; the 16-bit linear image as float64 [0,1]
(its green channel, or (H,W,3) R, G, B with rgb=True)'''
    import cv2

    pov = os.path.join(workdir, "scene.pov")
    png = os.path.join(workdir, "image.png")
    with open(pov, "w") as f:
        f.write(scene)
    cmd = [binary, "-D", "-V", "-P", "+FN16", "File_Gamma=1.0", "Output_Alpha=off",
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
        raise RendererUnavailableError(f"cannot run {binary}: {e}; {INSTALL_HINT}") from e
    seconds = time.perf_counter() - t0
    if proc.returncode != 0 or not os.path.exists(png):
        tail = "\n".join((proc.stderr or proc.stdout).strip().splitlines()[-8:])
        raise RendererError(f"povray failed (exit {proc.returncode}) on {pov}: {tail}")
    img = cv2.imread(png, cv2.IMREAD_UNCHANGED)
    if img is None or img.shape[:2] != (height, width):
        raise RendererError(f"povray wrote an unreadable or mis-sized image {png}")
    if rgb:
        if img.ndim != 3:
            raise RendererError(f"povray wrote a grey image {png}; expected colour")
        img = img[..., 2::-1]           # OpenCV reads B, G, R
    elif img.ndim == 3:
        img = img[..., 1]
    scale = 65535.0 if img.dtype == np.uint16 else 255.0
    return img.astype(np.float64) / scale, seconds


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


def render_terrain(model, terrain, Rt_ref_terrain=None, spp=1, shadows=True, exposure=1.0,
                   sky=0.0, interpolation="bilinear", warp_scale=1.0, binary="povray",
                   threads=None, keep_dir=None, shadow_codes=False):
    r'''Render a terrain through a camera model with POV-Ray (pinhole, then the warp)

SYNOPSIS

    r = render_terrain(model, terrain, Rt_ref_terrain, spp=1, shadows=True)
    # r.image (H,W) float32 in [0,1]; r.range is None
    r = render_terrain(model, terrain, Rt_ref_terrain, shadow_codes=True)
    # r.shadow (H,W) uint8 as raycast_terrain's: 0 lit, 1 facing away, 2 cast, 255 sky

Arguments as renderers.raycast_terrain.render_terrain, plus the warp's
interpolation ("bilinear"/"bicubic") and warp_scale, the POV-Ray binary,
threads and keep_dir (keep the scene files there). spp = K: POV-Ray's
non-adaptive anti-aliasing (n x n, n <= 9) on a b times finer image, K = n b,
as renderers/povray.py. shadow_codes=True renders the pinhole once more
(code_scene_text: one ray per pixel) for POV-Ray's per-pixel verdict, taken
at the pinhole pixel nearest each model pixel's ray; otherwise r.shadow is None.
'''
    from renderers.povray import perspective_camera, split_supersampling
    from renderers.warp import PinholeWarp, box_downsample

    if isinstance(spp, bool) or not isinstance(spp, int) or spp < 1:
        raise RendererError(f"supersampling K must be a positive integer; got {spp!r}")
    bin_path = find_povray(binary)
    t0 = time.perf_counter()
    Rt = _Rt_cam_terrain(model, Rt_ref_terrain)
    F = np.diag([1.0, -1.0, 1.0])          # POV-Ray's y is up: the camera frame with y negated
    M, t = F @ Rt[:3], F @ Rt[3]
    warp = PinholeWarp.for_model(model, scale=float(warp_scale))
    n, b = split_supersampling(spp)
    fine = warp.pinhole.scaled(b)
    workdir = keep_dir or tempfile.mkdtemp(prefix="camval-povray-terrain-")
    os.makedirs(workdir, exist_ok=True)
    try:
        write_albedo_png(terrain, os.path.join(workdir, "albedo.png"))
        scene = scene_text(terrain, M, t, perspective_camera(fine), "albedo.png",
                           exposure=exposure, sky=sky, shadows=shadows)
        img, pov_seconds = _run(bin_path, workdir, scene, fine.width, fine.height, n, threads)
        shadow = None
        if shadow_codes:
            import cv2
            pin_cam = perspective_camera(warp.pinhole)
            c, s2 = _run(bin_path, workdir, code_scene_text(terrain, M, t, pin_cam),
                         warp.pinhole.width, warp.pinhole.height, 1, threads, rgb=True)
            pov_seconds += s2
            pin_code = np.where(c[..., 2] < 0.5, 255, np.where(
                c[..., 1] < 0.5, 1, np.where(c[..., 0] < 0.5, 2, 0))).astype(np.uint8)
            map_x, map_y = warp.map()
            shadow = cv2.remap(pin_code, map_x, map_y, cv2.INTER_NEAREST,
                               borderMode=cv2.BORDER_CONSTANT, borderValue=255)
    finally:
        if not keep_dir:
            shutil.rmtree(workdir, ignore_errors=True)
    pin = box_downsample(img, b)
    image = warp.apply(pin, interpolation)
    t1 = time.perf_counter()
    return TerrainRender(
        image=np.clip(image, 0.0, 1.0).astype(np.float32), range=None, shadow=shadow,
        metadata={"renderer": NAME, "version": povray_version(binary), "spp": spp,
                  "shadows": bool(shadows), "exposure": exposure, "seconds": t1 - t0,
                  "povray_seconds": pov_seconds, "pinhole": warp.pinhole.as_dict(),
                  "interpolation": interpolation, "aa_depth": n, "finer": b,
                  "surface": "triangle pair per cell (mesh2)", "terrain": terrain.as_dict()})
