'''Terrain height fields and the exact terrain ray caster (intersections and shadows)'''

import math

import cv2
import numpy as np
import pytest

from reference_models.cahvore import CAHV, CAHVOR
from renderers.raycast_terrain import build_pyramid, render_terrain, trace_rays
from targets.terrain import Sun, Terrain, TerrainError, ground_pose, make_terrain


def small_terrain(seed=0, **kw):
    return make_terrain(extent=(0, 3, -1.5, 1.5), cell=0.1, texel=0.02, seed=seed,
                        relief_m=0.1, relief_wavelength_m=1.0, rocks_per_m2=2.0,
                        rock_radius_m=(0.05, 0.25), **kw)


def test_generation_is_deterministic_for_a_seed():
    a, b, c = small_terrain(3), small_terrain(3), small_terrain(4)
    assert np.array_equal(a.heights, b.heights) and np.array_equal(a.albedo, b.albedo)
    assert not np.array_equal(a.heights, c.heights)
    assert a.heights.shape == (31, 31) and a.albedo.shape == (150, 150)
    assert 0 < a.albedo.min() and a.albedo.max() < 1
    # rocks are bumps with darker albedo: the texture is granular at the texel scale
    assert np.std(np.diff(a.albedo, axis=1)) > 0.01


def test_height_files_and_functions(tmp_path):
    z = (np.arange(12, dtype=np.uint16).reshape(3, 4) * 1000)
    cv2.imwrite(str(tmp_path / "h.png"), z)
    np.save(tmp_path / "h.npy", z.astype(np.float32))
    a = Terrain.from_file(tmp_path / "h.png", cell=0.5, height_scale=0.001, origin=(1, 2))
    b = Terrain.from_file(tmp_path / "h.npy", cell=0.5, height_scale=0.001, origin=(1, 2))
    assert np.array_equal(a.heights, z * 0.001) and np.array_equal(a.heights, b.heights)
    assert a.extent() == (1.0, 2.5, 2.0, 3.0)
    # node (i, j) at (x0 + i cell, y0 + j cell) has heights[j, i]
    assert a.height_at(1.5, 2.5) == pytest.approx(z[1, 1] * 0.001)
    f = Terrain.from_function(lambda x, y: 0.1 * x + 0.2 * y, (0, 2, 0, 1), 0.25)
    assert f.heights.shape == (5, 9)
    x, y = np.random.default_rng(0).uniform(0, 1, (2, 50))
    assert np.allclose(f.height_at(x, y), 0.1 * x + 0.2 * y)   # planes are exact
    assert np.isnan(f.height_at(3.0, 0.5))
    with pytest.raises(TerrainError, match="known: .npy, .png"):
        Terrain.from_file(_touch(tmp_path / "h.tif"), cell=1)
    with pytest.raises(TerrainError, match="Ny, Nx >= 2"):
        Terrain(heights=np.zeros((1, 5)), cell=1.0)


def _touch(p):
    p.write_bytes(b"x")
    return p


def test_pyramid_is_a_max_pyramid():
    h = np.random.default_rng(1).normal(size=(11, 14))
    flat, offs, nx, ny = build_pyramid(h)
    assert (nx[0], ny[0]) == (13, 10) and (nx[-1], ny[-1]) == (1, 1)
    assert flat[offs[-1]] == h.max()
    lvl1 = flat[offs[1]:offs[1] + nx[1] * ny[1]].reshape(ny[1], nx[1])
    assert lvl1[0, 0] == h[:3, :3].max()


def _march(terrain, o, d, step=2e-4, tmax=20.0):
    r'''First crossing of the ray below the surface, by small steps and bisection'''
    t = np.arange(0, tmax, step)
    p = o + t[:, None] * d
    gap = p[:, 2] - terrain.height_at(p[:, 0], p[:, 1])
    below = np.nonzero(gap <= 0)[0]
    if below.size == 0:
        return np.inf
    k = below[0]
    if k == 0:
        return 0.0
    a, b = t[k - 1], t[k]
    for _ in range(60):
        m = 0.5 * (a + b)
        q = o + m * d
        if q[2] - terrain.height_at(q[0], q[1]) > 0:
            a = m
        else:
            b = m
    return 0.5 * (a + b)


