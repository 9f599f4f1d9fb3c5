'''Terrain shadows three ways: exact shadow rays (raycast_terrain), POV-Ray's own
shadows (povray_terrain) and the paper's two-pass z-buffer (osmesa_terrain)

The methods are asked about the same points: the centroid of each triangle of
every cell, seen from straight above (renderers.terrain_shadows). Bounds are
the measured figures with about 2x headroom (measured values in comments).
'''

import math
import shutil

import numpy as np
import pytest

from reference_models.cahvore import CAHV
from renderers.base import RendererError, RendererUnavailableError
from renderers.raycast_terrain import cell_shadows as raycast_cell_shadows
from renderers.terrain_shadows import ShadowCompareError, compare, sample_points
from targets.terrain import Sun, Terrain, ground_pose, make_terrain

HAVE_POVRAY = shutil.which("povray") is not None


def _osmesa():
    try:
        from renderers import osmesa_terrain
        osmesa_terrain.gl_version()
    except RendererUnavailableError as e:
        pytest.skip(f"OSMesa is not available here: {e}")
    return osmesa_terrain


needs_povray = pytest.mark.skipif(not HAVE_POVRAY, reason="the povray binary is not installed")


def rough_terrain(elevation_deg, azimuth_deg=120.0):
    # 8 x 8 m, 10 cm cells (12800 triangles), relief and rocks up to 0.4 m
    return make_terrain(extent=(0, 8, 0, 8), cell=0.1, texel=0.05, seed=5, relief_m=0.3,
                        relief_wavelength_m=3.0, rocks_per_m2=1.5, rock_radius_m=(0.05, 0.4),
                        sun=Sun(azimuth_deg, elevation_deg))


def wall_terrain(elevation_deg=20.0, **kw):
    r'''Flat ground with a one-node ridge at x = 2 m whose shadow (sun from -x) ends
at x = 2.95 m: half way between the centroids at 2.9333 and 2.9667 m'''
    height = 0.95 * math.tan(math.radians(elevation_deg))
    return Terrain.from_function(lambda x, y: np.where(np.abs(x - 2.0) < 1e-6, height, 0.0) + 0 * y,
                                 (0, 6, 0, 3), 0.1, sun=Sun(180.0, elevation_deg), **kw)


def wall_truth(terrain):
    r'''The analytic codes of wall_terrain: 0 lit, 1 facing away, 2 cast'''
    x, _ = sample_points(terrain)
    code = np.zeros(x.shape, np.uint8)
    code[(x > 2.0) & (x < 2.1)] = 1                # the ridge's far slope faces away
    code[(x > 2.1) & (x < 2.95)] = 2
    return code


# ---------------------------------------------------------------------------
@pytest.mark.parametrize("method", ["raycast", pytest.param("povray", marks=needs_povray),
                                    "osmesa"])
def test_each_method_finds_the_analytic_shadow_of_a_ridge(method):
    t = wall_terrain()
    if method == "raycast":
        code = raycast_cell_shadows(t)
    elif method == "povray":
        from renderers.povray_terrain import cell_shadows
        code = cell_shadows(t)
    else:
        code = _osmesa().cell_shadows(t)
    truth = wall_truth(t)
    assert (truth == 2).mean() == pytest.approx(0.14, abs=0.01)
    assert np.array_equal(code, truth)


@needs_povray
@pytest.mark.parametrize("elevation_deg, bound_ro", [(12.0, 0.006), (25.0, 0.003)])
def test_the_three_agree_on_which_cells_are_in_shadow(elevation_deg, bound_ro):
    from renderers.povray_terrain import cell_shadows as povray_cells

    osm = _osmesa()
    t = rough_terrain(elevation_deg)
    r = raycast_cell_shadows(t)
    p = povray_cells(t)
    o = osm.cell_shadows(t, map_size=4096)
    rp, ro, po = compare(r, p, t), compare(r, o, t), compare(p, o, t)
    # a low sun puts a non-trivial part of the terrain in shadow, for every method
    # (measured: 36.9% at 12 deg, 9.4% at 25 deg; cast shadows 17.4% / 3.0%)
    for c in (rp, ro):
        assert 0.05 < c["shadowed_fraction_a"] < 0.6
        assert 0.05 < c["shadowed_fraction_b"] < 0.6
    assert rp["cast_fraction_a"] > 0.02
    # POV-Ray's shadow rays and the exact ones: measured 0 of 12800 triangles differ
    assert rp["disagree_fraction"] <= 0.0005
    # the shadow map (4096^2, slope_bias 0.5): measured 0.32% / 0.14% of triangles,
    # 0.13% / 0.04% of the sunlight; nobody disagrees on which triangles face away
    for c in (ro, po):
        assert 0 < c["disagree_fraction"] <= bound_ro
        assert c["sunlight_weighted_disagreement"] <= bound_ro / 2
        assert c["facing_disagree"] == 0
        # where: within a cell of a shadow edge or on triangles within 6 deg of edge-on
        # to the sun (measured: all of them); at most 2 / 1 cells from an exact edge
        assert c["max_edge_distance_cells"] <= 5
        assert c["edge_or_grazing_fraction"] >= 0.95


