r'''The command renderer's "pinhole" and "rays" request modes (see renderers.command)

SYNOPSIS

    r = get_renderer("command", command=[...], mode="pinhole")   # or mode="rays"
    result = r.render(model, pattern, Rt_cam_board, RenderSettings(spp=16))

pinhole: camval chooses an ideal pinhole covering the model's field of view
(renderers.warp.PinholeWarp: at least as fine as the model everywhere, times
setup pinhole_scale, default 2), asks the program for its image (K x K
supersampled, request "pinhole" = {fx, fy, cx, cy, width, height}), and warps
it to the model with the area-sampled warp (pinhole_samples x pinhole_samples
remaps per model pixel; default "auto": area_samples(), samples about one
pinhole pixel apart where a model pixel covers the most; pinhole_interpolation,
default bilinear).
The warp's own share of the error is measured on every image (setup
pinhole_measure_warp, default true): the ray caster renders the same pinhole
and the model exactly, in this process, and metadata warp_rms / warp_max are
the RMS and largest difference (image values in [0,1]) between the warped
exact pinhole and the exact model image. A camera the warp cannot cover (field
of view >= 180 deg) is not-applicable.

rays: camval writes the camera-frame ray of every sample of the request's
pixels (K x K per pixel, at (ix + (i+0.5)/K - 0.5, iy + (j+0.5)/K - 0.5),
i, j = 0..K-1, as the ray caster samples) and the program returns the value
each ray sees, or the pixel averages. Directions: float32 (N, 3), unit;
origins: one [0, 0, 0] (a central camera: the rays start at C, the origin of
the camera frame) or float32 (N, 3) (noncentral CAHVORE: the entrance pupil
moves along O). Order: row iy, column ix, sub-row j, sub-column i (i
fastest). An image of more than protocol.MAX_RAYS_PER_REQUEST rays is asked
for in bands of whole rows, one request per band.
'''

import math
import os

import numpy as np

from .base import RendererError, RendererNotApplicable
from .protocol import (
    MAX_RAYS_PER_REQUEST,
    TERRAIN_OUTPUTS,
    check_values,
    is_terrain,
    load_output,
    read_image,
    read_terrain_output,
    terrain_lighting,
    write_request,
)

PINHOLE_DEFAULTS = {"pinhole_scale": 2.0, "pinhole_samples": "auto",
                    "pinhole_interpolation": "bilinear", "pinhole_measure_warp": True}
MAX_WARP_SAMPLES = 8     # renderers.warp.PinholeWarp's limit
RAYS_ORDER = ("row iy, column ix, sub-row j, sub-column i (i fastest); sample (i, j) of "
              "pixel (ix, iy) at q = (ix + (i+0.5)/K - 0.5, iy + (j+0.5)/K - 0.5)")


def render(renderer, mode, setup, model, scene, Rt_cam_board, settings):
    r'''-> (image (height, width) float64, kept request dir or None, metadata extras,
terrain outputs {"range", "shadow": (height, width)} (those the program gave; {} for a
board))

scene: a board pattern (Rt_cam_board) or a targets.terrain.Terrain (then
Rt_cam_board is Rt_ref_terrain, as protocol.write_request).'''
    if mode == "pinhole":
        return _pinhole(renderer, setup, model, scene, Rt_cam_board, settings)
    if mode == "rays":
        return _rays(renderer, setup, model, scene, Rt_cam_board, settings)
    raise RendererError(f"command renderer: mode {mode!r} is unknown")


# --- pinhole -----------------------------------------------------------------------------
def _pinhole_options(setup):
    o = {k: setup.get(k, v) for k, v in PINHOLE_DEFAULTS.items()}
    return o


