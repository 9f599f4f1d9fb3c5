import numpy as np
import pytest
from render_checks import board_pose, small_model

from reference_models.cahvore import CAHVORE
from renderers.warp import PinholeWarp, WarpError, box_downsample


@pytest.mark.parametrize("family", ["CAHV", "CAHVOR", "CAHVORE"])
def test_pinhole_covers_every_ray_with_margin(family):
    m = small_model(family, theta_deg=89.7 if family == "CAHV" else 90.0)
    w = PinholeWarp(m, margin=4.0)
    mx, my = w.map(board_pose() if family == "CAHVORE" else None)
    pin = w.pinhole
    assert mx.shape == (m.height, m.width) and mx.dtype == np.float32
    # every pixel centre lands inside, with the margin plus half a pixel of footprint
    assert mx.min() >= 4.0 and my.min() >= 4.0
    assert mx.max() <= pin.width - 1 - 4.0 and my.max() <= pin.height - 1 - 4.0


@pytest.mark.parametrize("scale", [1.0, 2.0])
def test_pinhole_is_at_least_as_fine_as_the_model(scale):
    m = small_model("CAHVOR")
    mx, my = PinholeWarp(m, scale=scale).map()
    # one model pixel step moves at least `scale` pinhole pixels (to float32 precision)
    step_x = np.hypot(np.diff(mx, axis=1), np.diff(my, axis=1))
    step_y = np.hypot(np.diff(mx, axis=0), np.diff(my, axis=0))
    assert step_x.min() >= scale * (1 - 1e-4)
    assert step_y.min() >= scale * (1 - 1e-4)
    assert min(step_x.min(), step_y.min()) < scale * 1.01  # and not needlessly finer


@pytest.mark.parametrize("family", ["CAHV", "CAHVOR"])
def test_map_sends_each_model_pixel_to_the_pinhole_pixel_of_the_same_ray(family):
    m = small_model(family, theta_deg=89.5 if family == "CAHV" else 90.0)
    w = PinholeWarp(m)
    mx, my = w.map()
    # a point seen by model pixel q projects through the pinhole to map(q)
    rng = np.random.default_rng(1)
    iy, ix = rng.integers(0, m.height, 50), rng.integers(0, m.width, 50)
    q = np.stack((ix, iy), -1).astype(float)
    _, v = m.unproject(q)
    p_ref = v * 1.7
    Rt = m.Rt_ref_cam()
    p_cam = (p_ref - Rt[3]) @ Rt[:3]
    u = w.pinhole.project(p_cam)
    assert np.abs(u[:, 0] - mx[iy, ix]).max() < 1e-4
    assert np.abs(u[:, 1] - my[iy, ix]).max() < 1e-4
    # and the model projects that point back to q
    assert np.abs(m.project(p_ref) - q).max() < 1e-9


def test_noncentral_map_is_exact_on_the_board_plane():
    m = small_model("CAHVORE")
    assert not m.is_central
    w = PinholeWarp(m)
    Rt = board_pose(30, 0.4)
    mx, my = w.map(Rt)
    # board points seen at pixel centres: intersect the true rays with the board plane
    iy, ix = np.mgrid[10:m.height:37, 10:m.width:41]
    q = np.stack((ix.ravel(), iy.ravel()), -1).astype(float)
    o, v = m.unproject(q)
    n, p0 = Rt[:3, 2], Rt[3]
    t = ((p0 - o) @ n) / (v @ n)
    p = o + t[:, None] * v
    u = w.pinhole.project(p)
    assert np.abs(u[:, 0] - mx[iy.ravel(), ix.ravel()]).max() < 1e-4
    assert np.abs(u[:, 1] - my[iy.ravel(), ix.ravel()]).max() < 1e-4
    # the map of a fixed range differs: the pupil moves by millimetres
    mx2, _ = w.map(None)
    assert np.abs(mx2 - mx).max() > 0.01


def _ramp_error_px(interpolation):
    m = small_model("CAHVOR")
    w = PinholeWarp(m)
    pin = w.pinhole
    u, v = np.meshgrid(np.arange(pin.width), np.arange(pin.height))
    s = pin.width + 2 * pin.height
    img = w.apply((u + 2 * v) / s, interpolation)
    mx, my = w.map()
    assert img.shape == (m.height, m.width) and img.dtype == np.float32
    # error in pinhole pixels along the ramp's gradient (length sqrt(5))
    return np.abs(img - (mx.astype(float) + 2 * my) / s).max() * s / np.sqrt(5)


