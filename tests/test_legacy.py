import numpy as np
import pytest
from render_checks import board_pose, grid_board, small_model

from renderers.base import RenderSettings, get_renderer
from renderers.legacy import (
    FAULT_PARAMETERS,
    FAULTS,
    LEGACY_DEFECTS,
    FaultNotApplicableError,
    FaultyRenderer,
    UnknownFaultError,
    apply_defects,
    legacy_model,
)

P = np.array([[0.1, -0.05, 1.2], [-0.3, 0.2, 2.0], [0.0, 0.0, 1.0], [0.25, 0.18, 0.9]])


def _moved(model, fault):
    return FAULTS[fault](model).project(P) - model.project(P)


@pytest.mark.parametrize("family", ["CAHV", "CAHVOR", "CAHVORE"])
def test_image_shift_faults_move_every_point_by_the_stated_amount(family):
    m = small_model(family)
    np.testing.assert_allclose(_moved(m, "half_pixel"), -0.5, atol=1e-9)
    d = _moved(m, "shift_001")
    np.testing.assert_allclose(d[:, 0], 0.01, atol=1e-9)
    np.testing.assert_allclose(d[:, 1], 0.0, atol=1e-9)


def test_focal_scale_scales_about_the_centre():
    m = small_model("CAHV")
    ph = m.photogrammetric()
    q = m.project(P)
    q2 = FAULTS["focal_scale"](m).project(P)
    np.testing.assert_allclose(q2[:, 0] - ph.Hc, (q[:, 0] - ph.Hc) * (1 + 1e-4), atol=1e-9)
    np.testing.assert_allclose(q2[:, 1] - ph.Vc, (q[:, 1] - ph.Vc) * (1 + 1e-4), atol=1e-9)


def test_swap_hv_transposes_the_image():
    m = small_model("CAHV")
    np.testing.assert_allclose(FAULTS["swap_hv"](m).project(P), m.project(P)[:, ::-1],
                               atol=1e-9)


def test_distortion_faults_and_where_they_do_not_apply():
    m = small_model("CAHVORE")
    assert FAULTS["r1_sign"](m).R[1] == -m.R[1]
    assert np.all(FAULTS["ignore_e"](m).E == 0) and np.any(m.E != 0)
    # the pupil moves by a fraction of a millimetre: visible close up and off axis
    near = np.array([[0.05, 0.04, 0.06]])
    assert np.abs(FAULTS["ignore_e"](m).project(near) - m.project(near)).max() > 0.05
    with pytest.raises(FaultNotApplicableError, match="CAHVOR or CAHVORE"):
        FAULTS["r1_sign"](small_model("CAHV"))
    with pytest.raises(FaultNotApplicableError, match="needs a CAHVORE"):
        FAULTS["ignore_e"](small_model("CAHVOR"))


def test_roams_defects():
    m = small_model("CAHV", hc=128.3, vc=95.74, theta_deg=89.83)
    m = m.with_photogrammetric(type(m.photogrammetric())(
        Hc=128.3, Vc=95.74, Hs=250.37, Vs=249.12, Hp=m.photogrammetric().Hp,
        Vp=m.photogrammetric().Vp))
    ph = LEGACY_DEFECTS["round_centre"](m).photogrammetric()
    assert (ph.Hc, ph.Vc) == pytest.approx((128.5, 95.5), abs=1e-9)
    ph = LEGACY_DEFECTS["rounded_aspect"](m).photogrammetric()
    assert ph.Hs / ph.Vs == pytest.approx(1.01, abs=1e-12) and ph.Vs == pytest.approx(249.12)
    assert LEGACY_DEFECTS["theta90"](m).photogrammetric().theta_deg == pytest.approx(90, abs=1e-9)
    cahvor = small_model("CAHVOR", theta_deg=89.83)
    assert LEGACY_DEFECTS["theta90"](cahvor) is cahvor   # ROAMS's CAHVOR warp kept theta
    f = LEGACY_DEFECTS["float32"](m)
    assert np.all(f.H == f.H.astype(np.float32)) and np.any(f.H != m.H)
    everything = legacy_model(m)
    ph = everything.photogrammetric()
    assert abs(ph.Hc - 128.5) < 1e-4 and abs(ph.theta_deg - 90) < 1e-4
    assert set(FAULT_PARAMETERS) == set(FAULTS) and len(FAULTS) >= 10


def test_unknown_names():
    with pytest.raises(UnknownFaultError, match="known: round_centre"):
        apply_defects(small_model("CAHV"), fault="half-pixel")
    with pytest.raises(UnknownFaultError, match="legacy defect"):
        legacy_model(small_model("CAHV"), ["round"])
    with pytest.raises(UnknownFaultError):
        FaultyRenderer("raycast", fault="nope")


def test_faulty_renderer_renders_the_defective_model():
    m = small_model("CAHVOR", W=128, H=96, f=125.0)
    pat, _ = grid_board()
    s = RenderSettings(spp=2)
    raycast = get_renderer("raycast")
    res = FaultyRenderer(raycast, fault="half_pixel").render(m, pat, board_pose(), s)
    ref = raycast.render(FAULTS["half_pixel"](m), pat, board_pose(), s)
    np.testing.assert_array_equal(res.image, ref.image)
    assert res.metadata["defects"] == ["half_pixel"]
    assert res.metadata["fault_parameters"] == {"half_pixel": "Hc, Vc"}
    # options select the fault per render
    res2 = FaultyRenderer(raycast).render(
        m, pat, board_pose(), RenderSettings(spp=2, options={"fault": "half_pixel"}))
    np.testing.assert_array_equal(res2.image, ref.image)
    clean = raycast.render(m, pat, board_pose(), s)
    assert np.abs(clean.image - ref.image).max() > 0.1