def test_intersection_agrees_with_brute_force_march():
    ter = small_terrain(7)
    rng = np.random.default_rng(2)
    n = 60
    o = np.column_stack((rng.uniform(-0.5, 0.5, n), rng.uniform(-1, 1, n),
                         rng.uniform(0.3, 1.0, n)))
    az = rng.uniform(-0.6, 0.6, n)
    el = rng.uniform(-0.6, -0.05, n)     # down, some of them grazing
    d = np.column_stack((np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)))
    _, t, code = trace_rays(ter, o, d, shadows=False)
    want = np.array([_march(ter, o[i], d[i]) for i in range(n)])
    hit = np.isfinite(want)
    assert hit.sum() > 30 and (~hit).sum() > 0        # hits and misses (off the grid)
    assert np.array_equal(np.isfinite(t), hit)
    assert np.max(np.abs(t[hit] - want[hit])) < 1e-6
    # the hit point is on the surface
    p = o[hit] + t[hit, None] * d[hit]
    assert np.max(np.abs(p[:, 2] - ter.height_at(p[:, 0], p[:, 1]))) < 1e-9
    assert np.all(code[~hit] == 255)


SUN_30 = Sun(azimuth_deg=0.0, elevation_deg=30.0)


def box_terrain(h=0.3, cell=0.05, sun=SUN_30):
    x = np.arange(0, 4 + 1e-9, cell)
    y = np.arange(-1, 1 + 1e-9, cell)
    z = np.zeros((y.size, x.size))
    box_x = (x >= 2.0 - 1e-9) & (x <= 2.5 + 1e-9)
    box_y = np.abs(y) <= 0.5 + 1e-9
    z[np.ix_(box_y, box_x)] = h
    return Terrain(heights=z, cell=cell, origin=(0.0, -1.0), sun=sun, ambient=0.0)


@pytest.mark.parametrize("elevation", [20.0, 30.0, 45.0])
def test_box_shadow_length(elevation):
    h, cell = 0.3, 0.05
    ter = box_terrain(h, cell, Sun(azimuth_deg=0.0, elevation_deg=elevation))
    # look straight down at a line across the box, along the sun's azimuth
    xs = np.arange(0.005, 4.0, 0.002)
    o = np.column_stack((xs, np.zeros_like(xs), np.full_like(xs, 5.0)))
    d = np.array([0.0, 0.0, -1.0])
    value, t, code = trace_rays(ter, o, d)
    # the sun is towards +x: the box's top edge at x = 2 casts the shadow towards -x
    dark = (code != 0) & (xs < 2.0)
    x_start = xs[dark].min()
    assert 2.0 - x_start == pytest.approx(h / math.tan(math.radians(elevation)), abs=cell)
    # everything between the shadow's start and the box is dark, all else lit
    assert np.all(dark[(xs > x_start) & (xs < 2.0)])
    assert np.all(code[(xs > 2.0) & (xs < 2.5)] == 0) and np.all(code[xs > 2.55] == 0)
    # on the flat ground, lit points are albedo * sin(elevation)
    lit = (code == 0) & (xs < 1.0)
    assert np.allclose(value[lit], 0.5 * math.sin(math.radians(elevation)))
    # a point of the plane in the open is lit, its range is exact
    assert np.allclose(t[xs < 1.0], 5.0)


