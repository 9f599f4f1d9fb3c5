'''Camera response stages: each against its model's expected statistics'''

import math

import numpy as np
import pytest

from reference_models.cahvore import CAHV, CAHVOR
from renderers.response import STAGES, ResponseChain, ResponseConfigError

FW = 10000.0
FLAT = np.full((1000, 1000), 0.5)


def run(cfg, image=FLAT, **kw):
    return ResponseChain.from_config({"full_well_e": FW, **cfg}).apply(image, **kw)


def test_empty_chain_is_identity():
    img = np.linspace(0, 1, 64 * 48).reshape(48, 64)
    r = run({}, img)
    assert r.image.dtype == np.float32
    assert np.array_equal(r.image, img.astype(np.float32))
    assert r.stages == []


def test_shot_and_read_noise_variance():
    r = run({"shot_noise": {}, "read_noise": {"sigma_e": 30.0}})
    e = r.image.astype(np.float64) * FW
    want = 0.5 * FW + 30.0 ** 2
    assert abs(e.var() / want - 1) < 0.02
    assert abs(e.mean() - 0.5 * FW) < 0.5
    assert [s["stage"] for s in r.stages] == ["shot_noise", "read_noise"]
    assert all(s["seconds"] >= 0 for s in r.stages)


def test_noise_is_deterministic_for_a_seed():
    a = run({"shot_noise": {}, "seed": 4}, FLAT[:50, :50]).image
    b = run({"shot_noise": {}, "seed": 4}, FLAT[:50, :50]).image
    c = run({"shot_noise": {}, "seed": 5}, FLAT[:50, :50]).image
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_dark_current_mean_and_variance():
    r = run({"dark_current": {"rate_e_per_s": 200.0, "exposure_s": 2.0}}, np.zeros((1000, 1000)))
    e = r.image.astype(np.float64) * FW
    assert abs(e.mean() - 400.0) < 0.5
    assert abs(e.var() / 400.0 - 1) < 0.02


def test_global_gain_scales_mean_and_noise():
    r = run({"global_gain": {"gain": 1.5}, "shot_noise": {}}, np.full((1000, 1000), 0.2))
    e = r.image.astype(np.float64) * FW
    assert abs(e.mean() / (0.3 * FW) - 1) < 1e-3
    # gain applies before the charge stages: Poisson on the amplified signal
    assert abs(e.var() / (0.3 * FW) - 1) < 0.02


def test_quantisation_levels():
    ramp = np.linspace(0, 1, 100000).reshape(100, 1000)
    for bits in (8, 10, 12):
        q = run({"quantise": {"bits": bits}}, ramp).image.astype(np.float64)
        n = (1 << bits) - 1
        k = q * n
        assert np.allclose(k, np.round(k), atol=1e-3)
        assert len(np.unique(np.round(k))) == n + 1
        err = (k - ramp * n)
        assert np.max(np.abs(err)) <= 0.5 + 1e-3
        assert abs(err.var() / (1 / 12) - 1) < 0.05


def test_vignetting_cos4_corner_ratio():
    m = CAHV(C=[0, 0, 0], A=[0, 0, 1], H=[500, 0, 319.5], V=[0, 500, 239.5],
             width=640, height=480)
    r = run({"vignetting": {}}, np.ones((480, 640)), model=m)
    alpha = math.atan(math.hypot(319.5, 239.5) / 500.0)
    assert r.image[0, 0] / r.image[240, 320] == pytest.approx(math.cos(alpha) ** 4, rel=1e-5)
    near = math.cos(math.atan(0.5 * math.hypot(1, 1) / 500)) ** 4
    assert r.image[239, 319] == pytest.approx(near, rel=1e-5)


def test_vignetting_cos4_follows_distorted_rays():
    m = CAHVOR(C=[0, 0, 0], A=[0, 0, 1], H=[300, 0, 199.5], V=[0, 300, 149.5],
               O=[0, 0, 1], R=[0, -0.2, 0.05], width=400, height=300)
    r = run({"vignetting": {}}, np.ones((300, 400)), model=m)
    _, v = m.unproject(np.array([0.0, 0.0]))
    assert r.image[0, 0] == pytest.approx(v[2] ** 4, rel=1e-5)


def test_vignetting_measured_profile():
    img = np.ones((101, 101))
    r = run({"vignetting": {"model": "profile", "radius_px": [0, 50, 100],
                            "factor": [1.0, 0.8, 0.5]}}, img)
    assert r.image[50, 50] == pytest.approx(1.0)
    assert r.image[50, 100] == pytest.approx(0.8)
    assert r.image[0, 0] == pytest.approx(0.8 - 0.3 * (50 * math.sqrt(2) - 50) / 50, rel=1e-6)