@needs_povray
def test_povray_shadow_texture_is_the_exact_shadow_baked_into_the_albedo():
    from renderers.povray_terrain import shadow_texture
    from renderers.raycast_terrain import trace_rays

    t = rough_terrain(12.0)                  # 160 x 160 texels, two per cell
    albedo, code = shadow_texture(t, shadow_factor=0.3)
    xmin, xmax, ymin, ymax = t.extent()
    ty, tx = t.albedo.shape
    x = xmin + (np.arange(tx) + 0.75) * (xmax - xmin) / tx       # nudge (0.25, -0.25)
    y = ymin + (np.arange(ty) + 0.25) * (ymax - ymin) / ty
    X, Y = np.meshgrid(x, y)
    _, _, exact = trace_rays(t, np.stack((X, Y, np.full_like(X, 5.0)), axis=-1),
                             np.array([0.0, 0.0, -1.0]))
    # measured: all 25600 texels agree (and 0 of 160000 on a 2 cm texture)
    assert np.mean((exact != 0) != (code != 0)) <= 0.001
    assert 0.1 < np.mean(code == 2) < 0.3
    cast = code == 2
    assert np.allclose(albedo[cast], 0.3 * t.albedo[cast], rtol=1e-6)
    assert np.array_equal(albedo[~cast], t.albedo[~cast])


def test_the_shadow_map_converges_with_its_resolution():
    osm = _osmesa()
    t = rough_terrain(12.0)
    r = raycast_cell_shadows(t)
    d = {S: compare(r, osm.cell_shadows(t, map_size=S), t)["disagree_fraction"]
         for S in (256, 1024, 4096)}
    # measured: 2.9%, 0.70%, 0.32%
    assert d[256] > d[1024] > d[4096]
    assert d[256] > 0.02


def test_tiled_top_down_view_gives_the_same_codes(monkeypatch):
    osm = _osmesa()
    t = rough_terrain(12.0)
    whole = osm.cell_shadows(t, map_size=1024)
    monkeypatch.setattr(osm, "TILE", 100)          # 240 x 240 px in 9 tiles
    assert np.array_equal(osm.cell_shadows(t, map_size=1024), whole)


@pytest.mark.parametrize("tilt_deg, expected", [(-20.0, 0), (0.0, 0), (7.0, 0), (9.5, 0),
                                                (12.0, 1)])
def test_no_self_shadowing_on_tilted_planes(tilt_deg, expected):
    r'''A plane rising towards a 10 deg sun by tilt_deg: cos i = sin(10 - tilt),
down to 0.009 (0.5 deg from edge-on): lit everywhere (the bias keeps the
shadow map from shadowing the plane itself); past 10 deg it faces away'''
    osm = _osmesa()
    k = math.tan(math.radians(tilt_deg))
    t = Terrain.from_function(lambda x, y: k * x + 0 * y, (0, 5, 0, 3), 0.1, sun=Sun(0.0, 10.0))
    codes = [raycast_cell_shadows(t), osm.cell_shadows(t, map_size=1024)]
    if HAVE_POVRAY:
        from renderers.povray_terrain import cell_shadows
        codes.append(cell_shadows(t))
    for code in codes:
        assert np.all(code == expected)


# ---------------------------------------------------------------------------
def top_down_camera(W=320, H=160, f=500.0, centre=(3.01234, 1.48765), height=10.0):
    # off the grid's lattice: from (3.0, 1.5) many pixel rays meet the surface exactly
    # on a cell diagonal, where POV-Ray's shadow rays leak through or hit the
    # neighbouring triangle (speckled lines; the exact renderer has none)
    A = np.array([0.0, 0.0, -1.0])
    Hp = np.array([1.0, 0.0, 0.0])
    Vp = np.cross(A, Hp)
    cx, cy = (W - 1) / 2.0, (H - 1) / 2.0
    return CAHV(C=np.array([centre[0], centre[1], height]), A=A, H=f * Hp + cx * A,
                V=f * Vp + cy * A, width=W, height=H)


