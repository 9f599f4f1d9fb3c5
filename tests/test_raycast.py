r'''The exact ray-cast renderer: rays, pixel convention, point sampling's adaptive == full,
edge pixels from the projected outlines, bad input'''

import math

import numpy as np
import pytest

from reference_models import kernels
from reference_models.cahvore import CAHV, CAHVOR, CAHVORE
from reference_models.catalogue import load_catalogue
from reference_models.errors import CamvalError
from renderers import _raycast_kernels as kern
from renderers.base import RenderSettings, get_renderer
from renderers.raycast import (
    PatternError,
    PoseError,
    RaycastRenderer,
    Rt_board_ref,
    compile_pattern,
)
from renderers.raycast_outlines import project_outlines
from targets.boards import load_target
from targets.centroids import board_to_ref, polygon_centroid
from targets.pattern import Pattern
from targets.poses import plan_poses


def point(spp, adaptive=True):
    r'''Settings of K x K point sampling: what most tests here check (subsample rays,
adaptive == full); area coverage, the default, is tests/test_raycast_area.py'''
    return RenderSettings(spp=spp, adaptive=adaptive, options={"coverage": "point"})


def _pinhole_parts(width, height, f, cx=None, cy=None):
    cx = (width - 1) / 2 if cx is None else cx
    cy = (height - 1) / 2 if cy is None else cy
    A = np.array([0.0, 0.0, 1.0])
    return dict(C=np.array([0.1, -0.2, 0.3]), A=A, H=np.array([f, 0.0, 0.0]) + cx * A,
                V=np.array([0.0, f, 0.0]) + cy * A, width=width, height=height)


def _tilted(deg):
    t = math.radians(deg)
    return np.array([math.sin(t), 0.2 * math.sin(t), math.cos(t)])


def small_models():
    r'''Small synthetic cameras of every family (fast to render fully)'''
    p = _pinhole_parts(200, 150, 160.0, cx=97.3, cy=80.1)
    return {
        "cahv": CAHV(**p),
        "cahvor": CAHVOR(O=_tilted(1.5), R=[0.0, -0.15, 0.03], **p),
        "cahvore-noncentral": CAHVORE(O=_tilted(2.0), R=[0.0, 0.02, -0.01],
                                      E=[0.01, 0.02, -0.005], model_type=3, linearity=0.37,
                                      **_pinhole_parts(200, 150, 90.0)),
        "cahvore-fisheye": CAHVORE(O=_tilted(0.5), R=[0.0, 0.01, 0.0], E=[0.003, -0.002, 0.001],
                                   model_type=2, **_pinhole_parts(160, 160, 60.0)),
    }


def catalogue_models():
    cat = load_catalogue()
    return {f"slot{i}": cat.get(i).model for i in (1, 12, 15, 17)} | \
        {"SuperCam": cat.get("SuperCam").model}


def dot_pattern(n=6, spacing=0.1, r=0.03, background=0.25):
    g = np.arange(n) * spacing
    X, Y = np.meshgrid(g, g)
    circles = np.stack((X.ravel(), Y.ravel(), np.full(n * n, r)), axis=1)
    m = spacing
    return Pattern(extent=(-m, (n - 1) * spacing + m, -m, (n - 1) * spacing + m),
                   board_value=0.9, background_value=background, circles=circles,
                   circle_value=0.05)


def board_pose(model, distance, euler_deg=(0, 0, 0), centre=(0.25, 0.25), offset=(0, 0)):
    r'''Rt_cam_board: the board point `centre` at (offset, distance) in the camera frame'''
    from scipy.spatial.transform import Rotation
    R = Rotation.from_euler("xyz", euler_deg, degrees=True).as_matrix()
    t = np.array([offset[0], offset[1], distance]) - R @ np.array([centre[0], centre[1], 0.0])
    return np.vstack((R, t))


# --- rays -------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["cahv", "cahvor", "cahvore-noncentral", "cahvore-fisheye",
                                  "slot1", "slot12", "slot15", "slot17", "SuperCam"])