def test_shadow_from_oblique_camera_rays_matches_geometry():
    ter = box_terrain()
    # ground points seen obliquely: shadow status must equal the analytic one
    rng = np.random.default_rng(5)
    n = 400
    target = np.column_stack((rng.uniform(1.0, 1.94, n), rng.uniform(-0.4, 0.4, n), np.zeros(n)))
    o = np.array([0.5, 0.3, 1.5])
    d = target - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    _, t, code = trace_rays(ter, o, d)
    assert np.allclose(o + t[:, None] * d, target, atol=1e-9)
    # the edge at x=2 (height 0.3) shades x in (2 - 0.3/tan 30deg, 2); the ramp from the
    # node at x = 1.95 (0) to x = 2.0 (0.3) is what actually casts, so allow one cell
    x_edge = 2.0 - 0.3 / math.tan(math.radians(30))
    sure_dark = target[:, 0] > x_edge + 0.05
    sure_lit = target[:, 0] < x_edge - 0.05
    assert np.all(code[sure_dark] == 2) and np.all(code[sure_lit] == 0)


def forward_camera(pitch_deg, f, width, height, C=(0, 0, -1.0), R=None):
    r'''A camera in a z-down rover frame looking forward (+x), pitched down'''
    p = math.radians(pitch_deg)
    A = np.array([math.cos(p), 0, math.sin(p)])
    Hp = np.array([0.0, 1.0, 0.0])
    Vp = np.cross(A, Hp)
    H = f * Hp + (width - 1) / 2 * A
    V = f * Vp + (height - 1) / 2 * A
    if R is None:
        return CAHV(C=C, A=A, H=H, V=V, width=width, height=height)
    return CAHVOR(C=C, A=A, H=H, V=V, O=A, R=R, width=width, height=height)


def test_render_flat_plane_range_is_exact():
    m = forward_camera(17.0, 60.0, 100, 80, R=[0, -0.1, 0.01])
    texture = np.random.default_rng(3).uniform(0.1, 0.9, (200, 150)).astype(np.float32)
    ter = Terrain(heights=np.zeros((3, 3)), cell=20.0, origin=(-10, -20), albedo=texture,
                  sun=Sun(0, 50), ambient=0.2)
    r = render_terrain(m, ter, ground_pose(0.0), spp=1)
    from reference_models.conventions import pixel_centres
    o, v = m.unproject(pixel_centres(100, 80))
    # rover frame z down: the ground is z = 0, the camera 1 m above it
    with np.errstate(divide="ignore"):
        want = np.where(v[..., 2] > 0, -o[..., 2] / v[..., 2], np.nan)
    p = o + want[..., None] * v
    off = (p[..., 0] < -10) | (p[..., 0] > 30) | (np.abs(p[..., 1]) > 20)
    want[off | (v[..., 2] <= 0)] = np.nan
    assert np.array_equal(np.isnan(r.range), np.isnan(want))
    assert np.nanmax(np.abs(r.range - want)) < 1e-9
    assert np.all(r.shadow[np.isfinite(want)] == 0)
    # the texture is sampled where the ray meets the ground (terrain y = -rover y)
    hit = np.isfinite(want)
    albedo = ter.albedo_at(p[..., 0][hit], -p[..., 1][hit])
    lit = albedo * (0.2 + math.sin(math.radians(50)))
    assert np.allclose(r.image[hit], lit, atol=1e-6)
    assert np.all(r.image[np.isnan(want)] == 0)


def test_supersampling_averages_and_keeps_centre_range():
    m = forward_camera(25.0, 40.0, 60, 50)
    ter = small_terrain(1)
    r1 = render_terrain(m, ter, ground_pose(0.0), spp=1)
    r2 = render_terrain(m, ter, ground_pose(0.0), spp=2)
    r3 = render_terrain(m, ter, ground_pose(0.0), spp=3)
    assert np.array_equal(r1.range, r2.range, equal_nan=True)
    assert np.array_equal(r1.range, r3.range, equal_nan=True)
    assert np.array_equal(r1.shadow, r3.shadow)
    assert np.mean(np.abs(r2.image - r1.image)) < 0.05
    assert r2.metadata["rays"] == 4 * 60 * 50


