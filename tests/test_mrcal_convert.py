'''Conversion between the JPL models and mrcal.cameramodel'''

import io

import mrcal
import mrcal.cahvor
import numpy as np
import pytest

from reference_models.cahvore import CAHV
from reference_models.errors import NotRepresentableError
from reference_models.jpl_files import model_text
from reference_models.mrcal_convert import from_mrcal, to_mrcal

LENSMODELS = {"CAHV": "LENSMODEL_PINHOLE", "CAHVOR": "LENSMODEL_CAHVOR",
              "CAHVORE": "LENSMODEL_CAHVORE_linearity=0.37"}


def test_theta_not_90_is_refused(catalogue_entry):
    m = catalogue_entry.model
    if abs(m.photogrammetric().theta_deg - 90.0) < 1e-9:
        # slots 17/18 (the M2020 helicopter navcam) are exactly 90 deg
        assert catalogue_entry.key in ("17", "18")
        to_mrcal(m)
        return
    with pytest.raises(NotRepresentableError) as info:
        to_mrcal(m)
    msg = str(info.value)
    assert "mrcal cannot represent" in msg and "orthogonalise" in msg
    assert f"{m.photogrammetric().theta_deg:.6f} deg" in msg


def test_to_mrcal_keeps_pose_and_lensmodel(catalogue_entry):
    m = catalogue_entry.model
    cm = to_mrcal(m, orthogonalise=True)
    m90 = m.with_theta_90()
    assert cm.intrinsics()[0] == LENSMODELS[m.family]
    assert tuple(cm.imagersize()) == (m.width, m.height)
    np.testing.assert_allclose(cm.Rt_ref_cam(), m90.Rt_ref_cam(), rtol=0, atol=1e-15)
    fx, fy, cx, cy = cm.intrinsics()[1][:4]
    ph = m90.photogrammetric()
    # closed-form conversion: a few ulps of room for another CPU; a convention slip is >= 1e-6
    assert (fx, abs(fy), cx, cy) == pytest.approx((ph.Hs, ph.Vs, ph.Hc, ph.Vc), rel=1e-13)
    assert (fy < 0) == m.mirrored


def test_from_mrcal_inverts_to_mrcal(catalogue_entry):
    m90 = catalogue_entry.model.with_theta_90()
    back = from_mrcal(to_mrcal(m90))
    assert back.family == m90.family and (back.width, back.height) == (m90.width, m90.height)
    for name in ("C", "A", "H", "V", "O", "R", "E"):
        if hasattr(m90, name):
            a, b = getattr(m90, name), getattr(back, name)
            assert np.linalg.norm(a - b) <= 1e-12 * max(1.0, np.linalg.norm(a)), name
    assert back.mirrored == m90.mirrored
    if m90.family == "CAHVORE":
        assert back.linearity == m90.linearity


def test_alpha_beta_as_mrcal_cahvor_computes_them(catalogue):
    # mrcal's own .cahvor reader derives alpha, beta from O; ours must agree
    for e in catalogue:
        m90 = e.model.with_theta_90()
        if m90.mirrored:
            continue
        theirs = mrcal.cahvor.read_from_string(model_text(m90))
        ours = to_mrcal(m90)
        assert theirs.intrinsics()[0] == ours.intrinsics()[0]
        np.testing.assert_allclose(theirs.intrinsics()[1], ours.intrinsics()[1],
                                   rtol=1e-13, atol=1e-13, err_msg=e.key)


def test_mirrored_model_projects_with_negative_fy(catalogue):
    m = catalogue.get("SuperCam").model.with_theta_90()
    cm = to_mrcal(m)
    xs = np.linspace(-0.5, m.width - 0.5, 9)
    q = np.stack(np.meshgrid(xs, xs), axis=-1).reshape(-1, 2)
    o, v = m.unproject(q)
    p = o + 5.0 * v
    qm = mrcal.project(mrcal.transform_point_Rt(cm.Rt_cam_ref(), p), *cm.intrinsics())
    np.testing.assert_allclose(qm, q, rtol=0, atol=1e-9)


def test_from_mrcal_refuses_other_lensmodels():
    cm = mrcal.cameramodel(intrinsics=("LENSMODEL_OPENCV4",
                                       np.array([500.0, 500, 320, 240, 0.1, 0, 0, 0])),
                           imagersize=(640, 480))
    with pytest.raises(NotRepresentableError, match="LENSMODEL_OPENCV4 has no JPL equivalent"):
        from_mrcal(cm)


def test_cameramodel_file_round_trip(tmp_path):
    m = CAHV(C=[1, 2, 3], A=[0, 0, 1], H=[800, 0, 320], V=[0, 810, 240], width=640, height=480)
    cm = to_mrcal(m)
    f = io.StringIO()
    cm.write(f)
    back = from_mrcal(mrcal.cameramodel(io.StringIO(f.getvalue())))
    np.testing.assert_allclose(back.H, m.H, atol=1e-9)
    np.testing.assert_allclose(back.V, m.V, atol=1e-9)
    np.testing.assert_allclose(back.C, m.C, atol=1e-12)