def _pinhole(renderer, setup, model, scene, Rt_cam_board, settings):
    from .warp import PinholeWarp

    terrain = is_terrain(scene)
    if terrain and not model.is_central:
        raise RendererNotApplicable(
            "command renderer, pinhole mode: a noncentral camera (CAHVORE with E != 0) is "
            "warped from a pinhole exactly only for a known depth per pixel (a board's "
            "plane); a terrain has none: use mode \"image\" or \"rays\"")
    o = _pinhole_options(setup)
    scale = float(o["pinhole_scale"])
    samples = o["pinhole_samples"]
    if samples == "auto":
        samples = area_samples(PinholeWarp.for_model(model, scale=scale, samples=1))
    elif isinstance(samples, bool) or not isinstance(samples, int):
        raise RendererError(f"command renderer: pinhole_samples {samples!r}; expected "
                            f"\"auto\" or an integer in [1, {MAX_WARP_SAMPLES}]")
    warp = PinholeWarp.for_model(model, scale=scale, samples=samples)
    pin = warp.pinhole
    extra = {"pinhole": {k: float(v) if k in ("fx", "fy", "cx", "cy") else int(v)
                         for k, v in pin.as_dict().items()}}
    fmt = setup.get("output_format", "png16")
    from .protocol import OUTPUT_FORMATS
    img_pin, workdir = renderer._exchange(
        setup,
        lambda d: write_request(d, model, scene, Rt_cam_board, settings, fmt, mode="pinhole",
                                extra=extra),
        lambda d: read_image(os.path.join(d, OUTPUT_FORMATS[fmt]), pin.width, pin.height))
    interp = o["pinhole_interpolation"]
    image = warp.apply(img_pin, interpolation=interp,
                       Rt_cam_board=None if terrain else Rt_cam_board)
    meta = {"warp": {"pinhole": extra["pinhole"], "scale": scale, "samples": samples,
                     "interpolation": interp}}
    if o["pinhole_measure_warp"]:
        rms, mx = warp_share(warp, model, scene, Rt_cam_board, settings, interp)
        meta.update(warp_rms=rms, warp_max=mx)
    return image.astype(np.float64), workdir, meta, {}


def area_samples(warp):
    r'''The warp samples per model pixel side: the largest stretch of the warp's map (pinhole
px per model px, over the image) rounded to the nearest integer, at least 1, at most 8

A model pixel covers up to that many pinhole pixels along its widest
direction (the Jacobian's larger singular value; a fisheye's edge pixels
cover several times more than its centre's). Samples one pinhole pixel
apart integrate that footprint with bilinear weights that add up alike for
every pinhole pixel under it; fewer skip pinhole pixels (aliasing: fisheye
17 CAHVORE at K=16, 2x pinhole, 2x2 samples, residual RMS 0.0067 px), and
samples 2/3 px apart (rounding a stretch of 2.001 up to 3) weight the pinhole
pixels unevenly (camera 17 CAHV: residual RMS 0.0035 px with 3x3 against
0.0010 px with 2x2). Where the stretch varies (a fisheye), the centre is
sampled more finely than one pinhole pixel, which is harmless. The
finite-difference Jacobian is of the warp's own map (pixel centres, no pose).'''
    mx, my = warp.map()
    mx = mx.astype(np.float64)
    my = my.astype(np.float64)
    a, b = np.gradient(mx, axis=1), np.gradient(mx, axis=0)
    c, d = np.gradient(my, axis=1), np.gradient(my, axis=0)
    s1 = a * a + b * b + c * c + d * d
    det = np.abs(a * d - b * c)
    smax = np.sqrt(0.5 * (s1 + np.sqrt(np.maximum(s1 * s1 - 4 * det * det, 0.0))))
    return int(min(MAX_WARP_SAMPLES, max(1, math.floor(float(np.max(smax)) + 0.5))))


def warp_share(warp, model, scene, Rt_cam_board, settings, interpolation="bilinear"):
    r'''The warp's own error on one image: (RMS, max) of warp(exact pinhole) - exact model
image, both ray cast here at the request's K (image values in [0,1]; a terrain by
renderers.raycast_terrain with the request's lighting, Rt_cam_board = Rt_ref_terrain)'''
    from dataclasses import replace

    pin = warp.pinhole
    if is_terrain(scene):
        from reference_models.poseutils import compose_Rt, invert_Rt

        from .raycast_terrain import render_terrain
        light = terrain_lighting(settings.options)
        # the pinhole's frame is the model's camera frame
        Rt_cam_terrain = compose_Rt(invert_Rt(model.Rt_ref_cam()), Rt_cam_board)
        exact_pin = render_terrain(pinhole_cahv(pin), scene, Rt_cam_terrain, spp=settings.spp,
                                   **light).image
        warped = warp.apply(exact_pin, interpolation=interpolation)
        exact = render_terrain(model, scene, Rt_cam_board, spp=settings.spp, **light).image
        d = warped.astype(np.float64) - exact.astype(np.float64)
        return float(np.sqrt(np.mean(d * d))), float(np.max(np.abs(d)))
    from .raycast import RaycastRenderer

    rc = RaycastRenderer()
    s = replace(settings, options={})
    exact_pin = rc.render(pinhole_cahv(pin), scene, Rt_cam_board, s).image
    warped = warp.apply(exact_pin, interpolation=interpolation, Rt_cam_board=Rt_cam_board)
    exact = rc.render(model, scene, Rt_cam_board, s).image
    d = warped.astype(np.float64) - exact.astype(np.float64)
    return float(np.sqrt(np.mean(d * d))), float(np.max(np.abs(d)))