def test_osmesa_darkens_shadowed_fragments_by_the_paper_factor():
    osm = _osmesa()
    t = wall_terrain(ambient=0.15)          # uniform albedo 0.5
    m = top_down_camera()
    shadowed = tuple(np.rint(m.project([2.5, 1.5, 0.0])).astype(int))
    lit = tuple(np.rint(m.project([4.0, 1.5, 0.0])).astype(int))
    lit_value = 0.5 * (0.15 + math.sin(math.radians(20.0)))
    for factor in (0.3, 0.6):
        img = osm.render_terrain(m, t, shadow_factor=factor).image
        assert img[lit[1], lit[0]] == pytest.approx(lit_value, rel=1e-5)
        assert img[shadowed[1], shadowed[0]] == pytest.approx(factor * lit_value, rel=1e-5)
    # the default factor gives flat ground in shadow the exact renderer's value (ambient only)
    r = osm.render_terrain(m, t)
    assert r.metadata["shadow_factor"] == pytest.approx(0.15 / (0.15 + math.sin(math.radians(20))))
    from renderers.raycast_terrain import render_terrain as raycast_render
    exact = raycast_render(m, t).image
    for q in (shadowed, lit):
        assert r.image[q[1], q[0]] == pytest.approx(exact[q[1], q[0]], rel=1e-5)
    assert exact[shadowed[1], shadowed[0]] == pytest.approx(0.5 * 0.15, rel=1e-6)
    # shadows off: nothing is darkened
    off = osm.render_terrain(m, t, shadows=False).image
    assert off[shadowed[1], shadowed[0]] == pytest.approx(lit_value, rel=1e-5)


@needs_povray
def test_povray_shades_like_the_exact_renderer():
    from renderers.povray_terrain import render_terrain as povray_render
    from renderers.raycast_terrain import render_terrain as raycast_render

    t = wall_terrain(ambient=0.15)
    m = top_down_camera()
    shadowed = tuple(np.rint(m.project([2.5, 1.5, 0.0])).astype(int))
    lit = tuple(np.rint(m.project([4.0, 1.5, 0.0])).astype(int))
    img = povray_render(m, t).image
    exact = raycast_render(m, t).image
    for q in (shadowed, lit):
        # 16-bit output: within 2 DN
        assert img[q[1], q[0]] == pytest.approx(exact[q[1], q[0]], abs=3e-5)


@pytest.mark.slow
@needs_povray
def test_camera_renders_of_the_three_agree():
    from harness.stereo import scale_model
    from reference_models.catalogue import load_catalogue
    from renderers.povray_terrain import render_terrain as povray_render
    from renderers.raycast_terrain import render_terrain as raycast_render

    osm = _osmesa()
    t = make_terrain(extent=(0, 10, -5, 5), cell=0.1, texel=0.02, seed=5, relief_m=0.3,
                     relief_wavelength_m=3.0, rocks_per_m2=1.5, rock_radius_m=(0.05, 0.4),
                     sun=Sun(120.0, 12.0))
    m = scale_model(load_catalogue().get(21).model, 0.05)   # Mars 2020 navcam, 256x192
    pose = ground_pose(1.9, pitch_deg=20.0)
    exact = raycast_render(m, t, pose, spp=2)
    images = {"povray": povray_render(m, t, pose, spp=2, shadow_codes=True),
              "osmesa": osm.render_terrain(m, t, pose, spp=2)}
    ground = np.isfinite(exact.range)
    # measured: 58% ground, 30% of it unlit
    assert 0.3 < ground.mean() < 0.9
    assert 0.1 < (exact.shadow[ground] != 0).mean() < 0.6
    for name, r in images.items():
        assert r.image.shape == exact.image.shape and r.image.dtype == np.float32
        d = np.abs(r.image.astype(np.float64) - exact.image)
        # measured mean 0.0033 (povray) / 0.0048 (osmesa: its darkening factor is one
        # number, exact on flat ground only), median 0.0002 / 0.0004: pinhole + warp
        # against exact rays, and shadow edges
        assert d.mean() < 0.01, name
        assert np.median(d) < 0.002, name
        assert r.metadata["renderer"] in ("povray_terrain", "osmesa_terrain")
    # per-pixel verdicts (the pinhole pixel nearest each pixel's ray) against the exact
    # ones: measured 98.5% (osmesa) / 98.6% (povray) of pixels agree on lit / unlit,
    # 99.85% on sky: the nearest-pixel resampling, more than the shadow test, differs
    for name, r in images.items():
        code = r.shadow
        assert code.shape == exact.shadow.shape and code.dtype == np.uint8, name
        assert ((code == 255) == (exact.shadow == 255)).mean() > 0.995, name
        assert ((code != 0) == (exact.shadow != 0)).mean() > 0.97, name