def test_rays_equal_model_unproject(name):
    model = (small_models() | catalogue_models())[name]
    rng = np.random.default_rng(3)
    W, H = model.width, model.height
    q = np.concatenate((rng.uniform([-0.5, -0.5], [W - 0.5, H - 0.5], (4000, 2)),
                        [[-0.5, -0.5], [W - 0.5, H - 0.5], [-0.5, H - 0.5], [W / 2, H / 2]]))
    cam = kernels.pack_model(model)
    origin, v = kernels.unproject_grid(cam, q)
    origin_ref, v_ref = model.unproject(q)
    assert np.all(np.isfinite(v)) and np.all(np.isfinite(v_ref))
    np.testing.assert_allclose(v, v_ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(origin, origin_ref, rtol=0, atol=1e-12)
    if not model.is_central:
        assert np.ptp(origin @ model.O) > 1e-4   # the pupil does move


@pytest.mark.parametrize("name", ["cahvor", "cahvore-noncentral", "slot12", "slot15"])
def test_subsample_rays_from_warm_start_equal_model_unproject(name):
    r'''The subsample rays (unnormalised, Newton from the pixel centre's chi) are the
same rays as model.unproject'''
    from numba import njit

    @njit
    def trace(cam, q, out_s, out_v):
        for i in range(q.shape[0]):
            warm = kernels.warm_start(cam, math.floor(q[i, 0] + 0.5), math.floor(q[i, 1] + 0.5))
            s, vx, vy, vz = kernels.ray_warm(cam, q[i, 0], q[i, 1], warm)
            out_s[i] = s
            out_v[i, 0] = vx
            out_v[i, 1] = vy
            out_v[i, 2] = vz

    model = (small_models() | catalogue_models())[name]
    q = np.random.default_rng(5).uniform([-0.5, -0.5],
                                         [model.width - 0.5, model.height - 0.5], (4000, 2))
    cam = kernels.pack_model(model)
    s = np.empty(len(q))
    v = np.empty((len(q), 3))
    trace(cam, q, s, v)
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    origin_ref, v_ref = model.unproject(q)
    np.testing.assert_allclose(v, v_ref, rtol=0, atol=1e-12)
    O = getattr(model, "O", np.zeros(3))
    np.testing.assert_allclose(model.C + s[:, None] * O, origin_ref, rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", ["cahv", "cahvor", "cahvore-noncentral", "cahvore-fisheye"])
def test_ray_cache_equals_model_unproject(name):
    r'''The cached pixel-centre rays (Newton solves started along the rows, directions
not normalised) of pixels -1..W, -1..H'''
    model = small_models()[name]
    W, H = model.width, model.height
    dirs, shift = kernels.build_ray_cache(kernels.pack_model(model), W, H, not model.is_central)
    assert dirs.shape == (H + 2, W + 2, 3)
    q = np.stack(np.meshgrid(np.arange(-1.0, W + 1), np.arange(-1.0, H + 1)), axis=-1)
    origin, v = model.unproject(q)
    np.testing.assert_allclose(dirs / np.linalg.norm(dirs, axis=-1, keepdims=True), v,
                               rtol=0, atol=1e-12)
    if not model.is_central:
        np.testing.assert_allclose(model.C + shift[..., None] * model.O, origin, rtol=0,
                                   atol=1e-12)
    else:
        assert shift.shape == (1, 1)


def test_board_transform_is_inverse_of_board_to_ref():
    model = small_models()["cahvore-noncentral"]
    Rt = board_pose(model, 1.0, (20, -30, 10))
    p_board = np.array([[0.1, 0.2, 0.0], [0.4, -0.1, 0.0]])
    p_ref = board_to_ref(model, Rt, p_board)
    Rt_br = Rt_board_ref(model, Rt)
    np.testing.assert_allclose(p_ref @ Rt_br[:3].T + Rt_br[3], p_board, atol=1e-14)


# --- the image ----------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["cahv", "cahvore-noncentral"])
def test_unsupersampled_pixels_are_the_albedo_where_model_unproject_rays_meet_the_board(name):
    r'''K = 1: each pixel is Pattern.albedo at the board point of its centre ray, the ray
computed by the reference model (independent of the kernels)'''
    model = small_models()[name]
    pattern = dot_pattern()
    Rt = board_pose(model, 0.9, (25, -20, 5))
    image = RaycastRenderer().render(model, pattern, Rt, point(spp=1)).image
    from reference_models.conventions import pixel_centres
    origin, v = model.unproject(pixel_centres(model.width, model.height))
    Rt_br = Rt_board_ref(model, Rt)
    o = origin @ Rt_br[:3].T + Rt_br[3]
    d = v @ Rt_br[:3].T
    t = -o[..., 2] / d[..., 2]
    x = o[..., 0] + t * d[..., 0]
    y = o[..., 1] + t * d[..., 1]
    ref = np.where(t > 0, pattern.albedo(x, y), pattern.background_value).astype(np.float32)
    assert (image != ref).sum() == 0


@pytest.mark.parametrize("name", ["cahvor", "cahvore-noncentral"])
def test_supersampled_pixels_average_albedo_at_subsample_rays(name):
    r'''K = 3 (no adaptivity): the mean albedo over the subsample rays (ix + (i+0.5)/3 - 0.5,
iy + (j+0.5)/3 - 0.5) of the reference model'''
    K = 3
    model = small_models()[name]
    pattern = dot_pattern()
    Rt = board_pose(model, 0.9, (-15, 25, 40))
    image = RaycastRenderer().render(model, pattern, Rt,
                                     point(spp=K, adaptive=False)).image
    off = (np.arange(K) + 0.5) / K - 0.5
    iy, ix = np.mgrid[0:model.height, 0:model.width]
    Rt_br = Rt_board_ref(model, Rt)
    acc = np.zeros(image.shape)
    for oy in off:
        for ox in off:
            q = np.stack((ix + ox, iy + oy), axis=-1)
            origin, v = model.unproject(q)
            o = origin @ Rt_br[:3].T + Rt_br[3]
            d = v @ Rt_br[:3].T
            t = -o[..., 2] / d[..., 2]
            a = pattern.albedo(o[..., 0] + t * d[..., 0], o[..., 1] + t * d[..., 1])
            acc += np.where(t > 0, a, pattern.background_value)
    np.testing.assert_allclose(image, acc / K**2, rtol=0, atol=2e-7)


def _dot_darkness_centroid(image, board_value, window):
    r'''Darkness-weighted centroid over a window (x0, x1, y0, y1) of pixels'''
    x0, x1, y0, y1 = window
    w = board_value - image[y0:y1, x0:x1].astype(np.float64)
    iy, ix = np.mgrid[y0:y1, x0:x1]
    return np.array([(w * ix).sum() / w.sum(), (w * iy).sum() / w.sum()])


@pytest.mark.parametrize("name,tilt", [("slot15", (30, -35, 10)), ("slot12", (-40, 20, 0)),
                                       ("cahvore-noncentral", (35, 30, 0))])
def test_single_dot_centroid_is_the_exact_expected_centroid(name, tilt):
    r'''A lone dot's darkness-weighted centroid equals the area centroid of its projected
outline to 1e-3 px: this proves the pixel convention (centre of pixel (0,0) at q = (0,0))
and the area sampling'''
    model = (small_models() | catalogue_models())[name]
    # the dot ~40 px in radius, away from the centre of the image
    ph = model.photogrammetric()
    q_target = np.array([0.3 * model.width, 0.65 * model.height])
    origin, v = model.unproject(q_target)
    Rt_ref_cam = model.Rt_ref_cam()
    v_cam = v @ Rt_ref_cam[:3]
    o_cam = (origin - Rt_ref_cam[3]) @ Rt_ref_cam[:3]
    distance = 0.5
    centre_cam = o_cam + distance * v_cam
    radius = 40.0 * distance / ph.Hs
    from scipy.spatial.transform import Rotation
    R = Rotation.from_euler("xyz", tilt, degrees=True).as_matrix()
    Rt = np.vstack((R, centre_cam))         # the board origin at the dot
    pattern = Pattern(extent=(-8 * radius, 8 * radius, -8 * radius, 8 * radius),
                      board_value=1.0, background_value=1.0,
                      circles=np.array([[0.0, 0.0, radius]]), circle_value=0.0)
    # K = 64: the K x K grid errs by ~1e-3 px at K = 16, ~1e-4 px at K = 64 (measured)
    result = RaycastRenderer().render(model, pattern, Rt, point(spp=64))
    t = np.linspace(0, 2 * math.pi, 1440, endpoint=False)
    outline = np.stack((radius * np.cos(t), radius * np.sin(t), 0 * t), axis=-1)
    q = model.project(board_to_ref(model, Rt, outline))
    expected = polygon_centroid(q)
    lo = np.floor(q.min(axis=0)).astype(int) - 3
    hi = np.ceil(q.max(axis=0)).astype(int) + 4
    assert 40 < (hi - lo).min() < 200
    got = _dot_darkness_centroid(result.image, 1.0, (lo[0], hi[0], lo[1], hi[1]))
    assert np.linalg.norm(got - expected) < 1e-3
    # the same dot rendered off by half a pixel would be way off: the test can fail
    assert np.linalg.norm(got + 0.5 - expected) > 0.5


# --- adaptive == full ---------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["cahv", "cahvor", "cahvore-noncentral", "cahvore-fisheye"])
@pytest.mark.parametrize("K", [2, 5, 8])
def test_adaptive_equals_full_supersampling_bit_for_bit(name, K):
    model = small_models()[name]
    r = RaycastRenderer()
    for Rt in (board_pose(model, 0.7, (25, -20, 5)), board_pose(model, 1.2, (-40, 30, 60),
                                                                 offset=(0.2, -0.1))):
        for pattern in (dot_pattern(), load_target("chessboard").pattern(),
                        load_target("apriltag").pattern()):
            a = r.render(model, pattern, Rt, point(spp=K, adaptive=True))
            f = r.render(model, pattern, Rt, point(spp=K, adaptive=False))
            assert a.metadata["board_fraction"] > 0.01
            assert 0 < a.metadata["adaptive_fraction"] < 0.8
            assert f.metadata["adaptive_fraction"] == 1.0
            assert np.array_equal(a.image, f.image)
            # adaptive mode counts the board pixels of uniform tiles without their rays
            assert a.metadata["board_fraction"] == f.metadata["board_fraction"]


@pytest.mark.slow
@pytest.mark.parametrize("slot,target", [(12, "dots"), (15, "dots"), (5, "apriltag"),
                                         (16, "chessboard")])
def test_adaptive_equals_full_on_planned_poses_of_catalogue_cameras(slot, target):
    r'''The bit-for-bit check on real cameras (incl. the noncentral CAHVORE hazcams) at
K = 16, on the rows of the image where the target is'''
    model = load_catalogue().get(slot).model
    tgt = load_target(target)
    r = RaycastRenderer()
    Rt = plan_poses(model, tgt, n=6, seed=0)[slot % 6]
    a = r.render(model, tgt.pattern(), Rt, point(spp=16))
    # full supersampling of a band of rows through the board (all of it is too slow here)
    rows = np.flatnonzero((a.image != a.image[0, 0]).any(axis=1))
    start = int(np.clip(rows[len(rows) // 2] - 24, 0, model.height - 48))
    band = slice(start, start + 48)
    crop = model.replace(V=model.V - band.start * model.A, height=48)
    f = r.render(crop, tgt.pattern(), Rt, point(spp=16, adaptive=False))
    assert np.array_equal(a.image[band], f.image)
    assert len(np.unique(f.image)) > 50


# --- output, metadata ----------------------------------------------------------------------
def test_output_range_dtype_and_metadata():
    model = small_models()["cahvore-noncentral"]
    renderer = get_renderer("raycast")
    assert renderer.name == "raycast" and renderer.version().startswith("raycast ")
    res = renderer.render(model, dot_pattern(), board_pose(model, 0.8, (10, 10, 0)),
                          RenderSettings(spp=4))
    img = res.image
    assert img.dtype == np.float32 and img.shape == (model.height, model.width)
    assert img.min() >= 0.0 and img.max() <= 1.0
    assert set(np.unique(img)) >= {np.float32(0.25), np.float32(0.9), np.float32(0.05)}
    md = res.metadata
    assert md["renderer"] == "raycast" and md["settings"] == {"spp": 4, "adaptive": True,
                                                              "options": {}}
    assert md["seconds"] > 0 and md["samples"] > 0 and 0 < md["adaptive_fraction"] < 1
    assert md["version"] == renderer.version()


def test_target_objects_render_like_their_pattern():
    model = small_models()["cahvor"]
    tgt = load_target("apriltag")
    Rt = board_pose(model, 1.2, (10, 10, 0), centre=tgt.centre()[:2])
    r = RaycastRenderer()
    a = r.render(model, tgt, Rt, RenderSettings(spp=2)).image
    b = r.render(model, tgt.pattern(), Rt, RenderSettings(spp=2)).image
    assert np.array_equal(a, b) and len(np.unique(a)) > 3


def test_patterns_drawn_in_turn_are_compiled_once_and_render_alike():
    model = small_models()["cahvor"]
    tags, dots = load_target("apriltag"), dot_pattern()
    Rt = board_pose(model, 1.2, (10, 10, 0), centre=tags.centre()[:2])
    r = RaycastRenderer()
    first = [r.render(model, p, Rt, RenderSettings(spp=2)).image for p in (tags, dots)]
    compiled = [r._compiled(p) for p in (tags.pattern(), dots)]
    # a worker's jobs alternate targets: each pattern keeps its compiled form
    again = [r.render(model, p, Rt, RenderSettings(spp=2)).image for p in (tags, dots)]
    assert [r._compiled(p) for p in (tags.pattern(), dots)] == compiled
    assert all(np.array_equal(a, b) for a, b in zip(first, again, strict=True))


def test_images_held_are_never_rendered_into_and_dropped_ones_are_reused():
    model = small_models()["cahvor"]
    pattern = dot_pattern()
    poses = [board_pose(model, d, (10, 10, 0)) for d in (0.8, 0.9, 1.0, 1.1)]
    r = RaycastRenderer()
    fresh = [RaycastRenderer().render(model, pattern, Rt).image for Rt in poses]
    held = r.render(model, pattern, poses[0]).image
    view = r.render(model, pattern, poses[1]).image[10:20]   # only a slice of it kept
    address = view.base.ctypes.data
    # both buffers are held (an image and a view of the other): a third one
    third = r.render(model, pattern, poses[2]).image
    assert third.ctypes.data not in (held.ctypes.data, address)
    assert np.array_equal(held, fresh[0]) and np.array_equal(view, fresh[1][10:20])
    del view
    fourth = r.render(model, pattern, poses[3]).image
    # the dropped one is rendered into again, and every pixel is written
    assert fourth.ctypes.data == address and np.array_equal(fourth, fresh[3])
    assert np.array_equal(held, fresh[0]) and np.array_equal(third, fresh[2])


# --- bad input ----------------------------------------------------------------------------------
def test_board_behind_the_camera_renders_blank():
    model = small_models()["cahvore-noncentral"]
    Rt = board_pose(model, -1.0)
    res = RaycastRenderer().render(model, dot_pattern(), Rt, RenderSettings(spp=4))
    assert res.metadata["board_fraction"] == 0.0
    assert np.all(res.image == np.float32(0.25))


def test_board_edge_on_renders_without_crash():
    model = small_models()["cahvor"]
    # the camera's optical axis lies in the board plane
    R = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])
    Rt = np.vstack((R, [0.0, 0.0, 0.5]))
    res = RaycastRenderer().render(model, dot_pattern(), Rt, RenderSettings(spp=4))
    assert np.all(np.isfinite(res.image))


@pytest.mark.parametrize("spp", [0, -3, 2.5, True])
def test_non_positive_or_non_integer_K_is_an_error(spp):
    with pytest.raises(CamvalError, match="positive integer"):
        RaycastRenderer().render(small_models()["cahv"], dot_pattern(), board_pose(None, 1.0),
                                 RenderSettings(spp=spp))


def test_zero_size_dot_is_an_error():
    p = Pattern(extent=(0, 1, 0, 1), circles=np.array([[0.5, 0.5, 0.1], [0.2, 0.2, 0.0]]))
    with pytest.raises(PatternError, match="circle 1 has radius 0.0"):
        RaycastRenderer().render(small_models()["cahv"], p, board_pose(None, 1.0),
                                 RenderSettings(spp=1))


@pytest.mark.parametrize("pattern,match", [
    (Pattern(extent=(1, 0, 0, 1)), "xmin < xmax"),
    (Pattern(extent=(0, 1, 0, 1), board_value=1.5), "board_value = 1.5"),
    (Pattern(extent=(0, 1, 0, 1), cells=np.zeros((2, 2)), cell_size=0.0), "cell_size"),
    (Pattern(extent=(0, 1, 0, 1), circles=np.zeros((2, 2))), r"expected \(N,3\)"),
])
def test_bad_patterns_are_errors(pattern, match):
    with pytest.raises(PatternError, match=match):
        RaycastRenderer().render(small_models()["cahv"], pattern, board_pose(None, 1.0),
                                 RenderSettings(spp=1))


@pytest.mark.parametrize("Rt,match", [(np.zeros((3, 3)), "shape"),
                                      (np.vstack((2 * np.eye(3), np.ones(3))), "rotation"),
                                      (np.full((4, 3), np.nan), "non-finite")])
def test_bad_poses_are_errors(Rt, match):
    with pytest.raises(PoseError, match=match):
        RaycastRenderer().render(small_models()["cahv"], dot_pattern(), Rt,
                                 RenderSettings(spp=1))


def test_not_a_pattern_is_an_error():
    with pytest.raises(CamvalError, match="Pattern"):
        RaycastRenderer().render(small_models()["cahv"], "dots", board_pose(None, 1.0),
                                 RenderSettings(spp=1))


@pytest.mark.parametrize("name", ["cahvore-fisheye", "cahvore-noncentral"])
def test_adaptive_equals_full_with_the_horizon_in_view(name):
    r'''A board plane seen nearly edge-on by a wide-angle camera: its horizon crosses the
image, part of the board recedes to grazing angles (footprints far from affine)'''
    model = small_models()[name]
    r = RaycastRenderer()
    big = dot_pattern(n=20, spacing=0.1, r=0.03)
    Rt = board_pose(model, 0.4, (80, 0, 10), centre=(0.95, 0.95))
    a = r.render(model, big, Rt, point(spp=6))
    f = r.render(model, big, Rt, point(spp=6, adaptive=False))
    assert 0.05 < a.metadata["board_fraction"] < 0.9
    assert np.array_equal(a.image, f.image)
    # the horizon: some pixel rows see the plane, the top ones do not
    sees = np.any(a.image != np.float32(0.25), axis=1)
    assert sees.any() and not sees.all()


def test_non_finite_pixels_are_counted_per_band():
    r'''render() raises on non-finite pixels from the kernel's per-band count'''
    out = np.zeros((6, 5), dtype=np.float32)
    out[0, 0] = np.float32(np.finfo(np.float32).max)
    out[1, 4] = np.nan
    out[4, 2] = np.inf
    out[5, 0] = -np.inf
    out[5, 1] = np.float32(np.finfo(np.float32).tiny) / 2   # subnormal: finite
    assert kern._count_nonfinite(out, 0, 1) == 0
    assert kern._count_nonfinite(out, 0, 3) == 1
    assert kern._count_nonfinite(out, 3, 6) == 2
    assert kern._count_nonfinite(out, 0, 6) == 3


# --- edge pixels from the projected outlines ------------------------------------------------
@pytest.mark.parametrize("name", ["cahv", "cahvor", "cahvore-noncentral", "cahvore-fisheye"])
def test_outline_edges_render_the_pixels_of_tested_edges(name):
    r'''Edge pixels found from the projected outlines (the default) against edge pixels
found by testing pixels (outlines=False): in point sampling the same pixels bit for bit
(where either looks closer it counts the K x K subsamples exactly); in area coverage the
same integrals from the same rays up to the last bits of their Newton solves (1e-15), so
within a few roundings of float32 values <= 1 (6e-8 each)'''
    model = small_models()[name]
    outlines = RaycastRenderer()
    tested = RaycastRenderer(outlines=False)
    for Rt in (board_pose(model, 0.7, (25, -20, 5)),
               board_pose(model, 1.2, (-40, 30, 60), offset=(0.2, -0.1))):
        for pattern in (dot_pattern(), load_target("chessboard").pattern(),
                        load_target("apriltag").pattern()):
            for settings in (RenderSettings(spp=4), point(spp=4)):
                a = outlines.render(model, pattern, Rt, settings)
                b = tested.render(model, pattern, Rt, settings)
                assert (a.metadata["edges"], b.metadata["edges"]) == ("outlines", "tested")
                if settings.options:
                    assert np.array_equal(a.image, b.image)
                else:
                    assert np.abs(a.image - b.image).max() <= 2e-7
                assert a.metadata["board_fraction"] == b.metadata["board_fraction"]
                # fewer pixels looked at closely than the tests look at
                assert a.metadata["pixels_tested"] < b.metadata["pixels_tested"]


def _circle_crossings(cx, cy, r, n=20000):
    r'''The pixels (ix, iy) a circle in the image passes through (dense points)'''
    t = np.linspace(0, 2 * math.pi, n, endpoint=False)
    return np.unique(np.floor(np.stack((cx + r * np.cos(t), cy + r * np.sin(t)), -1)
                              + 0.5).astype(int), axis=0)


@pytest.mark.parametrize("seed", [0, 1])
def test_mark_outlines_marks_every_pixel_a_polyline_comes_near(seed):
    r'''Circles in the image as closed polylines with their sagitta as margin: every pixel
the circle passes through is marked, with its tile; the marked pixels are not many more
than the crossed ones (a band about 2 px wide)'''
    rng = np.random.default_rng(seed)
    W, H, T = 120, 90, 32
    for _ in range(20):
        cx, cy = rng.uniform([-10, -10], [W + 10, H + 10])
        r = rng.uniform(0.3, 40.0)
        n = max(8, int(2 * math.pi * r / 1.5))
        a = np.arange(n) * 2 * math.pi / n
        q = np.stack((cx + r * np.cos(a), cy + r * np.sin(a)), -1)
        sagitta = r * (1 - math.cos(math.pi / n))
        mask = np.zeros((H, W), np.uint8)
        tiles = np.zeros((3, 4), np.uint8)
        kern.mark_outlines(q, np.array([0, n]), np.array([1], np.uint8),
                           np.array([sagitta + 1e-9]), mask, tiles, T)
        px = _circle_crossings(cx, cy, r)
        px = px[(px[:, 0] >= 0) & (px[:, 0] < W) & (px[:, 1] >= 0) & (px[:, 1] < H)]
        assert np.all(mask[px[:, 1], px[:, 0]] == 1)
        iy, ix = np.nonzero(mask)
        assert tiles.sum() == len(np.unique(np.stack((iy // T, ix // T), -1), axis=0))
        assert mask.sum() <= 3 * len(px) + 8


@pytest.mark.parametrize("name", ["cahvor", "cahvore-noncentral", "cahvore-fisheye"])
def test_projected_outlines_hold_the_projected_curves_within_their_margins(name):
    r'''Points of each dot's outline between the polyline's samples, projected by the
reference model, lie within the polyline's margin of its chord (the chord-error bound
of renderers.raycast_outlines); the margins are small (<= MAX_SAGITTA_PX + slop)'''
    from renderers.raycast_outlines import MAX_SAGITTA_PX, MAX_STEP_PX, PROJECTION_SLOP_PX
    model = small_models()[name]
    pattern = dot_pattern()
    Rt = board_pose(model, 0.5, (35, -30, 10))
    ol = project_outlines(model, Rt, compile_pattern(pattern))
    assert ol is not None
    assert ol.margin.max() <= MAX_SAGITTA_PX + PROJECTION_SLOP_PX
    # the board rectangle's 4 sides come first, then the circles (no cells)
    for k, (cx, cy, r) in enumerate(pattern.circles):
        i = 4 + k
        q = ol.q[ol.starts[i]:ol.starts[i + 1]]
        n = len(q)
        assert np.linalg.norm(np.diff(q, axis=0), axis=-1).max() <= MAX_STEP_PX
        a = (np.arange(16 * n) + 0.5) * 2 * math.pi / (16 * n)
        p = np.stack((cx + r * np.cos(a), cy + r * np.sin(a), 0 * a), -1)
        dense = model.project(board_to_ref(model, Rt, p))
        j = np.arange(16 * n) // 16
        A, B = q[j], q[(j + 1) % n]
        d = B - A
        t = np.clip(np.sum((dense - A) * d, -1) / np.sum(d * d, -1), 0, 1)
        dist = np.linalg.norm(dense - (A + t[:, None] * d), axis=-1)
        assert dist.max() <= ol.margin[i]
        # the margin is not vacuous: the chords do bow away from the curve
        assert dist.max() > 0.05 * ol.margin[i]


def test_a_board_reaching_behind_a_fisheye_tests_its_pixels():
    r'''A wide-angle CAHVORE sees a board whose far part lies behind the camera: its image
is not known to be bounded by the projected outline, so the pixels are tested (edges
"tested"), as with outlines=False'''
    model = small_models()["cahvore-fisheye"]
    big = dot_pattern(n=20, spacing=0.1, r=0.03)
    Rt = board_pose(model, 0.3, (100, 0, 0), centre=(0.95, 0.95))
    a = RaycastRenderer().render(model, big, Rt, RenderSettings(spp=4))
    b = RaycastRenderer(outlines=False).render(model, big, Rt, RenderSettings(spp=4))
    assert a.metadata["edges"] == "tested"
    assert np.array_equal(a.image, b.image)
    assert a.metadata["board_fraction"] > 0.01


def test_a_board_past_a_folding_distortion_tests_its_pixels(monkeypatch):
    r'''A wide CAHVORE (E != 0) whose distortion polynomial chi (1 + R1 chi^2 + R2 chi^4)
has its maximum (u = 2.02 at chi = 2.14, 667 px from the centre) inside the image: board
points beyond it project back into the image, where the pixels' rays see other points,
so the outline does not bound the board's image; the pixels are tested (edges
"tested"), as with outlines=False. Without that check (_round_trip) the outline path
paints board over background here'''
    from renderers import raycast_outlines
    from targets.poses import plan_poses
    model = _folding_cahvore()
    target = load_target("dots")
    Rt = plan_poses(model, target, n=6, seed=0)[4]
    a = RaycastRenderer().render(model, target.pattern(), Rt, RenderSettings(spp=4))
    b = RaycastRenderer(outlines=False).render(model, target.pattern(), Rt,
                                               RenderSettings(spp=4))
    assert a.metadata["edges"] == "tested"
    assert np.array_equal(a.image, b.image)
    monkeypatch.setattr(raycast_outlines, "_round_trip", lambda *args: True)
    c = RaycastRenderer().render(model, target.pattern(), Rt, RenderSettings(spp=4))
    assert c.metadata["edges"] == "outlines"
    assert (np.abs(c.image - b.image) > 0.5).sum() > 100


@pytest.mark.parametrize("R", [[0.0, 0.0, 0.0], [0.00096, -0.002183, 0.018547],
                               [0.000998, 0.003762, -0.057232], [0.0, -0.4, 0.1],
                               [0.0, -1.0, 0.2], [0.0, 0.0, -1e-6], [-1.2, 0.0, 0.0],
                               [0.0, 0.01, 0.0]])
def test_the_fold_check_is_skipped_only_where_the_distortion_cannot_fold(R):
    r'''_cahvor_monotone (no round trip) exactly where g' = 1 + R0 + 3 R1 t + 5 R2 t^2 stays
> 0 for every t = chi^2 >= 0: checked against g' on a dense grid of t (the vertex of the
parabola falls inside it for these R; beyond it a positive R2 only grows g', a
negative one makes it fall below 0 somewhere)'''
    from renderers.raycast_outlines import _cahvor_monotone
    model = CAHVOR(C=[0.0, 0.0, 0.0], A=[0.0, 0.0, 1.0], H=[500.0, 0.0, 512.0],
                   V=[0.0, 500.0, 512.0], O=[0.0, 0.0, 1.0], R=R, width=1024, height=1024)
    t = np.linspace(0.0, 1e7, 2_000_001)
    t = np.concatenate((np.linspace(0.0, 10.0, 100_001), t))
    brute = bool(np.all(1.0 + R[0] + 3.0 * R[1] * t + 5.0 * R[2] * t * t > 0.0))
    assert _cahvor_monotone(model) == brute


def _folding_cahvore():
    r'''A wide CAHVORE (E != 0) whose distortion chi (1 + R1 chi^2 + R2 chi^4) has its maximum
(u = 2.02 at chi = 2.14, 667 px from the centre) inside its image'''
    f = 330.0
    t = math.radians(1.2)
    O = np.array([math.sin(t), 0.3 * math.sin(t), math.cos(t)])
    A = np.array([0.0, 0.0, 1.0])
    return CAHVORE(C=[0.0, 0.0, 0.0], A=A, H=np.array([f, 0, 0]) + 642.1 * A,
                   V=np.array([0, f, 0]) + 478.7 * A, O=O / np.linalg.norm(O),
                   R=[0.0, 0.08, -0.02], E=[0.004, 0.012, -0.003], model_type=3,
                   linearity=0.6, width=1280, height=960)


def _fold_cases():
    r'''(name, model, target name, [Rt_cam_board]): cameras whose distortion folds inside
or just outside their field (R2 < 0), central and noncentral, and catalogue cameras'''
    cases = [("folding", _folding_cahvore(), "dots"), ("folding", _folding_cahvore(), "apriltag")]
    f = 300.0
    A = np.array([0.0, 0.0, 1.0])
    for k, (R, E, L) in enumerate((([0.0, 0.05, -0.03], [0.01, 0.02, -0.01], 0.37),
                                   ([0.0, 0.1, -0.2], [0.0, 0.0, 0.0], 0.0),
                                   ([0.0, 0.02, -0.01], [0.05, 0.05, -0.02], 0.8),
                                   ([0.0, 0.0, -0.005], [0.002, 0.001, 0.0], -0.3))):
        t = math.radians(2.0)
        O = np.array([math.sin(t), -0.5 * math.sin(t), math.cos(t)])
        cases.append((f"synthetic{k}", CAHVORE(
            C=[0.0, 0.0, 0.0], A=A, H=np.array([f, 0, 0]) + 640.0 * A,
            V=np.array([0, f, 0]) + 480.0 * A, O=O / np.linalg.norm(O), R=R, E=E,
            model_type=3, linearity=L, width=1280, height=960), "dots"))
        cases.append((f"synthetic{k}-cahvor", CAHVOR(
            C=[0.0, 0.0, 0.0], A=A, H=np.array([f, 0, 0]) + 640.0 * A,
            V=np.array([0, f, 0]) + 480.0 * A, O=O / np.linalg.norm(O), R=R,
            width=1280, height=960), "dots"))
    cat = load_catalogue()
    for slot in ("1", "17", "21"):
        cases.append((f"slot{slot}", cat.get(slot).model, "dots"))
    return cases


def test_a_board_the_fold_bound_clears_passes_the_round_trip():
    r'''_fold_free (no round trip) only where the round trip passes: on folding cameras
(the maximum of the distortion inside the image or near it) and catalogue cameras, over
poses from the planner (covering the field) and poses pushed towards the image's edges
and closer (boards out to the fold). _fold_free is a sufficient condition: where it
holds, every outline point must be seen by its pixel's ray (the round trip, exact rays,
to 1e-7 of the board's size). On the folding camera it must not clear every pose (its
fourth planned pose reaches past the fold: test_a_board_past_a_folding_distortion_...)'''
    import mrcal

    from renderers.raycast_outlines import (
        MAX_POINTS,
        _fold_free,
        _outline_polylines,
        _round_trip,
        board_features,
    )
    cleared = failed = 0
    for name, model, tname in _fold_cases():
        target = load_target(tname)
        cp = compile_pattern(target.pattern())
        segs, circles = board_features(cp)
        cam = kernels.pack_model(model)
        poses = plan_poses(model, target, n=6, seed=0)
        for Rt in list(poses):
            for shift, scale in ((0.3, 1.0), (0.6, 0.8), (-0.5, 0.7)):
                Rt2 = np.array(Rt, dtype=np.float64)
                Rt2[3] = Rt2[3] * scale + shift * abs(Rt2[3, 2]) * np.array([1.0, 0.6, 0.0])
                poses.append(Rt2)
        for i, Rt in enumerate(poses):
            Rt_ref_board = mrcal.compose_Rt(model.Rt_ref_cam(), Rt)
            status, xy, q, starts, _ = _outline_polylines(segs, circles, Rt_ref_board, cam,
                                                          MAX_POINTS)
            if status != 0:
                continue
            free = _fold_free(cam, Rt_ref_board, cp.f[:4])
            trip = _round_trip(cam, Rt_ref_board, q, xy, starts)
            assert trip or not free, f"{name} pose {i}: cleared but folds"
            cleared += free
            failed += not trip
        if name == "folding" and tname == "dots":
            Rt_ref_board = mrcal.compose_Rt(model.Rt_ref_cam(), poses[4])
            assert not _fold_free(cam, Rt_ref_board, cp.f[:4])
    # the bound clears most boards, and the cases do reach folds
    assert cleared > 50 and failed > 5


def test_a_monotone_cahvor_would_pass_the_fold_check():
    r'''Where the fold check is skipped (navcam 15: a CAHVOR whose distortion increases
everywhere), it would pass: every outline point of every pose is seen by its pixel's ray'''
    import mrcal

    from renderers.raycast_outlines import (
        MAX_POINTS,
        _cahvor_monotone,
        _outline_polylines,
        _round_trip,
        board_features,
    )
    model = load_catalogue().get("15").model
    assert _cahvor_monotone(model)
    target = load_target("dots")
    cp = compile_pattern(target.pattern())
    segs, circles = board_features(cp)
    cam = kernels.pack_model(model)
    for Rt in plan_poses(model, target, n=6, seed=0):
        Rt_ref_board = mrcal.compose_Rt(model.Rt_ref_cam(), Rt)
        status, xy, q, starts, _ = _outline_polylines(segs, circles, Rt_ref_board, cam,
                                                      MAX_POINTS)
        assert status == 0
        assert _round_trip(cam, Rt_ref_board, q, xy, starts)


def test_a_reused_buffer_gives_the_image_a_fresh_one_gives():
    r'''A renderer renders into the buffer of the image its caller dropped, and does not
write again the tiles that already hold their value (the background around the board):
the images are those of a fresh renderer bit for bit, whatever was rendered before
(another pose, another pattern, another background albedo, a board filling the image,
a board behind the camera: blank), and they are read-only (a caller writing into one
would make the buffer's tiles unknown)'''
    model = catalogue_models()["slot15"]
    target = load_target("dots")
    poses = plan_poses(model, target, n=3, seed=0)
    dots = target.pattern()
    dark = dot_pattern(n=8, spacing=0.05, r=0.015, background=0.6)
    behind = board_pose(model, -1.0)
    close = board_pose(model, 0.25, centre=(0.17, 0.17))
    sequence = [(dots, poses[0]), (dots, poses[1]), (dark, close), (dots, poses[2]),
                (dots, behind), (dark, poses[0]), (dots, poses[0]), (dots, poses[0])]
    shared = RaycastRenderer()
    s = RenderSettings(spp=4)
    for pattern, Rt in sequence:
        got = shared.render(model, pattern, Rt, s).image
        want = RaycastRenderer().render(model, pattern, Rt, s).image
        assert np.array_equal(got, want)
        assert not got.flags.writeable
        with pytest.raises(ValueError):
            got[0, 0] = 0.5
        del got, want