def pinhole_cahv(pin):
    r'''A renderers.warp.Pinhole as a CAHV in its camera frame (C = 0, A = z, x = H', y = A x H')'''
    from reference_models.cahvore import CAHV
    A = np.array([0.0, 0.0, 1.0])
    return CAHV(C=np.zeros(3), A=A, H=pin.fx * np.array([1.0, 0.0, 0.0]) + pin.cx * A,
                V=pin.fy * np.array([0.0, 1.0, 0.0]) + pin.cy * A,
                width=int(pin.width), height=int(pin.height))


# --- rays --------------------------------------------------------------------------------
def sample_rays(model, K, y0, y1):
    r'''Camera-frame rays of the K x K samples of the pixels of rows [y0, y1)

RETURNED VALUE

(origins, directions): float64 (N, 3), N = (y1 - y0) * width * K * K, in the
order of RAYS_ORDER; origins (1, 3) zeros for a central model.
'''
    from reference_models import kernels as kern

    W = model.width
    d = (np.arange(K) + 0.5) / K - 0.5
    q = np.empty((y1 - y0, W, K, K, 2))
    q[..., 0] = np.arange(W)[None, :, None, None] + d[None, None, None, :]
    q[..., 1] = np.arange(y0, y1)[:, None, None, None] + d[None, None, :, None]
    # the ray caster's compiled unprojection (the rays it traces; model.unproject's
    # equations, numba-parallel)
    origin, v = kern.unproject_grid(kern.pack_model(model), q.reshape(-1, 2))
    del q
    Rt = model.Rt_ref_cam()
    R, C = Rt[:3], Rt[3]
    v_cam = v @ R
    if model.is_central:
        return np.zeros((1, 3)), v_cam
    return (origin - C) @ R, v_cam