def test_bilinear_samples_pinhole_pixel_centres_at_integers():
    # a linear ramp is reproduced exactly by bilinear interpolation, up to cv2.remap's
    # 1/32 px fixed-point weights: a half-pixel convention slip would cost 0.5 px
    assert _ramp_error_px("bilinear") < 1.0 / 32


def test_bicubic_is_opencvs_keys_kernel_which_bends_ramps():
    # cv2.INTER_CUBIC uses Keys' kernel with a = -0.75, which does not reproduce linear
    # functions: sample values move by up to ~0.06 px of the ramp (measured 0.064);
    # bilinear is the geometrically faithful choice
    err = _ramp_error_px("bicubic")
    assert 0.02 < err < 0.1


def test_scaled_pinhole_blocks_average_to_the_coarse_pixel():
    m = small_model("CAHVOR")
    pin = PinholeWarp(m).pinhole
    K = 4
    fine = pin.scaled(K)
    p = np.array([[0.05, -0.03, 1.2]])
    u = pin.project(p)[0]
    uf = fine.project(p)[0]
    np.testing.assert_allclose(uf, K * (u + 0.5) - 0.5, atol=1e-9)
    a = np.arange(64.0).reshape(8, 8)
    np.testing.assert_allclose(box_downsample(a, 4), [[13.5, 17.5], [45.5, 49.5]])


def test_for_model_caches_per_camera():
    m = small_model("CAHVOR")
    assert PinholeWarp.for_model(m) is PinholeWarp.for_model(m)
    assert PinholeWarp.for_model(m) is not PinholeWarp.for_model(m, scale=2.0)


def test_bad_input():
    m = small_model("CAHVOR")
    w = PinholeWarp(m)
    with pytest.raises(WarpError, match="interpolation"):
        w.apply(np.zeros((w.pinhole.height, w.pinhole.width)), "nearest")
    with pytest.raises(WarpError, match="shape"):
        w.apply(np.zeros((3, 4)))
    with pytest.raises(WarpError, match="scale"):
        PinholeWarp(m, scale=0)
    # a fisheye seeing beyond 90 degrees cannot be covered by a pinhole
    fish = CAHVORE(C=[0, 0, 0], A=[0, 0, 1], H=[100, 0, 128], V=[0, 100, 96],
                   O=[0, 0, 1], R=[0, 0, 0], E=[0, 0, 0], model_type=2, width=256, height=192)
    with pytest.raises(WarpError, match="field of view"):
        PinholeWarp(fish)


def test_area_samples_average_remaps_at_sub_pixel_centres():
    m = small_model("CAHVOR")
    w = PinholeWarp(m, scale=2.0, samples=2)
    assert w.offsets == [(-0.25, -0.25), (0.25, -0.25), (-0.25, 0.25), (0.25, 0.25)]
    # sample 3 is the ray of pixel centre + (0.25, 0.25)
    mx, my = w.map(None, 3)
    _, v = m.unproject(np.array([[10.25, 20.25]]))
    u = w.pinhole.project(v)[0]
    assert abs(mx[20, 10] - u[0]) < 1e-3 and abs(my[20, 10] - u[1]) < 1e-3
    # a linear ramp averages to its value at the pixel centre
    pin = w.pinhole
    uu, vv = np.meshgrid(np.arange(pin.width), np.arange(pin.height))
    img = w.apply(uu / pin.width, "bilinear")
    centre = PinholeWarp(m, scale=2.0).map()[0]
    # the sub-sample mean of a smooth map differs from the centre by its curvature only
    assert np.abs(img - centre / pin.width).max() < 0.05 / pin.width
    with pytest.raises(WarpError, match="samples"):
        PinholeWarp(m, samples=0)


def test_a_field_of_view_no_pinhole_covers_is_not_applicable():
    from reference_models.catalogue import load_catalogue
    from renderers.base import RendererNotApplicable
    from renderers.warp import FieldOfViewError
    wide = load_catalogue().get(8).model     # MER A front hazcam CAHVORE: 92 deg off axis
    with pytest.raises(FieldOfViewError, match="field of view reaches 9[0-9].[0-9] deg") as e:
        PinholeWarp(wide)
    assert isinstance(e.value, RendererNotApplicable) and isinstance(e.value, WarpError)