def _brute_force_hits(terrain, o, d):
    r'''Nearest hit of each ray with every triangle of the grid (no acceleration)'''
    h = terrain.heights
    ny, nx = h.shape
    x0, y0 = terrain.origin
    c = terrain.cell
    j, i = np.meshgrid(np.arange(ny - 1), np.arange(nx - 1), indexing="ij")
    i, j = i.ravel(), j.ravel()
    h00, h10, h01, h11 = h[j, i], h[j, i + 1], h[j + 1, i], h[j + 1, i + 1]
    best = np.full(len(o), np.inf)
    u0 = (o[:, 0, None] - (x0 + i * c)) / c
    v0 = (o[:, 1, None] - (y0 + j * c)) / c
    du, dv = d[:, 0, None] / c, d[:, 1, None] / c
    for a, b, cc, lower in ((h00, h10 - h00, h11 - h10, True), (h00, h11 - h01, h01 - h00, False)):
        den = d[:, 2, None] - b * du - cc * dv
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (a + b * u0 + cc * v0 - o[:, 2, None]) / den
        u, v = u0 + t * du, v0 + t * dv
        e = 1e-9
        ok = (t >= 0) & (u >= -e) & (u <= 1 + e) & (v >= -e) & (v <= 1 + e)
        ok &= (u - v >= -e) if lower else (v - u >= -e)
        best = np.minimum(best, np.where(ok, t, np.inf).min(axis=1))
    return best


@pytest.mark.parametrize("shape", [(14, 11), (17, 33), (2, 2), (9, 2)])
def test_pyramid_walk_equals_brute_force(shape):
    # odd and tiny grids (padded pyramid levels), rays along grid lines and axes, rays
    # from outside the grid, from below and above, vertical rays, grazing rays
    rng = np.random.default_rng(shape[0] * 100 + shape[1])
    ny, nx = shape
    z = 0.3 * rng.normal(size=shape)
    z[rng.random(shape) < 0.2] += 0.8
    ter = Terrain(heights=z, cell=0.25, origin=(-1.0, 2.0), sun=Sun(30, 12))
    xmin, xmax, ymin, ymax = ter.extent()
    n = 3000
    o = np.column_stack((rng.uniform(xmin - 1, xmax + 1, n), rng.uniform(ymin - 1, ymax + 1, n),
                         rng.uniform(-0.5, 3.0, n)))
    target = np.column_stack((rng.uniform(xmin, xmax, n), rng.uniform(ymin, ymax, n),
                              rng.uniform(-1.0, 1.0, n)))
    d = target - o
    k = n // 6
    # along grid lines / axes: origins on nodes' lines, directions with zero x or y
    o[:k, 0] = xmin + ter.cell * rng.integers(0, nx, k)
    d[:k, 0] = 0.0
    o[k:2 * k, 1] = ymin + ter.cell * rng.integers(0, ny, k)
    d[k:2 * k, 1] = 0.0
    d[2 * k:2 * k + 50, :2] = 0.0                       # vertical
    d[3 * k:4 * k, 2] = rng.uniform(-0.05, 0.05, k)    # grazing
    _, t, code = trace_rays(ter, o, d, shadows=False)
    want = _brute_force_hits(ter, o, d)
    hit = np.isfinite(want)
    assert hit.sum() > n // 5 and (~hit).sum() > n // 10
    assert np.array_equal(np.isfinite(t), hit)
    assert np.max(np.abs(t[hit] - want[hit]) / np.linalg.norm(d[hit], axis=1)) < 1e-9
    # shadow rays: a point facing the sun is in a cast shadow exactly when the ray towards
    # the sun from the point lifted off its triangle (1e-7 cells along the normal, as the
    # renderer does) meets a triangle
    p = o[hit] + t[hit, None] * d[hit]
    _, _, code = trace_rays(ter, o[hit], d[hit])
    sun = ter.sun.direction()
    lifted = p + 1e-7 * ter.cell * _normals(ter, p)
    blocked = np.isfinite(_brute_force_hits(ter, lifted, np.broadcast_to(sun, p.shape)))
    facing = code != 1
    if min(shape) > 2:     # a one-cell-wide grid casts few shadows
        assert blocked[facing].sum() > 20 and (~blocked[facing]).sum() > 20
    assert np.array_equal(code[facing] == 2, blocked[facing])