def bands(model, K, max_rays=MAX_RAYS_PER_REQUEST):
    r'''[(y0, y1), ...]: row bands of at most max_rays rays (at least one row each)'''
    rows = max(1, int(max_rays // (model.width * K * K)))
    return [(y0, min(y0 + rows, model.height)) for y0 in range(0, model.height, rows)]


def _rays(renderer, setup, model, scene, Rt_cam_board, settings):
    K = settings.spp
    W = model.width
    image = np.empty((model.height, W), dtype=np.float64)
    terrain = is_terrain(scene)
    # terrain: the program's per-ray range and shadow codes, kept at each pixel's centre
    # sample (sample (K//2, K//2) is the pixel centre when K is odd; there is none when
    # K is even)
    centre = (K // 2) * K + K // 2 if terrain and K % 2 == 1 else None
    outputs = {}
    workdir = None
    parts = bands(model, K, int(setup.get("max_rays") or MAX_RAYS_PER_REQUEST))
    for y0, y1 in parts:
        origins, dirs = sample_rays(model, K, y0, y1)
        n = len(dirs)

        def write(d, origins=origins, dirs=dirs, y0=y0, y1=y1, n=n):
            np.save(os.path.join(d, "rays-directions.npy"), dirs.astype(np.float32))
            rays = {"directions": "rays-directions.npy", "count": n, "rows": [y0, y1],
                    "samples_per_pixel": K * K, "frame": "camera", "order": RAYS_ORDER,
                    "dtype": "float32"}
            if len(origins) == 1:
                rays.update(origins=None, origin=[0.0, 0.0, 0.0])
            else:
                np.save(os.path.join(d, "rays-origins.npy"), origins.astype(np.float32))
                rays.update(origins="rays-origins.npy", origin=None)
            return write_request(d, model, scene, Rt_cam_board, settings, mode="rays",
                                 extra={"rays": rays})

        def read(d, y0=y0, y1=y1, n=n):
            v = read_values(os.path.join(d, "values.npy"), n, y1 - y0, W, K)
            more = {}
            if centre is not None:
                for k, f in TERRAIN_OUTPUTS.items():
                    r = read_terrain_output(os.path.join(d, f), k, n)
                    if r is not None:
                        more[k] = r.reshape(y1 - y0, W, K * K)[..., centre]
            return v, more

        (image[y0:y1], more), wd = renderer._exchange(setup, write, read)
        for k, v in more.items():
            if k not in outputs:
                outputs[k] = [np.empty((model.height, W), dtype=v.dtype), 0]
            outputs[k][0][y0:y1] = v
            outputs[k][1] += 1
        workdir = workdir or wd
    # an output the program gave for some bands only is not an image of it
    outputs = {k: a for k, (a, n) in outputs.items() if n == len(parts)}
    return image, workdir, {"rays": {"bands": len(parts), "dtype": "float32",
                                     "adaptive": False}}, outputs


def read_values(path, n, rows, W, K):
    r'''values.npy of a rays request -> pixel values (rows, W): per-ray values (N,) or
(rows*W, K*K) are averaged per pixel; pixel averages (rows, W) or (rows*W,) as they are'''
    if not os.path.exists(path):
        raise RendererError(f"the renderer wrote no values at '{path}'")
    v = load_output(path, "values")
    if v.dtype.kind != "f":
        raise RendererError(f"'{path}' holds {v.dtype} values; expected float32 in [0,1]")
    v = v.astype(np.float64)
    if v.size == n:
        out = v.reshape(rows, W, K * K).mean(axis=-1)
    elif v.size == rows * W:
        out = v.reshape(rows, W)
    else:
        raise RendererError(f"'{path}' has {v.size} values; expected one per ray ({n}) or "
                            f"one per pixel ({rows * W})")
    check_values(path, v)
    return out


# --- the shadow check through the protocol ------------------------------------------------
SHADOW_RAYS_ORDER = ("cell row j, cell column i, triangle k (k fastest; k = 0: the centroid "
                     "at (u, v) = (2/3, 1/3), k = 1: (1/3, 2/3))")


def shadow_camera(terrain):
    r'''The frame of the shadow check's rays request: a CAHV whose camera frame is the
terrain frame (C = 0, x = H' = x, y = A x H' = y, z = A = z), 2 (Nx-1) x (Ny-1) "pixels"
(one per triangle centroid)'''
    from reference_models.cahvore import CAHV
    ny, nx = terrain.heights.shape
    return CAHV(C=np.zeros(3), A=np.array([0.0, 0.0, 1.0]), H=np.array([1.0, 0.0, 0.0]),
                V=np.array([0.0, 1.0, 0.0]), width=2 * (nx - 1), height=ny - 1)


def shadow_rays(terrain):
    r'''The shadow check's rays: from 1 m above the highest node straight down onto every
triangle centroid (renderers.terrain_shadows.sample_points), terrain frame -> (origins
(N, 3), directions (1, 3)) float64, N = 2 (Ny-1)(Nx-1), order SHADOW_RAYS_ORDER'''
    from .terrain_shadows import sample_points
    x, y = sample_points(terrain)
    top = float(terrain.heights.max()) + 1.0
    origins = np.stack((x.ravel(), y.ravel(), np.full(x.size, top)), axis=-1)
    return origins, np.array([[0.0, 0.0, -1.0]])


def cell_shadows(renderer, setup, terrain):
    r'''The program's shadow codes at the triangle centroids (renderers.terrain_shadows)

One rays-mode request (whatever setup's mode) with the camera of shadow_camera,
the terrain at the identity pose, K = 1, the vertical rays of shadow_rays as
per-ray origins and directions, and the shadow output required; the program
returns a value per ray (not used) and shadow.npy, one code per ray. ->
(Ny-1, Nx-1, 2) uint8: 0 lit, 1 facing away, 2 cast. A ray that misses
(255) is a RendererError, as for the built-in renderers.'''
    from .base import RenderSettings

    ny, nx = terrain.heights.shape
    model = shadow_camera(terrain)
    origins, down = shadow_rays(terrain)
    n = len(origins)
    if n > MAX_RAYS_PER_REQUEST:
        raise RendererError(f"command renderer shadow check: {n} triangles; one request holds "
                            f"at most {MAX_RAYS_PER_REQUEST} rays")
    settings = RenderSettings(spp=1, adaptive=False)
    identity = np.vstack((np.eye(3), np.zeros(3)))

    def write(d):
        np.save(os.path.join(d, "rays-directions.npy"),
                np.repeat(down.astype(np.float32), n, axis=0))
        np.save(os.path.join(d, "rays-origins.npy"), origins.astype(np.float32))
        rays = {"directions": "rays-directions.npy", "origins": "rays-origins.npy",
                "origin": None, "count": n, "rows": [0, ny - 1], "samples_per_pixel": 1,
                "frame": "camera", "order": SHADOW_RAYS_ORDER, "dtype": "float32",
                "purpose": "shadow_check"}
        return write_request(d, model, terrain, identity, settings, mode="rays",
                             extra={"rays": rays, "shadow_required": True})

    def read(d):
        read_values(os.path.join(d, "values.npy"), n, ny - 1, 2 * (nx - 1), 1)
        return read_terrain_output(os.path.join(d, TERRAIN_OUTPUTS["shadow"]), "shadow", n,
                                   required=True)

    code, _ = renderer._exchange(dict(setup, mode="rays"), write, read)
    code = code.reshape(ny - 1, nx - 1, 2)
    if np.any(code == 255):
        raise RendererError(f"external renderer {setup['command'][0]!r}: the shadow check's "
                            f"vertical rays missed the terrain at {int(np.sum(code == 255))} "
                            "centroids (each lies on the surface)")
    return code