def _moments(img):
    y, x = np.mgrid[0:img.shape[0], 0:img.shape[1]]
    s = img.sum()
    mx, my = (img * x).sum() / s, (img * y).sum() / s
    return s, mx, my, (img * (x - mx) ** 2).sum() / s, (img * (y - my) ** 2).sum() / s


@pytest.mark.parametrize("cfg", [{"kind": "gaussian", "sigma_px": 2.0},
                                 {"kind": "disc", "radius_px": 3.0}])
def test_psf_preserves_sum_and_centroid(cfg):
    img = np.zeros((64, 64))
    img[30, 33] = 0.5
    img[20:24, 20:26] = 0.1
    r = ResponseChain.from_config({"psf": cfg}).apply(img).image.astype(np.float64)
    s0, mx0, my0, _, _ = _moments(img)
    s1, mx1, my1, _, _ = _moments(r)
    assert s1 == pytest.approx(s0, rel=1e-6)
    assert (mx1, my1) == pytest.approx((mx0, my0), abs=1e-5)


def test_gaussian_psf_variance():
    img = np.zeros((65, 65))
    img[32, 32] = 1.0
    r = ResponseChain.from_config({"psf": {"sigma_px": 2.5}}).apply(img).image.astype(np.float64)
    _, _, _, vx, vy = _moments(r)
    assert vx == pytest.approx(2.5 ** 2 + 1 / 12, rel=1e-3)
    assert vy == pytest.approx(2.5 ** 2 + 1 / 12, rel=1e-3)


def test_disc_psf_radius():
    img = np.zeros((65, 65))
    img[32, 32] = 1.0
    r = ResponseChain.from_config({"psf": {"kind": "disc", "radius_px": 6.0}}).apply(img).image
    # a uniform disc of radius R has variance R^2/4 per axis
    _, _, _, vx, _ = _moments(r.astype(np.float64))
    assert vx == pytest.approx(36 / 4 + 1 / 12, rel=0.02)
    assert r[32, 32 + 8] == 0


def test_motion_blur_moves_light_along_the_velocity():
    img = np.zeros((64, 64))
    img[32, 32] = 0.8
    r = ResponseChain.from_config({"motion_blur": {"velocity_px": [12.0, 0.0]}}).apply(img).image
    s, mx, my, vx, vy = _moments(r.astype(np.float64))
    assert s == pytest.approx(0.8, rel=1e-6)
    assert (mx, my) == pytest.approx((32, 32), abs=1e-6)
    assert vx == pytest.approx(144 / 12, rel=0.03)
    assert vy < 1e-9


def test_saturation_clips_and_blooming_conserves_charge():
    img = np.zeros((40, 5))
    img[20, 2] = 5.0           # five full wells in one pixel
    clipped = run({"saturation": {}}, img).image
    assert clipped[20, 2] == 1.0 and clipped.sum() == 1.0
    r = ResponseChain.from_config({"saturation": {"blooming": True}})
    e = r.stages[0](img * FW, {"full_well_e": FW})
    assert e.sum() == pytest.approx(5 * FW)
    assert np.array_equal(np.nonzero(e[:, 2])[0], [18, 19, 20, 21, 22])
    assert np.all(e[18:23, 2] == FW)
    assert e[:, [0, 1, 3, 4]].sum() == 0


def test_blooming_drains_at_the_column_end():
    img = np.zeros((6, 1))
    img[0, 0] = 3.0
    r = ResponseChain.from_config({"saturation": {"blooming": True}})
    e = r.stages[0](img * FW, {"full_well_e": FW})
    # half of the 2 FW excess goes up and off the sensor
    assert e[:, 0].tolist() == [FW, FW, 0, 0, 0, 0]


def test_hot_and_dead_pixels_are_fixed_patterns():
    cfg = {"hot_pixels": {"fraction": 0.001, "charge_e": 3000.0},
           "dead_pixels": {"fraction": 0.002}}
    img = np.full((200, 300), 0.25)
    a = run(cfg, img).image
    b = run({**cfg, "seed": 99}, img).image
    assert np.array_equal(a, b)
    assert np.sum(a == 0) == 120
    assert np.sum(np.isclose(a, 0.25 + 0.3)) == 60