def _normals(terrain, p):
    r'''Unit upward normals of the triangles under points p (N,3) of the surface'''
    h, c = terrain.heights, terrain.cell
    gx = (p[:, 0] - terrain.origin[0]) / c
    gy = (p[:, 1] - terrain.origin[1]) / c
    i = np.clip(np.floor(gx).astype(int), 0, h.shape[1] - 2)
    j = np.clip(np.floor(gy).astype(int), 0, h.shape[0] - 2)
    lower = gx - i >= gy - j
    b = np.where(lower, h[j, i + 1] - h[j, i], h[j + 1, i + 1] - h[j + 1, i]) / c
    cc = np.where(lower, h[j + 1, i + 1] - h[j, i + 1], h[j + 1, i] - h[j, i]) / c
    n = np.column_stack((-b, -cc, np.ones_like(b)))
    return n / np.linalg.norm(n, axis=1, keepdims=True)


@pytest.mark.parametrize("azimuth", [0.0, 30.0, 45.0, 90.0, 160.0, 200.0, 270.0, 315.0])
@pytest.mark.parametrize("columns", [48, 3])
def test_sun_bound_is_above_every_ray_towards_the_sun(azimuth, columns, monkeypatch):
    # the shadow walk stops once a ray is above its cell's bound V: every point of a cell
    # below which the surface rises into the ray must lie under V (also when the strip
    # is cut short after a few columns and the rest bounded by the highest node)
    from renderers import raycast_terrain
    from renderers.raycast_terrain import _cell_maxima, _sun_bound
    monkeypatch.setattr(raycast_terrain, "SUN_BOUND_COLUMNS", columns)
    ter = small_terrain(11, sun=Sun(azimuth_deg=azimuth, elevation_deg=8.0))
    mmax = _cell_maxima(ter.heights)
    s = ter.sun.direction()
    hz = math.hypot(s[0], s[1])
    V = _sun_bound(mmax, s[0] / hz, s[1] / hz, s[2] / hz * ter.cell, ter.heights.max())
    assert V.shape == mmax.shape and np.all(V >= mmax)
    rng = np.random.default_rng(int(azimuth))
    ny, nx = mmax.shape
    j, i = np.meshgrid(np.arange(ny), np.arange(nx), indexing="ij")
    # corners and random points of every cell
    for fu, fv in [(0, 0), (1, 0), (0, 1), (1, 1)] + [tuple(rng.random(2)) for _ in range(3)]:
        x = ter.origin[0] + (i + fu) * ter.cell
        y = ter.origin[1] + (j + fv) * ter.cell
        r = np.arange(0.0, 3.0, 0.002)[:, None, None]          # metres along the ground
        zs = ter.height_at(x + r * s[0] / hz, y + r * s[1] / hz) - r * s[2] / hz
        need = np.nanmax(zs, axis=0)                            # height to clear the surface
        assert np.all(need <= V + 1e-9)
    # and, with the whole strip examined, far below the trivial bound (the highest node)
    if columns > 40:
        assert np.median(V - mmax) < 0.3 * (ter.heights.max() - np.median(mmax))


