r'''Convert between camval's JPL models and mrcal.cameramodel

SYNOPSIS

    from reference_models.mrcal_convert import to_mrcal, from_mrcal

    cm = to_mrcal(m)                      # NotRepresentableError if theta != 90 deg
    cm = to_mrcal(m, orthogonalise=True)  # the model's theta = 90 version
    m2 = from_mrcal(cm)                   # CAHV, CAHVOR or CAHVORE

    q = mrcal.project(mrcal.transform_point_Rt(cm.Rt_cam_ref(), p), *cm.intrinsics())

mrcal's camera frame is camval's (Rt_ref_cam(): x = H', y = A x H', z = A,
origin C), so the pose is kept exactly. The lens models are

    CAHV    -> LENSMODEL_PINHOLE            fx, fy, cx, cy = Hs, Vs, Hc, Vc
    CAHVOR  -> LENSMODEL_CAHVOR             ... alpha, beta, R0, R1, R2
    CAHVORE -> LENSMODEL_CAHVORE_linearity=L  ... alpha, beta, R0, R1, R2, E0, E1, E2

with O given by its angles in the camera frame, as mrcal/cahvor.py does:
o = R_ref_cam^T O, alpha = atan2(o_x, o_z), beta = asin(o_y).

mrcal's camera frame is an orthonormal rotation, so it cannot hold a model whose
H' and V' are not perpendicular (theta != 90 deg): it would orthogonalise V'
and project differently. to_mrcal refuses such a model unless asked to convert
its theta = 90 version (model.with_theta_90()). A mirrored model (H' x V'
against A, theta = 90) is exact in mrcal with fy = -Vs.
'''

import math
import re

import numpy as np

from .cahvore import CAHV, CAHVOR, CAHVORE
from .errors import ModelError, NotRepresentableError

# decomposing a theta = 90 model gives 90 deg to ~1e-16 rad; anything more is
# a real skew (0.01 deg moves a pixel 500 px from the centre by ~0.1 px)
THETA_90_TOLERANCE = 1e-12


def to_mrcal(model, orthogonalise=False):
    r'''A mrcal.cameramodel with the same projection and pose

SYNOPSIS

    cm = to_mrcal(m)                       # m has theta = 90 deg
    cm = to_mrcal(m, orthogonalise=True)   # converts m.with_theta_90()

ARGUMENTS

- model: CAHV, CAHVOR or CAHVORE
- orthogonalise: if True, convert the model's theta = 90 version instead of
  raising for theta != 90 deg

RETURNED VALUE

A mrcal.cameramodel (LENSMODEL_PINHOLE, LENSMODEL_CAHVOR or
LENSMODEL_CAHVORE_linearity=L) whose Rt_ref_cam is model.Rt_ref_cam(). Raises
NotRepresentableError for theta != 90 deg without orthogonalise.
'''
    import mrcal

    ph = model.photogrammetric()
    if abs(ph.theta - math.pi / 2) > THETA_90_TOLERANCE:
        if not orthogonalise:
            raise NotRepresentableError(
                f"mrcal cannot represent this {model.family}: its H' and V' are "
                f"{ph.theta_deg:.6f} deg apart, and mrcal's camera frame forces 90 deg "
                "(it would orthogonalise V' and project differently); convert the "
                "theta = 90 version with orthogonalise=True (--orthogonalise)")
        model = model.with_theta_90()
        ph = model.photogrammetric()
    Rt_ref_cam = model.Rt_ref_cam()
    R_ref_cam = Rt_ref_cam[:3]
    # a mirrored camera has V' = -(A x H'): a negative fy in mrcal's frame
    fy = -ph.Vs if model.mirrored else ph.Vs
    intrinsics = [ph.Hs, fy, ph.Hc, ph.Vc]
    if model.family == "CAHV":
        lensmodel = "LENSMODEL_PINHOLE"
    else:
        o = model.O @ R_ref_cam
        alpha = math.atan2(o[0], o[2])
        beta = math.asin(max(-1.0, min(1.0, o[1])))
        intrinsics += [alpha, beta, *model.R]
        lensmodel = "LENSMODEL_CAHVOR"
        if model.family == "CAHVORE":
            intrinsics += list(model.E)
            lensmodel = model.mrcal_lensmodel
    return mrcal.cameramodel(intrinsics=(lensmodel, np.array(intrinsics, dtype=np.float64)),
                             imagersize=np.array((model.width, model.height), dtype=np.int32),
                             Rt_ref_cam=np.ascontiguousarray(Rt_ref_cam))


_re_cahvore = re.compile(r"^LENSMODEL_CAHVORE_linearity=(.+)$")


def from_mrcal(cameramodel):
    r'''The JPL model of a mrcal.cameramodel

SYNOPSIS

    m = from_mrcal(mrcal.cameramodel("x.cameramodel"))

LENSMODEL_PINHOLE gives a CAHV, LENSMODEL_CAHVOR a CAHVOR and
LENSMODEL_CAHVORE_linearity=L a CAHVORE of type 3 with linearity L; the pose
(Rt_ref_cam) becomes C and the directions of H', V', A. Other lens models raise
NotRepresentableError.
'''
    lensmodel, intrinsics = cameramodel.intrinsics()
    intrinsics = np.asarray(intrinsics, dtype=np.float64)
    Rt = np.asarray(cameramodel.Rt_ref_cam(), dtype=np.float64)
    W, H = (int(x) for x in cameramodel.imagersize())
    fx, fy, cx, cy = intrinsics[:4]
    Hp, Vp, A = Rt[:3, 0], Rt[:3, 1], Rt[:3, 2]
    kw = dict(C=Rt[3], A=A, H=fx * Hp + cx * A, V=fy * Vp + cy * A, width=W, height=H)
    if lensmodel == "LENSMODEL_PINHOLE":
        return CAHV(**kw)
    m = _re_cahvore.match(lensmodel)
    if lensmodel != "LENSMODEL_CAHVOR" and not m:
        raise NotRepresentableError(
            f"mrcal lens model {lensmodel} has no JPL equivalent; expected LENSMODEL_PINHOLE, "
            "LENSMODEL_CAHVOR or LENSMODEL_CAHVORE_linearity=...")
    alpha, beta = intrinsics[4:6]
    o = np.array((math.sin(alpha) * math.cos(beta), math.sin(beta),
                  math.cos(alpha) * math.cos(beta)))
    O = Rt[:3, :3] @ o
    R = intrinsics[6:9]
    if not m:
        return CAHVOR(**kw, O=O, R=R)
    try:
        linearity = float(m.group(1))
    except ValueError:
        raise ModelError(f"cannot read the linearity of {lensmodel}") from None
    return CAHVORE(**kw, O=O, R=R, E=intrinsics[9:12], model_type=3, linearity=linearity)