def test_unknown_keys_name_the_choices():
    with pytest.raises(ResponseConfigError, match="known stages: vignetting, psf"):
        ResponseChain.from_config({"shotnoise": {}})
    with pytest.raises(ResponseConfigError, match="known: sigma_e"):
        ResponseChain.from_config({"read_noise": {"sigma": 3}})
    with pytest.raises(ResponseConfigError, match="known: 8, 10, 12"):
        ResponseChain.from_config({"quantise": {"bits": 9}})
    with pytest.raises(ResponseConfigError, match="needs 'gain'"):
        ResponseChain.from_config({"global_gain": {}})
    with pytest.raises(ResponseConfigError, match="needs the camera model"):
        ResponseChain.from_config({"vignetting": {}}).apply(np.ones((4, 4)))


def test_stages_run_in_physical_order_whatever_the_key_order():
    cfg = {k: v for k, v in reversed(list({
        "vignetting": {"model": "profile", "radius_px": [0, 1], "factor": [1, 1]},
        "psf": {}, "shot_noise": {}, "read_noise": {"sigma_e": 1}, "quantise": {"bits": 8},
    }.items()))}
    chain = ResponseChain.from_config(cfg)
    assert chain.names() == ["vignetting", "psf", "shot_noise", "read_noise", "quantise"]
    assert set(chain.names()) <= set(STAGES)
    assert chain.as_dict()["quantise"] == {"bits": 8}


def test_recorded_parameters_rebuild_the_same_chain():
    # a campaign record lists each stage's params (describe()); they are a complete
    # configuration: the same chain and, for the same seed, the same image bit for bit
    cfg = {"full_well_e": 15000.0, "vignetting": {"model": "profile", "radius_px": [0, 40],
                                                  "factor": [1.0, 0.7]},
           "psf": {"kind": "disc", "radius_px": 1.2}, "motion_blur": {"velocity_px": [2, 1]},
           "global_gain": {"gain": 0.9}, "shot_noise": {},
           "dark_current": {"rate_e_per_s": 5.0}, "hot_pixels": {"fraction": 0.01,
                                                                "charge_e": 900.0},
           "dead_pixels": {"fraction": 0.01}, "saturation": {"blooming": True},
           "read_noise": {"sigma_e": 8.0}, "quantise": {"bits": 10}}
    img = np.linspace(0, 1.2, 48 * 64).reshape(48, 64)
    chain = ResponseChain.from_config(cfg)
    seed = [3, 0, 123456789, 42, 7, 99, 1]       # the runner's per-image seed list
    a = chain.apply(img, seed=seed)
    assert [s["stage"] for s in a.stages] == [c for c in STAGES if c in cfg]
    rebuilt = ResponseChain.from_config(
        {"full_well_e": chain.full_well_e, **{s["stage"]: s["params"] for s in a.stages}})
    assert rebuilt.as_dict() == chain.as_dict()
    b = rebuilt.apply(img, seed=seed)
    assert np.array_equal(a.image, b.image)
    assert not np.array_equal(a.image, chain.apply(img, seed=seed[:-1] + [2]).image)
    assert a.cost() == pytest.approx(sum(s["seconds"] for s in a.stages))
    assert all(s["seconds"] > 0 for s in a.stages)


def test_encoding_curves():
    x = np.array([[0.0, 0.002, 0.0031308, 0.18, 0.5, 1.0, 1.2]])
    s = run({"encoding": {"kind": "srgb"}}, x).image.astype(np.float64)[0]
    # IEC 61966-2-1: linear toe, then 1.055 x^(1/2.4) - 0.055; mid grey 0.18 -> 0.4614
    assert np.allclose(s[:3], 12.92 * x[0, :3], atol=1e-7)
    assert abs(s[3] - 0.46135) < 1e-4 and abs(s[4] - 0.73536) < 1e-4
    assert s[5] == 1.0 and s[6] == 1.0
    g = run({"encoding": {"kind": "gamma", "gamma": 2.2}}, x).image.astype(np.float64)[0]
    assert np.allclose(g[:6], x[0, :6] ** (1 / 2.2), atol=1e-6)
    # before quantisation: 8-bit sRGB levels
    chain = ResponseChain.from_config({"quantise": {"bits": 8}, "encoding": {}})
    assert chain.names() == ["encoding", "quantise"]
    q = chain.apply(x).image.astype(np.float64)[0] * 255
    assert np.allclose(q, np.round(q), atol=1e-3) and round(q[4]) == 188