def test_hits_do_not_depend_on_the_order_of_rays():
    # a ray starts its walk where the previous ray of its run first passed a cell; any
    # start level must give the same hit, so shuffling the rays changes nothing
    m = forward_camera(20.0, 50.0, 80, 60)
    ter = small_terrain(5, sun=Sun(azimuth_deg=200.0, elevation_deg=15.0))
    from renderers.raycast_terrain import pixel_rays
    o, v = pixel_rays(m, 1)
    o, v = o.reshape(-1, 3), v.reshape(-1, 3)
    Rt = ground_pose(0.4)
    value, t, code = trace_rays(ter, o, v, Rt_ref_terrain=Rt)
    assert 0.3 < np.mean(np.isfinite(t)) < 1 and np.sum(code == 2) > 20
    perm = np.random.default_rng(0).permutation(len(o))
    value2, t2, code2 = trace_rays(ter, o[perm], v[perm], Rt_ref_terrain=Rt)
    assert np.array_equal(t2, t[perm], equal_nan=True)
    assert np.array_equal(code2, code[perm]) and np.array_equal(value2, value[perm])


def test_pixel_rays_are_cached_within_a_byte_budget(monkeypatch):
    from renderers import raycast_terrain
    from renderers.raycast_terrain import pixel_rays
    monkeypatch.setattr(raycast_terrain, "_RAY_CACHE", {})
    a, b = forward_camera(20.0, 50.0, 40, 30), forward_camera(25.0, 50.0, 40, 30)
    ra = pixel_rays(a, 2)
    assert pixel_rays(a, 2)[0] is ra[0]                 # computed once
    assert ra[0].shape == (1200, 4, 3) and np.allclose(np.linalg.norm(ra[1], axis=-1), 1)
    # a budget of one camera's rays: b's rays push a's out
    monkeypatch.setattr(raycast_terrain, "_RAY_CACHE_BYTES", ra[0].nbytes + ra[1].nbytes)
    pixel_rays(b, 2)
    assert len(raycast_terrain._RAY_CACHE) == 1 and pixel_rays(a, 2)[0] is not ra[0]


# ---------------------------------------------------------------------------
def test_the_registry_renders_terrain_as_the_module_does():
    from renderers.base import (
        RendererError,
        RenderSettings,
        TerrainRenderer,
        get_renderer,
        get_terrain_renderer,
        renderer_scenes,
    )
    from renderers.raycast_terrain import cell_shadows

    m = forward_camera(25.0, 40.0, 60, 50)
    ter = small_terrain(1)
    pose = ground_pose(0.0)
    r = get_terrain_renderer("raycast_terrain")
    assert isinstance(r, TerrainRenderer) and renderer_scenes("raycast_terrain") == ("terrain",)
    for settings, kw in ((RenderSettings(spp=2), {}),
                         (RenderSettings(spp=1, options={"shadows": False, "exposure": 0.7}),
                          {"shadows": False, "exposure": 0.7})):
        a = r.render_terrain(m, ter, pose, settings)
        b = render_terrain(m, ter, pose, spp=settings.spp, **kw)
        assert np.array_equal(a.image, b.image)
        assert np.array_equal(a.range, b.range, equal_nan=True)
        assert np.array_equal(a.shadow, b.shadow)
        assert a.metadata["renderer"] == "raycast_terrain"
    # settings None: K = 1, as the module's default
    assert np.array_equal(r.render_terrain(m, ter, pose).image, render_terrain(m, ter, pose).image)
    assert np.array_equal(r.cell_shadows(ter), cell_shadows(ter))
    with pytest.raises(RendererError, match="unknown option.*known: exposure, shadows, sky"):
        r.render_terrain(m, ter, pose, RenderSettings(spp=1, options={"sun": 3}))
    # a board renderer is not a terrain renderer, and the board path is unchanged
    with pytest.raises(RendererError, match="'raycast' does not render terrain scenes; terrain "
                                            "renderers: .*raycast_terrain"):
        get_terrain_renderer("raycast")
    assert renderer_scenes("raycast") == ("board",) and get_renderer("raycast").name == "raycast"