@pytest.mark.slow
@needs_povray
def test_povray_mesh_camera_render_equals_the_exact_one_for_a_fisheye():
    from harness.stereo import scale_model
    from reference_models.catalogue import load_catalogue
    from renderers.povray_terrain import render_terrain as povray_render
    from renderers.raycast_terrain import render_terrain as raycast_render

    t = make_terrain(extent=(0, 8, -4, 4), cell=0.1, texel=0.02, seed=5, relief_m=0.3,
                     relief_wavelength_m=3.0, rocks_per_m2=1.5, rock_radius_m=(0.05, 0.4),
                     sun=Sun(120.0, 12.0))
    m = scale_model(load_catalogue().get(12).model, 0.125)   # MER B hazcam CAHVORE, 128x128
    pose = ground_pose(0.5)
    exact = raycast_render(m, t, pose, spp=2)
    r = povray_render(m, t, pose, spp=2, camera="mesh", shadow_codes=True)
    assert r.metadata["camera"] == "mesh"
    # the same rays, POV-Ray's intersections and shadows: measured |d| mean 7e-6,
    # p99 6e-6 (16-bit output), 99.99% of pixel shadow codes equal (at 256x256)
    d = np.abs(r.image.astype(np.float64) - exact.image)
    assert d.mean() < 1e-4 and np.percentile(d, 99) < 1e-4
    assert np.mean(r.shadow == exact.shadow) > 0.999
    assert 0.05 < np.mean(exact.shadow[exact.shadow != 255] != 0) < 0.6


def test_osmesa_and_povray_through_the_registry_render_as_their_modules():
    from renderers.base import RenderSettings, TerrainRenderer, get_terrain_renderer

    osm = _osmesa()
    t = wall_terrain(ambient=0.15)
    m = top_down_camera(W=48, H=32)
    settings = RenderSettings(spp=2, options={"shadows": False})
    backends = {"osmesa_terrain": osm.render_terrain}
    if HAVE_POVRAY:
        from renderers import povray_terrain
        backends["povray_terrain"] = povray_terrain.render_terrain
    for name, render in backends.items():
        r = get_terrain_renderer(name)
        assert isinstance(r, TerrainRenderer) and r.version(), name
        a = r.render_terrain(m, t, None, settings)
        b = render(m, t, None, spp=2, shadows=False)
        assert a.metadata["renderer"] == name
        assert np.array_equal(a.image, b.image), name
        for x, y in ((a.shadow, b.shadow), (a.range, b.range)):
            assert (x is None and y is None) or np.array_equal(x, y), name
    assert np.array_equal(get_terrain_renderer("osmesa_terrain", map_size=1024).cell_shadows(t),
                          osm.cell_shadows(t, map_size=1024))


# ---------------------------------------------------------------------------
def test_bad_input_is_refused_with_a_reason():
    osm = _osmesa()
    t = wall_terrain()
    m = top_down_camera(W=32, H=16)
    with pytest.raises(RendererError, match="map_size"):
        osm.cell_shadows(t, map_size=8)
    with pytest.raises(RendererError, match="shadow_factor"):
        osm.render_terrain(m, t, shadow_factor=1.5)
    with pytest.raises(RendererError, match="supersampling K"):
        osm.render_terrain(m, t, spp=0)
    with pytest.raises(RendererError, match="Rt_ref_terrain"):
        osm.render_terrain(m, t, Rt_ref_terrain=np.zeros((3, 3)))
    from renderers.povray_terrain import cell_shadows, render_terrain
    with pytest.raises(RendererUnavailableError, match="apt-get install povray"):
        cell_shadows(t, binary="no-such-povray-binary")
    with pytest.raises(RendererUnavailableError, match="apt-get install povray"):
        render_terrain(m, t, binary="no-such-povray-binary")
    from renderers.base import get_terrain_renderer
    with pytest.raises(RendererUnavailableError, match="apt-get install povray"):
        get_terrain_renderer("povray_terrain", binary="no-such-povray-binary")
    with pytest.raises(RendererError, match="known: perspective, mesh"):
        render_terrain(m, t, camera="fisheye")
    with pytest.raises(RendererError, match="max_mesh_rays"):
        render_terrain(m, t, camera="mesh", spp=4, max_mesh_rays=1000)
    with pytest.raises(ShadowCompareError, match=r"\(Ny-1, Nx-1, 2\)"):
        compare(np.zeros((3, 3, 2), np.uint8), np.zeros((3, 4, 2), np.uint8))
