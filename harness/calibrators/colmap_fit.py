r'''COLMAP (pycolmap) as a reference calibrator: bundle adjustment with fixed 3D points

SYNOPSIS

    from harness.calibrators import calibrate

    r = calibrate("colmap", obs, target, "OPENCV")   # or "FULL_OPENCV", "OPENCV_FISHEYE"
    r.model.project(p)   # a ColmapModel (COLMAP's own projection, our pixel convention)

What COLMAP is given: the detections and the target's 3D points in the board
frame; the board poses are unknown. What is done, exactly:

1. Seed: fx, fy, cx, cy from the board homographies (cv2.initCameraMatrix2D),
   distortion 0.
2. One image per pose. Its pose (cam_from_world, world = board frame) is
   seeded by pycolmap.estimate_and_refine_absolute_pose with the seed camera.
3. A pycolmap.Reconstruction is built: one camera (trivial rig), one 3D point
   per target point at its surveyed board coordinates, each image's 2D points
   linked to them (tracks). pycolmap's bundle adjuster
   (create_default_bundle_adjuster with a BundleAdjustmentConfig) then refines
   the camera intrinsics (focal length, principal point, extra parameters) and
   every image pose, with ALL 3D points constant (add_constant_point): this is
   bundle adjustment with a known target, i.e. a camera calibration.
4. Bias correction as for the other calibrators: each detection is corrected by
   the dot-centroid bias computed with the current camera and poses, and the
   adjustment repeated (at most bias_passes, until the bias changes by less than
   bias_tolerance px).

COLMAP's pixel convention puts the centre of the top-left pixel at (0.5, 0.5):
detections are shifted by +0.5 px going in, principal points by -0.5 px coming
out (ColmapModel projects in our convention). known_poses is not applicable.
The camera is the reference frame: C, A and theta are not estimated.

Models: "OPENCV" (fx fy cx cy k1 k2 p1 p2), "FULL_OPENCV" (+ k3..k6),
"OPENCV_FISHEYE" (fx fy cx cy k1..k4).
'''

import time

import numpy as np

from harness.quiet import diagnostics_of

from .base import (
    CalibrationFailed,
    CalibrationResult,
    check_homography_conditioning,
    check_pose_diversity,
)
from .skeleton import board_residuals, fitted_result, iterate_bias

NAME = "colmap"
LIBRARY = "pycolmap"
MODELS = ("OPENCV", "FULL_OPENCV", "OPENCV_FISHEYE")
NPARAMS = {"OPENCV": 8, "FULL_OPENCV": 12, "OPENCV_FISHEYE": 8}
# COLMAP's pixel (0, 0) is the corner of the top-left pixel; ours its centre
COLMAP_OFFSET = 0.5


def uses_world_frame(**options):
    r'''False: the adapter estimates the board poses; the fitted camera is its own frame'''
    return False


def library_version():
    import pycolmap
    return f"pycolmap {pycolmap.__version__}"


def canonical_model(name):
    return str(name).upper()


class ColmapModel:
    r'''A camera fitted by COLMAP, projectable by compare.py (our pixel convention)

SYNOPSIS

    m = ColmapModel("OPENCV", params, width, height)   # params in COLMAP's convention
    q = m.project(p)         # p (...,3) in the world frame (= camera frame); q (...,2)
    m.fx, m.fy, m.cx, m.cy   # cx, cy in our convention
'''

    def __init__(self, family, params, width, height):
        self.family = family
        self.params = np.asarray(params, dtype=np.float64)
        self.width, self.height = int(width), int(height)
        self.fx, self.fy = float(self.params[0]), float(self.params[1])
        self.cx = float(self.params[2]) - COLMAP_OFFSET
        self.cy = float(self.params[3]) - COLMAP_OFFSET

    def camera(self):
        import pycolmap
        return pycolmap.Camera(model=self.family, width=self.width, height=self.height,
                               params=self.params.tolist(), camera_id=1)

    def Rt_ref_cam(self):
        return np.vstack((np.eye(3), np.zeros(3)))

    def project(self, p):
        p = np.asarray(p, dtype=np.float64)
        flat = np.ascontiguousarray(p.reshape(-1, 3))
        q = np.full((len(flat), 2), np.nan)
        front = flat[:, 2] > 0
        if front.any():
            q[front] = self.camera().img_from_cam(np.ascontiguousarray(flat[front]),
                                                  check_cheirality=False) - COLMAP_OFFSET
        return q.reshape(p.shape[:-1] + (2,))

    def __repr__(self):
        return f"ColmapModel({self.family}, params={self.params.tolist()})"


def _seed(obs, views, found):
    import cv2
    objs = [obs.p_board[i][found[i]].astype(np.float32) for i in views]
    imgs = [obs.q[i][found[i]].astype(np.float32) for i in views]
    K = cv2.initCameraMatrix2D(objs, imgs, tuple(obs.imagersize), aspectRatio=0)
    if not (np.all(np.isfinite(K)) and K[0, 0] > 0 and K[1, 1] > 0):
        raise CalibrationFailed("degenerate poses: the homographies give no focal length")
    return K


def _Rt_from_rigid(rigid):
    M = np.asarray(rigid.matrix(), dtype=np.float64)
    return np.vstack((M[:, :3], M[:, 3]))


@diagnostics_of(LIBRARY)
def fit(obs, target, model_name, truth=None, known_poses=False, bias_correction=True,
        bias_passes=4, bias_tolerance=1e-5, max_rms=1.0):
    r'''The COLMAP calibrator (see the module docstring); returns a CalibrationResult'''
    import pycolmap

    t0 = time.perf_counter()
    if known_poses:
        return CalibrationResult(
            calibrator=NAME, model_name=model_name, status="not-applicable",
            reason="the colmap adapter estimates the board poses; known_poses is not supported",
            library=LIBRARY, library_version=library_version())
    if not np.allclose(obs.p_board, obs.p_board[0], rtol=0, atol=1e-12):
        raise CalibrationFailed("colmap needs the same target in every pose")
    found = obs.found
    views = [i for i in range(obs.Nposes) if found[i].sum() >= 6]
    if len(views) < 2 or sum(int(found[i].sum()) for i in views) < 30:
        raise CalibrationFailed(f"too few points: {int(found.sum())} found in {len(views)} "
                                "usable poses; colmap needs >= 30 points in >= 2 poses")
    check_homography_conditioning(obs)
    W, H = obs.imagersize
    K = _seed(obs, views, found)
    params = np.zeros(NPARAMS[model_name])
    params[:4] = (K[0, 0], K[1, 1], K[0, 2] + COLMAP_OFFSET, K[1, 2] + COLMAP_OFFSET)
    model = ColmapModel(model_name, params, W, H)
    p_world = obs.p_board[0]

    poses = {}
    for i in views:
        est = pycolmap.estimate_and_refine_absolute_pose(
            obs.q[i][found[i]] + COLMAP_OFFSET, p_world[found[i]], model.camera())
        if est is None:
            raise CalibrationFailed(f"degenerate poses: COLMAP found no pose for pose {i}")
        poses[i] = est["cam_from_world"]

    iterations = 0

    def adjust(q, model, poses):
        nonlocal iterations
        rec = pycolmap.Reconstruction()
        rec.add_camera_with_trivial_rig(model.camera())
        # only observed points: a constant point without observations aborts the process
        # (Ceres: "Parameter block not found ... before it can be set constant")
        seen = np.any(found[views], axis=0)
        point_ids = {j: rec.add_point3D(p_world[j], pycolmap.Track())
                     for j in np.flatnonzero(seen)}
        config = pycolmap.BundleAdjustmentConfig()
        for k, i in enumerate(views):
            idx = np.flatnonzero(found[i])
            pts = pycolmap.Point2DList(
                [pycolmap.Point2D(q[i][j] + COLMAP_OFFSET) for j in idx])
            image = pycolmap.Image(name=f"pose{i}", points2D=pts, camera_id=1,
                                   image_id=k + 1)
            rec.add_image_with_trivial_frame(image, poses[i])
            for n, j in enumerate(idx):
                rec.add_observation(point_ids[j], pycolmap.TrackElement(k + 1, n))
            config.add_image(k + 1)
        for pid in point_ids.values():
            config.add_constant_point(pid)
        options = pycolmap.BundleAdjustmentOptions()
        options.refine_focal_length = True
        options.refine_principal_point = True
        options.refine_extra_params = True
        options.refine_points3D = False
        options.print_summary = False
        cer = options.ceres
        cer.solver_options.max_num_iterations = 500
        cer.solver_options.function_tolerance = 1e-15
        cer.solver_options.gradient_tolerance = 1e-15
        cer.solver_options.parameter_tolerance = 1e-15
        adjuster = pycolmap.create_default_bundle_adjuster(options, config, rec)
        summary = adjuster.solve()
        if not summary.is_solution_usable():
            raise CalibrationFailed(f"diverged: COLMAP's bundle adjustment ended with "
                                    f"{summary.termination_type}")
        iterations += 1  # one bundle adjustment (pycolmap does not expose Ceres' count)
        cam = rec.camera(1)
        new_model = ColmapModel(model_name, np.asarray(cam.params), W, H)
        new_poses = {i: rec.image(k + 1).cam_from_world() for k, i in enumerate(views)}
        return new_model, new_poses

    def Rts_of(poses):
        Rts = np.full((obs.Nposes, 4, 3), np.nan)
        for i in views:
            Rts[i] = _Rt_from_rigid(poses[i])
        return Rts

    check_pose_diversity(Rts_of(poses))
    model, poses = adjust(obs.q, model, poses)
    # once more from the adjusted start: the first adjustment starts from zero distortion
    model, poses = adjust(obs.q, model, poses)
    if not np.all(np.isfinite(model.params)):
        raise CalibrationFailed("diverged: COLMAP returned non-finite intrinsics")
    Rts = Rts_of(poses)
    passes = [{"pass": 1}]

    def refit(q_used, change):
        nonlocal model, poses, Rts
        model, poses = adjust(q_used, model, poses)
        Rts = Rts_of(poses)
        return {"bias_change_max": change}

    q_used, bias_applied = iterate_bias(
        obs, target, lambda: (model, Rts), refit, passes,
        bias_passes=bias_passes if bias_correction and target is not None else 0,
        bias_tolerance=bias_tolerance, views=views)
    return fitted_result(
        NAME, LIBRARY, library_version(), model_name, t0, model=model,
        residuals=board_residuals(model, Rts, obs.p_board, q_used), found=found,
        max_rms=max_rms, Rt_cam_board=Rts, iterations=iterations,
        info={"params_colmap_convention": model.params, "passes": passes,
              "bias_corrected": bias_applied, "world_frame": False, "known_poses": False,
              "points3D": "constant (surveyed board points)"})
