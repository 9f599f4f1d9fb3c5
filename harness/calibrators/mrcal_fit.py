r'''mrcal as a reference calibrator: CAHVOR, CAHVORE, OPENCV8, splined

SYNOPSIS

    from harness.calibrators import calibrate

    r = calibrate("mrcal", obs, target, "CAHVOR")                    # board poses estimated
    r = calibrate("mrcal", obs, target, "CAHVORE", truth=truth)      # linearity from truth
    r = calibrate("mrcal", obs, target, "CAHVOR", known_poses=True)  # boards held at the survey
    r.model              # CAHVOR/CAHVORE (reference_models), or MrcalModel (OPENCV8, SPLINED)
    r.info["cameramodel"]  # the mrcal.cameramodel itself (not JSON-serialised)

Models: "CAHV" (LENSMODEL_PINHOLE), "CAHVOR" (LENSMODEL_CAHVOR), "CAHVORE"
(LENSMODEL_CAHVORE_linearity=L; L from a CAHVORE truth, else the option
linearity), "OPENCV8" (LENSMODEL_OPENCV8), "SPLINED"
(LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=16_Ny=12_fov_x_deg=F, F from the
seed's field of view); any "LENSMODEL_..." string is accepted as well.

What mrcal is given: the detections and the target's geometry (it must be a
regular grid: mrcal's calibration object). By default the board poses are
unknown and estimated (the usual calibration; the camera is the reference
frame, so the fitted model's C and A are not comparable with the truth's). With
known_poses=True the boards are held at the surveyed poses Rt_ref_board and
mrcal fits the camera's pose in the world frame instead.

The recipe (../shared/FINDINGS.md): seed fx, fy, cx, cy from the board
homographies (cv2.initCameraMatrix2D), board poses from
mrcal.estimate_monocular_calobject_poses_Rt_tocam, a pinhole solve, then the
lens model with distortions frozen, then everything (restarted while it gains, on
every other row and column of the grid first, then on all of it; a CAHVOR or
CAHVORE fit jumps on along its R0 / focal-length valley after each restart:
VALLEY_JUMP_MAX). No outlier rejection.
Regularisation is off (it biases fx/R0 by up to 100 px on exact data) except
for the splined model, which needs it. mrcal's rms_reproj_error__pixels is per
coordinate and includes regularisation: residuals are computed here, per
point. Bias correction as for jpl: each detection is corrected by the dot
centroid bias computed with the current model and estimated board poses, and
the solve repeated until the bias changes by less than bias_tolerance px (or
BIAS_RELATIVE x the RMS residual). Between bias passes the solver restarts on
the coarse grid only; once the bias has settled, the fit is polished on the
full grid and the bias checked again against that model.

mrcal has no theta: its camera frame is orthonormal, so the fitted CAHVOR has
theta = 90 deg exactly; compare.py reports theta as not estimated. Its
LENSMODEL_CAHVOR reaches a skewed camera only in a limit: with e = 1 + R0 -> 0
and fx e, fy e, R1/e, R2/e held, the projection tends to a CAHVOR whose optical
axis is O and whose image axes are skewed by o_x o_y / o_z^2 rad (o = O in
the camera frame). For a truth with theta != 90 deg the optimum lies at infinity:
the solver runs off along that valley (Rocky8 navcam, slot 21, theta 90.0106 deg:
R0 -> -0.975, fx 2900 -> 117000 px, skew -> 0.0099 deg) and stops where the
restarts gain less than POLISH_GAIN, or where the restarts of a fit found to
misfit end (residuals far above the noise: crawl_verdict, then restarted once;
still so once the bias settled, settled_misfit_verdict: on the coarse grid).
The projection is then close (0.03 px there; 0.0005 px for the MER A hazcam,
slot 5) while fx, cx and R are far from the truth's.
'''

import functools
import math
import time

import numpy as np

from harness.quiet import diagnostics_of
from reference_models.cahvore import FAMILIES

from .base import CalibrationFailed, check_homography_conditioning, check_pose_diversity
from .skeleton import applied_bias, fitted_result, iterate_bias, start_bias

NAME = "mrcal"
LIBRARY = "mrcal"
MODELS = ("CAHV", "CAHVOR", "CAHVORE", "OPENCV8", "SPLINED")
SPLINED_NX, SPLINED_NY = 16, 12
# an RMS residual below this (px) is an exact fit: no second start is tried
EXACT_RMS = 1e-7
# restarts of mrcal.optimize continue while each gains more than 1% in RMS (POLISH_GAIN), or
# more than 0.1% (POLISH_GAIN_FINE) once the RMS is below FINE_RMS px: only exact or nearly
# exact data get there, and there a slow crawl still reaches the exact model (the exact-recovery
# tests hold it to 1e-6 px). Each restart that does not converge costs ~0.45 s (mrcal's solver
# at its iteration limit: the R0 / focal-length valley makes its Hessian singular, "CHOLMOD
# warning: not positive definite", and its dogleg falls back to gradient steps): 0.1% everywhere
# took 119 s on 14 jobs of the paper campaign.
# Where the CPU goes (benchmarks/bench_fits.py on the paper campaign, session 8): 32 CPU s of
# image fits over 39 jobs, 85% of it inside mrcal.optimize, mostly restarts that end at
# libdogleg's iteration limit (CAHVOR: 0.037 s on the coarse grid, 0.145 s on the full one).
# 78% of it is in the 18 jobs whose floor is far (verdict floor_far: theta != 90 deg, or a
# CAHVORE that mrcal's LENSMODEL_CAHVORE does not reach; floors 0.015-12.7 px), where the
# restarts crawl until max_restarts. The crawl is the problem's, not libdogleg's: MINPACK's
# LM on mrcal.optimizer_callback's Jacobian took 1000-2000+ evaluations in the same valleys
# (5 and 15 CAHVOR) and stopped elsewhere (5 CAHVOR: 5.205e-4 vs 5.127e-4 px). And these fits
# are chaotic: the bias correction computed 1e-10 px differently (the compiled projection)
# moved the gauge figures R0 and R0_frac by 1e4-1e9 sigma (17 and 21 CAHVOR, 2 CAHVORE) and 17
# CAHVOR's projection difference by 0.4 sigma, and doubled 5 CAHVOR's CPU (0.75 -> 1.53 s). So
# any change of this recipe moves those records by more than their sigma.
# A crawl that spends the whole budget far above the noise is a misfit (crawl_verdict): from
# then on each polish restarts once (19, 21, 22 CAHVOR of the paper campaign, all floor_far:
# mrcal image fits 2.84, 2.63, 1.87 -> 1.38, 1.55, 1.35 CPU s, benchmarks/bench_fits.py, load
# 16; every other record bit for bit the same). No local test stops a crawl sooner: 5 CAHVOR
# (theta 90.018 deg, reached through the R0 gauge) crawls at 30x its noise with gains of 1-2%
# for 16 restarts, then converges to a floor of 2e-6 px; 21 CAHVOR crawls at 35x with gains
# of 1-4% to the end of its budget. A rule on RMS / noise and gain that stopped the second
# would stop the first, a judged record.
# The same test once the bias has settled (settled_misfit_verdict, after the settled polish's
# coarse restarts, which end by their gain rule): a misfit there restarts the full grid once
# (paper campaign, session 10, every mrcal record refitted in-process on the campaign's own
# detections, load 10-13: image-fit solves 892 -> 847, CPU of the floor-far records' image
# fits 33.3 -> 26.9 s; every judged record and every floor_far / fits_disagree flag bit for
# bit the same; floor-far records move where their valley's crawl stops, projection RMS
# by 0.6-14 sigma of a renderer difference they are not judged by).
# From a misfit's verdict confirmed once the bias settled (settled_misfit_verdict) on, a model
# with distortions (the valley's) is fitted on the coarse grid alone (misfit_coarse), its
# image fit and the exact fit warm-started from it alike:
# the full grid's single restart crawled the same valley at 4x the cost per call (0.1-0.3 s:
# libdogleg's iteration limit), and that restart and the exact fit's were 8 of the 33 CPU s
# of mrcal in the paper campaign. Measured there (session 11, benchmarks/bench_fits.py,
# load 4-6): mrcal calibrate 25.1 -> 22.1 CPU s, its exact fits 7.9 -> 3.5 CPU s; every judged
# record and every status, floor_far and fits_disagree flag bit for bit the same (no judged
# fit gets a settled verdict; the clean renderer gate on every catalogue slot and extra
# passes, its one judged record with an unconfirmed crawl, MCAM_Z_RIGHT-Z034 CAHVOR, bit for
# bit the same); the floor-far CAHVOR / CAHVORE records' total projection errors move by
# -2.2% .. +11.3% (where the coarse fit of a model that cannot represent the camera stops),
# their renderer differences by -0.10 .. +0.03 px (the exact fit's crawl no longer in them).
POLISH_GAIN = 0.99
POLISH_GAIN_FINE = 0.999
FINE_RMS = 5e-4
# The two starts are polished RACE_RESTARTS restarts each; the better one goes on. Its full
# polish comes after the first bias correction (which moves the detections by up to ~1 px on
# wide lenses, so polishing before it is mostly wasted): 73 -> 50 s CPU on 17 paper jobs,
# projection differences within 2% of the full race (4 of them slightly better). One restart
# each instead of two: 65 -> 49 s CPU on the same jobs; the projection differences move both
# ways (6 better, 6 worse, by up to 40%: where a crawl along the R0 valley stops), and every
# catalogue model is still recovered exactly (tests/test_mrcal_fit.py).
RACE_RESTARTS = 1
# polish() restarts on every COARSE_STEP-th row and column of the grid first (a quarter of the
# points: a quarter of the time per restart), then on the full grid (0 or 1: full grid only);
# the race of the two starts is run on that coarse grid alone (the regularised solve of the
# first start on the full grid: from a coarse one, the misfitting CAHVOREs ended 5-40% worse).
# With the one-restart race: 49 -> 30 s CPU on the 17 pickled paper jobs; the projection
# differences are within 6% of the full-grid recipe or better (16 and 17 CAHVOR 3x and 12x
# better, one 12 CAHVOR 19% worse); every catalogue model is still recovered exactly.
COARSE_STEP = 2
# Bias passes stop when the bias changes by less than bias_tolerance px or by less than
# BIAS_RELATIVE x the RMS residual (a change far below what the model cannot fit anyway).
BIAS_RELATIVE = 0.05
# A warm start (fit(start=...): harness.verdict's fit of the exact observations from the
# image fit) restarts mrcal.optimize at most this many times per polish: the start is
# within the detection error (~1e-3 px) of the exact observations' optimum of the same
# minimum, and the restarts' crawl along the R0 / focal-length valley is what carried a
# cold exact fit into another minimum than the image fit's (mrcal CAHVOR, cameras 5, 17).
# (Up to 3 restarts while each gained, on the full grid: 13 CAHVOR's exact fit went from
# 1.6e-5 to 3e-9 px RMS, but the misfits crawl through all 3 on every polish: 19 CAHVOR's
# exact fit 0.29 -> 0.95 CPU s.) Its fit is made to the detections corrected by the bias
# the start computed at its final model (_start_bias), and that bias is held (no bias pass),
# as jpl's and OpenCV's warm fits hold theirs (skeleton.iterate_bias's b_start says why:
# the verdict's scatter holds the bias too, and the bias's convergence error cancels in the
# renderer difference): one polish. The bias pass it replaces (its bias step projects every dot's
# outline) cost 1.48 -> 0.84 CPU s of the paper campaign's mrcal exact fits (bench_fits on
# the paper renders, idle); judged renderer projections moved <= 0.004 sigma.
# A warm fit has no valley LM (valley needs warm None) and no valley jump: its restarts are
# mrcal.optimize's. 16 CAHVOR's exact fit of the paper campaign ends at 3.8e-4 px RMS on
# exact observations (the clean gate's joint chi2/dof ~1e8 comes from it), R0 13.4 off the
# truth's (e ~ 14, fx e held). Tried (session 16, in-process, not kept): the valley LM with
# the strict rule in the warm polish: 3.84e-4 -> 3.75e-4 px after its 100 steps, renderer
# projection 4.7e-6 -> 9.4e-4 px: the LM crawls there too, so that minimum lies far along
# the R0 gauge and more iterations of either solver do not reach it.
WARM_RESTARTS = 1
# LENSMODEL_CAHVOR's R0 / focal-length valley: a restart of mrcal.optimize crawls along it
# at libdogleg's iteration limit (300 steps of a trust region held at ~0.02 by the valley's
# curvature, rho ~0.57: 37 ms on the coarse grid), 1-10% of RMS per restart: 23 restarts
# for 13 CAHVOR of the paper campaign (R0 -0.15 -> -0.46, fx 4259 -> 6689 px, fx e held).
# So after each restart that moved (valley_jump), the state is moved on along the restart's
# own step in the valley's natural coordinates (log fx, log fy, cx, cy, alpha, beta, log e,
# R1 / e, R2 / e; e = 1 + R0: the gauge family of the module docstring), t = 1, 2, 4, ...
# VALLEY_JUMP_MAX times that step, with the core and board poses settled to each (a
# distortion-frozen solve, ~0.5 ms), while the RMS falls; the best is kept and the restarts
# go on from it. A restart and its jump gain together (the stop rule's gain): a jump puts
# the state where the next restart settles the distortions rather than crawls. The linear
# extrapolation alone, without that settling solve, left the valley's floor at a quarter of
# one restart's step (RMS x30). Jumps keep the principal point inside the image: the
# valley's limit of a misfit (e -> 0, a skew emulated) ran 1 CAHVOR's cx to -3e4 px and its
# projection 1e8 px off at the corners. Measured (paper campaign, bench_mrcal.py --stages,
# load 5-6): CAHVOR image fits 12.1 -> 8.5 CPU s (13 CAHVOR 1.19 -> 0.54 s, 5 CAHVOR
# 0.70 -> 0.31 s: 4 refit restarts reach its minimum at R0 -0.94 where 6 + 10 crawled).
# Judged records end in the same minima; floor-far ones stop elsewhere along their valley
# (most further: lower residuals and floors). LENSMODEL_CAHVORE has the same R terms and
# valley: its E0, E1, E2 are extrapolated as they are (CAHVORE image fits 8.75 -> 7.7 CPU s,
# 5 CAHVORE 0.93 -> 0.60 s, its projection bit for bit at 4 digits).
VALLEY_JUMP_MAX = 8
# A restart of a CAHVOR / CAHVORE fit without a warm start is, instead of mrcal.optimize and
# its valley jump, Levenberg-Marquardt on mrcal.optimizer_callback's Jacobian in the valley's
# natural coordinates (_valley_lm), at most VALLEY_LM iterations (0: mrcal.optimize). The
# coordinates: log fx, log fy, O's image (cx + fx tan(alpha), cy + fy tan(beta) / cos(alpha):
# fixed where e -> 0 runs fx and cx off together), alpha, beta, log e, R1 / e, R2 / e, E;
# without O's image the valley still curves (870 Jacobians for a synthetic 5 CAHVOR against
# 76-115, 0.24 CPU s against the crawl's 1.04). A restart of it that leaves the principal
# point outside the image (a misfit's e -> 0 limit: 1 CAHVOR's projection 6.8e7 px off at the
# corners) is undone and made by mrcal.optimize, and so is every later one of that fit
# (lm_off); refusing its steps that leave the image instead stopped 5 CAHVOR's image fit on
# that edge (0.17 px RMS against 6.8e-4). Measured (session 14, benchmarks/bench_fits.py on
# the paper campaign's renders, back to back, load 6-8): mrcal calibrate 16.3 -> 13.6 CPU s,
# exact fits 2.02 -> 1.68. It converges where mrcal.optimize's crawl along the valley stopped
# short, so records moved where the crawl had held them: 19 CAHVOR reaches the R0 gauge's
# limit (image fit 8.1e-3 -> 7.9e-5 px RMS) and turns from floor_far to judged; judged 16 and
# 17 CAHVOR reach deeper minima (residual RMS 7.46e-4 -> 6.17e-4 and 1.742e-3 -> 1.718e-3
# px; 17's exact fit 3.3e-4 -> 7.8e-9 px, floor 2.8e-3 -> 1e-7 px, renderer difference
# 1.7e-4 -> 3.5e-3 px at z 1.2: the scatter along the valley that the two crawls' common
# stopping point had hidden); the gauge figures at the R0 limit (R0_frac) move by 1e3+
# sigma at 1e-6 relative, beyond any solver's convergence. The clean renderer gate (every
# slot and extra, seeds 0-2) passes with 0 false alarms and judges more: mrcal CAHVOR 22 ->
# 29 records (twins once), CAHVORE 10.
VALLEY_LM = 100
# _valley_lm stops once a step gains less than LM_REL_TOL of the cost in a polish whose fit is
# the record's (final: the one after the bias settled, or the last one), and less than
# LM_STEP_SIGMA^2 x cost / (residuals - parameters) in the others (the race's and the bias
# passes' polishes, whose state only starts the next one). cost / (residuals - parameters)
# is the noise variance of one residual or more (a misfit adds to it), so such a step moves
# the fit by less than ~LM_STEP_SIGMA of its scatter under that noise. With LM_REL_TOL
# everywhere most LM calls ran to VALLEY_LM steps (~0.5 ms each), in misfits' valleys for
# almost nothing (20 CAHVORE: cost 6.929 -> 6.926 over 90 steps). Measured (session 15,
# bench_fits.py on the paper campaign's renders, twice back to back, load 6-14): mrcal
# calibrate 14.53 / 14.01 -> 11.88 / 11.51 CPU s, exact fits 1.78 / 1.74 -> 1.60 / 1.57; the
# LM's Jacobians 7708 -> 4422 over the 25 CAHVOR / CAHVORE image fits. Every
# judged record's renderer figures move <= 0.002 sigma but 16 CAHVOR's (projection 6.7e-5
# -> 5.3e-6 px, 0.08 sigma; its R0 gauge and the floor of its unconverged exact fit move
# along the valley as they do under any change); no flag changes; the worst ok renderer
# projection stays 1 CAHVOR's 9.2e-3 px. Not taken: LM_STEP_SIGMA 0.1 (image fits 11.6 s):
# 20 CAHVOR (floor far) then ends its misfit's crawl elsewhere, renderer 3.6e-3 -> 1.8e-2
# px; the rule in every polish (9.1 s): judged 16 CAHVOR stopped short in its valley
# (residual RMS 6.166e-4 -> 6.281e-4 px, Delta chi^2 ~45).
LM_REL_TOL = 1e-10
LM_STEP_SIGMA = 0.03
# Where the CPU goes now and what did not pay (session 13, benchmarks/bench_mrcal.py --stages
# on its 25 CAHVOR / CAHVORE paper jobs, load 9-12): image fits 16.7 CPU s, 84% inside
# mrcal.optimize (cProfile); by phase: the refits' coarse restarts 7.0 s (178 calls, 39 ms:
# libdogleg's iteration limit), the race's coarse restarts 2.6 s, its regularised full-grid
# start with the pinhole solves 2.4 s, the settled polish 1.1 s full + 0.9 s coarse; exact
# fits 2.0 s. Tried, measured, not taken:
# - the settled polish skipping the coarse restarts its refit had just ended by the gain rule
#   (same observations, no solve between): image fits -1.6 CPU s, but the clean renderer gate
#   lost a judged record (2 CAHVORE, pose seed 1, theta 89.84 deg): there the repeated
#   restart gained again and went on to the R0 gauge's limit (exact fit 2.9e-7 px RMS);
#   without it the settled misfit verdict fell on the refit's state (0.9 px, 19x its noise
#   estimate) and the floor came out far. A restart after one that gained < POLISH_GAIN can
#   gain again: the gain rule's end is no fixed point.
# - restarts ending once one moved the fitted projections by less than the noise's scatter
#   in them (grid_noise_rms x sqrt(parameters / coordinates)): 28 of 280 restarts fewer,
#   image fits -2%; but grid_noise_rms errs high on a misfit (0.047 px on that 2 CAHVORE,
#   whose detection noise was 7.8e-5 px): the unsafe side for a stop rule, open to the
#   same failure (not gated).
# - the warm exact fit straight to the full grid: no faster (its full-grid restart crawls
#   instead) and less exact (13 CAHVOR's exact fit 9e-8 -> 2e-5 px RMS, floor 5e-7 -> 4.5e-4
#   px): the coarse restart is the cheap part of its convergence.
# - VALLEY_JUMP_MAX 1024: the same (jumps end where the RMS rises, not at the cap).
# - the race's regularised start solved on the coarse grid first: the full-grid solve after
#   it still runs to the iteration limit (3 CAHVOR 148 -> 37 + 147 ms): the regularised
#   problem has the valley too (it stops at fx 2288 or 2473 px depending on the start).
# - nor is there a floor-far record's cost left after its misfit verdict for any other rule
#   to take: on the 25 jobs above (load 14-17), 14.14 of the 14.30 CPU s of mrcal.optimize
#   in image fits come before the first crawl_verdict / settled_misfit_verdict (the settled
#   one falls after the settled polish's coarse restarts, the last of a fit's work; only
#   21 CAHVOR gets a crawl_verdict, at call 51 of 53). The judged records (5, 13, 15, 16,
#   17 CAHVOR, 5, 17, 19 CAHVORE) take 3.9 s of it, the floor-far ones 10.4 s.


def uses_world_frame(known_poses=False, **options):
    r'''Whether the fit reads the surveyed board poses: only with known_poses=True'''
    return bool(known_poses)


@functools.cache
def library_version():
    # importlib.metadata reads the installed distributions' metadata (~1.7 ms a call, once
    # per fit, image and exact): the installed version does not change within a process
    import importlib.metadata
    return f"mrcal {importlib.metadata.version('mrcal')}"


def canonical_model(name):
    name = str(name)
    if name.startswith("LENSMODEL_"):
        short = {"LENSMODEL_PINHOLE": "CAHV", "LENSMODEL_CAHVOR": "CAHVOR",
                 "LENSMODEL_OPENCV8": "OPENCV8"}.get(name)
        if short:
            return short
        if name.startswith("LENSMODEL_CAHVORE"):
            return "CAHVORE"
        if name.startswith("LENSMODEL_SPLINED_STEREOGRAPHIC"):
            return "SPLINED"
        return name
    return name.upper()


class MrcalModel:
    r'''A mrcal.cameramodel that compare.py can evaluate (any lens model)

SYNOPSIS

    m = MrcalModel(cameramodel, family="OPENCV8")
    q = m.project(p)          # p (...,3) in the world frame; q (...,2)
    m.Rt_ref_cam(), m.fx, m.fy, m.cx, m.cy, m.width, m.height
'''

    def __init__(self, cameramodel, family):
        self.cameramodel = cameramodel
        self.family = family
        self.lensmodel, intrinsics = cameramodel.intrinsics()
        self.intrinsics = np.asarray(intrinsics, dtype=np.float64)
        self.fx, self.fy, self.cx, self.cy = (float(x) for x in self.intrinsics[:4])
        self.width, self.height = (int(x) for x in cameramodel.imagersize())

    def Rt_ref_cam(self):
        return np.asarray(self.cameramodel.Rt_ref_cam(), dtype=np.float64)

    def project(self, p):
        import mrcal
        Rt = self.Rt_ref_cam()
        p_cam = (np.asarray(p, dtype=np.float64) - Rt[3]) @ Rt[:3]
        return mrcal.project(np.ascontiguousarray(p_cam), self.lensmodel, self.intrinsics)

    def __repr__(self):
        return f"MrcalModel({self.lensmodel}, intrinsics={self.intrinsics.tolist()})"


def _grid(p_board):
    r'''(spacing, nx, ny, ix, iy, origin) of a regular planar grid of points'''
    p = np.asarray(p_board, dtype=np.float64)
    if np.any(np.abs(p[:, 2]) > 1e-9):
        raise CalibrationFailed("mrcal needs a planar grid target (z = 0); this target is not")
    origin = p.min(axis=0)
    d = p[:, :2] - origin[:2]
    nz = np.abs(d[d > 1e-9])
    if nz.size == 0:
        raise CalibrationFailed("too few points: the target has no extent")
    spacing = float(nz.min())
    idx = np.round(d / spacing)
    if np.max(np.abs(idx * spacing - d)) > 1e-9 * max(1.0, spacing):
        raise CalibrationFailed(f"mrcal's calibration object is a regular grid; the points of "
                                f"this target are not on one (spacing {spacing:g} m)")
    ix, iy = idx[:, 0].astype(int), idx[:, 1].astype(int)
    nx, ny = ix.max() + 1, iy.max() + 1
    if nx * ny != len(p) or len(set(zip(ix, iy, strict=True))) != len(p):
        raise CalibrationFailed(f"mrcal needs a full {nx}x{ny} grid; the target has "
                                f"{len(p)} points")
    return spacing, nx, ny, ix, iy, origin


def _lensmodel(model_name, truth, linearity, fov_x_deg):
    if model_name == "CAHV":
        return "LENSMODEL_PINHOLE"
    if model_name == "CAHVOR":
        return "LENSMODEL_CAHVOR"
    if model_name == "OPENCV8":
        return "LENSMODEL_OPENCV8"
    if model_name == "CAHVORE":
        if truth is not None and getattr(truth, "family", None) == "CAHVORE":
            linearity = truth.linearity
        if linearity is None:
            linearity = 1.0
        return f"LENSMODEL_CAHVORE_linearity={float(linearity)!r}"
    if model_name == "SPLINED":
        return (f"LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx={SPLINED_NX}_Ny={SPLINED_NY}_"
                f"fov_x_deg={int(math.ceil(fov_x_deg))}")
    raise CalibrationFailed(f"no mrcal lens model for {model_name!r}")


def _seed_pinhole(obs, found):
    r'''fx, fy, cx, cy from the board homographies (Zhang), via OpenCV'''
    import cv2
    objs, imgs = [], []
    for i in range(obs.Nposes):
        f = found[i]
        if f.sum() >= 6:
            objs.append(obs.p_board[i][f].astype(np.float32))
            imgs.append(obs.q[i][f].astype(np.float32))
    if len(objs) < 2:
        raise CalibrationFailed(f"too few points: only {len(objs)} poses with >= 6 detections; "
                                "mrcal's seed needs at least 2")
    K = cv2.initCameraMatrix2D(objs, imgs, tuple(obs.imagersize), aspectRatio=0)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    if not (np.all(np.isfinite([fx, fy, cx, cy])) and fx > 0 and fy > 0):
        raise CalibrationFailed("degenerate poses: the homographies give no focal length")
    return np.array([fx, fy, cx, cy])


def _Rt_board_grid(origin):
    return np.vstack((np.eye(3), origin))


# a pose with fewer detections than this is left out of the fit (mrcal seeds each board
# pose by a homography / PnP, which needs 4 points off one line; 6 is the Zhang seed's
# own minimum above, so a kept pose contributes to the seed too)
MIN_POSE_POINTS = 6


@diagnostics_of(LIBRARY)
def fit(obs, target, model_name, truth=None, start=None, **options):
    r'''The mrcal calibrator (see the module docstring); returns a CalibrationResult

Poses with fewer than MIN_POSE_POINTS detections are left out (a detector that found
no dot in an image must not fail the fit: mrcal's PnP seed needs points in every
pose it is given); info["poses_dropped"] lists them with their counts, and their
residuals and board poses are NaN. The rest as _fit_poses.
'''
    counts = obs.found.sum(axis=1)
    views = np.flatnonzero(counts >= MIN_POSE_POINTS)
    if len(views) == obs.Nposes or len(views) < 2:
        return _fit_poses(obs, target, model_name, truth=truth, start=start, **options)
    sub = obs.replace(q=obs.q[views], p_board=obs.p_board[views],
                      Rt_ref_board=None if obs.Rt_ref_board is None else obs.Rt_ref_board[views],
                      corner_model=None if obs.corner_model is None else obs.corner_model[views],
                      corner_blur_px=None if obs.corner_blur_px is None
                      else obs.corner_blur_px[views],
                      corner_spans=None if obs.corner_spans is None else obs.corner_spans[views],
                      corner_sigma_px=None if obs.corner_sigma_px is None
                      else obs.corner_sigma_px[views])
    if start is not None and getattr(start, "Rt_cam_board", None) is not None \
            and len(start.Rt_cam_board) == obs.Nposes:
        info = dict(start.info or {})
        for k in ("bias", "bias_settled"):
            b = info.get(k)
            info[k] = None if b is None or len(b) != obs.Nposes else b[views]
        start = start.replace(Rt_cam_board=start.Rt_cam_board[views], info=info)
    res = _fit_poses(sub, target, model_name, truth=truth, start=start, **options)
    dropped = [{"pose": int(i), "found": int(counts[i]),
                "reason": f"{int(counts[i])} points found; mrcal's pose seed needs "
                          f"{MIN_POSE_POINTS}"}
               for i in range(obs.Nposes) if i not in set(views.tolist())]
    changes = {"info": {**res.info, "poses_dropped": dropped}}
    for k in ("bias", "bias_settled"):   # NaN where dropped
        if res.info.get(k) is not None:
            b = np.full(obs.q.shape, np.nan)
            b[views] = res.info[k]
            changes["info"][k] = b
    if res.residuals is not None:
        r = np.full(obs.q.shape, np.nan)
        r[views] = res.residuals
        changes["residuals"] = r
    if res.Rt_cam_board is not None:
        Rt = np.full((obs.Nposes, 4, 3), np.nan)
        Rt[views] = res.Rt_cam_board
        changes["Rt_cam_board"] = Rt
    return res.replace(**changes)


def _fit_poses(obs, target, model_name, truth=None, known_poses=False, bias_correction=True,
               bias_passes=4, bias_tolerance=1e-5, regularization=None, max_rms=1.0,
               linearity=None, max_restarts=25, start=None):
    r'''The mrcal fit of every pose of obs (see fit)

start: None, or an ok CalibrationResult of this calibrator and model on observations of
the same poses (harness.verdict: the image fit, to fit the exact observations): its
intrinsics and board poses are the starting point; the board pose estimate, the pinhole
solve, the staged model and the race of two starts are skipped, and each polish restarts
mrcal.optimize at most WARM_RESTARTS times: the fit stays in the start's minimum. A
start of another lens model or without every board pose is ignored (info["warm_start"]
says which); info["moved_from_start"] says whether the warm fit moved from it at all. The
start's bias (_start_bias) corrects the detections, and is held: no bias pass follows
(WARM_RESTARTS says why).
info["bias"] is the bias the last fit was made with (skeleton.applied_bias);
info["bias_settled"] the bias computed at the final model when the last bias pass found
the bias settled (None otherwise): within the tolerance of info["bias"], which for mrcal
is BIAS_RELATIVE x the RMS residual (~5e-5 px on a rendered image), and what a warm
fit's first fit starts from.

info["crawl"], when present: the restarts of a polish ran out of their budget
(max_restarts) still gaining, with residuals far above the noise (crawl_verdict), or
the coarse restarts of the polish after the bias settled ended far above it
(settled_misfit_verdict, "restarts": 0): from then on every polish restarts once, and
the entry says why in words. Where the residuals still misfit once the bias has
settled ("settled": True), a model with distortion parameters restarts on the coarse
grid only from then on (its final fit is the coarse grid's: the full grid's restart
crawls the same valley at 4x the cost), and a warm fit from such a start inherits the
entry ("from_start": True): its fit of the exact observations is the same coarse fit.
'''
    import mrcal

    t0 = time.perf_counter()
    if known_poses and not obs.has_world_points:
        raise CalibrationFailed("known_poses=True needs the surveyed board poses "
                                "(Observations.Rt_ref_board)")
    spacing, nx, ny, ix, iy, origin = _grid(obs.p_board[0])
    if not np.allclose(obs.p_board, obs.p_board[0], rtol=0, atol=1e-12):
        raise CalibrationFailed("mrcal needs the same target in every pose")
    found = obs.found
    nfound = int(found.sum())
    if nfound < 30:
        raise CalibrationFailed(f"too few points: {nfound} found, mrcal needs at least 30")
    check_homography_conditioning(obs)
    seed = _seed_pinhole(obs, found)
    W, H = obs.imagersize
    fov = 2.0 * math.degrees(math.atan(0.5 * W / seed[0])) * 1.2
    lensmodel = _lensmodel(model_name, truth, linearity, min(fov, 179.0))
    if regularization is None:
        regularization = model_name == "SPLINED"

    Nposes = obs.Nposes

    def board_obs(q):
        ob = np.zeros((Nposes, ny, nx, 3))
        ok = np.all(np.isfinite(q), axis=-1)
        ob[:, iy, ix, 0] = np.where(ok, q[..., 0], 0.0)
        ob[:, iy, ix, 1] = np.where(ok, q[..., 1], 0.0)
        ob[:, iy, ix, 2] = np.where(ok, 1.0, -1.0)
        return ob

    observations = board_obs(obs.q)
    indices = np.column_stack((np.arange(Nposes), np.zeros(Nposes), -np.ones(Nposes)))
    indices = indices.astype(np.int32)
    nint = mrcal.lensmodel_num_params(lensmodel)
    warm = _warm_start(start, lensmodel, nint, Nposes, origin)
    if warm is not None:   # the start's board poses: no pose estimate to replace
        Rt_cam_grid = warm[1]
    else:
        Rt_cam_grid = mrcal.estimate_monocular_calobject_poses_Rt_tocam(
            indices, observations, spacing, [("LENSMODEL_PINHOLE", seed)])
        Rt_cam_grid = np.asarray(Rt_cam_grid, dtype=np.float64).reshape(Nposes, 4, 3)
        if not np.all(np.isfinite(Rt_cam_grid)):
            raise CalibrationFailed("degenerate poses: mrcal could not estimate the board "
                                    "poses")
    check_pose_diversity(Rt_cam_grid)
    problem = dict(
        intrinsics=np.zeros((1, nint)),
        rt_cam_ref=None,
        rt_ref_frame=mrcal.rt_from_Rt(Rt_cam_grid),
        points=None,
        observations_board=observations,
        indices_frame_camintrinsics_camextrinsics=indices,
        observations_point=None,
        indices_point_camintrinsics_camextrinsics=None,
        lensmodel=lensmodel,
        imagersizes=np.array([[W, H]], dtype=np.int32),
        calibration_object_spacing=spacing,
        do_apply_outlier_rejection=False,
        do_apply_regularization=bool(regularization),
        do_optimize_calobject_warp=False,
        do_optimize_extrinsics=False,
        do_optimize_frames=True,
    )
    problem["intrinsics"][0, :4] = seed
    if warm is not None:
        problem["intrinsics"][0] = warm[0]
        warm_state = _snapshot(problem)
    unpolished = False   # the race's winner still needs its full polish
    iterations = 0
    stages = []
    start_info = {"warm_start": warm is not None} if start is not None else {}
    bias_runs = bias_correction and bias_passes > 0 and target is not None
    b_start = None
    if warm is not None:
        max_restarts = WARM_RESTARTS
        # the first fit is made to the detections the start's bias corrects
        b_start = _start_bias(start, obs) if bias_runs else None
        if b_start is not None:
            problem["observations_board"] = board_obs(obs.q - b_start)

    # every COARSE_STEP-th row and column of the grid: the coarse problem of polish(), used
    # when it has 4 x 4 points or more and every pose keeps at least 8 of them
    coarse = COARSE_STEP if min(nx, ny) >= 4 * COARSE_STEP > 0 else 1
    if coarse > 1 and (observations[:, ::coarse, ::coarse, 2] > 0).sum(axis=(1, 2)).min() < 8:
        coarse = 1

    def problem_residuals(step=1):
        # (observed - projected) on the grid of every step-th row and column, and the
        # mask of the points observed: (Nposes, ny', nx', 2), (Nposes, ny', nx')
        Rt_f = mrcal.Rt_from_rt(problem["rt_ref_frame"])
        if problem["rt_cam_ref"] is not None:
            Rt_cr = mrcal.Rt_from_rt(problem["rt_cam_ref"][0])
            Rt_f = np.array([mrcal.compose_Rt(Rt_cr, Rt) for Rt in Rt_f])
        p_grid = np.zeros((ny, nx, 3))
        p_grid[iy, ix, :2] = obs.p_board[0][:, :2] - origin[:2]
        p = mrcal.transform_point_Rt(Rt_f[:, None, None], p_grid[None, ::step, ::step])
        q = mrcal.project(p, problem["lensmodel"], problem["intrinsics"][0])
        ob = problem["observations_board"][:, ::step, ::step]
        return ob[..., :2] - q, ob[..., 2] > 0

    def problem_rms(step=1):
        d, w = problem_residuals(step)
        d = d[w]
        return float(np.sqrt(np.mean((d * d).sum(axis=-1))))

    def problem_kw(step=1, **flags):
        # mrcal's arguments for the problem on the grid of every step-th row and column
        kw = dict(problem)
        kw.update(flags)
        if step > 1:
            kw["observations_board"] = np.ascontiguousarray(
                problem["observations_board"][:, ::step, ::step])
            kw["calibration_object_spacing"] = spacing * step
        return kw

    def solve(step=1, **flags):
        nonlocal iterations
        mrcal.optimize(**problem_kw(step, **flags))
        iterations += 1  # mrcal does not report its solver's iteration count
        if not np.all(np.isfinite(problem["intrinsics"])):
            raise CalibrationFailed("diverged: mrcal returned non-finite intrinsics")
        stages.append({"lensmodel": problem["lensmodel"], **flags})

    # an intermediate lens model first: wide lenses fall into local minima otherwise
    staged = {"OPENCV8": ("LENSMODEL_OPENCV4", 8)}
    if warm is not None:
        pass
    elif model_name in staged:
        lm_stage, n_stage = staged[model_name]
        problem.update(lensmodel=lm_stage, intrinsics=np.zeros((1, n_stage)))
        problem["intrinsics"][0, :4] = seed
        solve(do_optimize_intrinsics_core=True, do_optimize_intrinsics_distortions=False)
        solve(do_optimize_intrinsics_core=True, do_optimize_intrinsics_distortions=True)
        stage_intrinsics = problem["intrinsics"][0].copy()
        problem.update(lensmodel=lensmodel, intrinsics=np.zeros((1, nint)))
        problem["intrinsics"][0, :n_stage] = stage_intrinsics
    else:
        solve(do_optimize_intrinsics_core=True, do_optimize_intrinsics_distortions=False)

    # crawl: set once a restarts() run with the full budget ends still gaining, far above
    # the detection noise (crawl_verdict), or once the coarse restarts of the polish after
    # the bias settled end far above it (settled_misfit_verdict): every later polish
    # restarts once only (on the coarse grid only, for a model with distortions: misfit_coarse)
    crawl = None
    lm_final = False  # the polish running is the record's last (LM_STEP_SIGMA)
    lm_off = False    # a restart of _valley_lm left the image: mrcal.optimize from then on
    if warm is not None and ((start.info or {}).get("crawl") or {}).get("settled"):
        # the start misfits: the exact observations' fit is the same coarse fit of it
        crawl = {**start.info["crawl"], "from_start": True}

    def misfit_coarse():
        # a misfit's polishes end on the coarse grid once the bias has settled and the
        # residuals are still MISFIT_FACTOR x the noise (settled_misfit_verdict: crawl
        # ["settled"]): for a model with distortions the full grid's one restart crawls the
        # misfit's R0 / focal-length valley as the coarse grid's did, at 4x the cost per call
        # (0.1-0.3 s in the paper campaign, at libdogleg's iteration limit), and where it
        # stops is the budget's choice. A crawl_verdict alone (before the bias settled) is
        # not enough: a Mastcam-Z CAHVOR (extra MCAM_Z_RIGHT-Z034) crawled its 25 restarts
        # at 7.6x the noise after the first bias pass, then reached its noise on the full
        # grid. A pinhole's full-grid solve converges in a few steps: it keeps its full grid.
        return crawl is not None and crawl.get("settled", False) and nint > 4 and coarse > 1

    def polish(limit=None, full=True, settle=False, final=False):
        # mrcal's solver stops early in flat valleys (narrow lenses: focal length vs range;
        # R0 vs focal length); restarting it keeps making progress. Stop when a restart gains
        # less than 1% in RMS (0.1% near an exact fit) or after max_restarts. A CAHVOR truth
        # with theta != 90 is reached this way: mrcal absorbs the skew through the R0 gauge
        # (R0 -> -0.94 for a MER hazcam, theta 90.018 deg), exactly, after ~20 restarts.
        # The restarts run on the coarse grid first, then on the full one (full=False: the
        # coarse grid only).
        # settle=True: the polish of settled(), the bias settled: a misfit of the coarse
        # grid's restarts (settled_misfit_verdict) limits the full grid's to one.
        # final=True: the record's fit ends with this polish (LM_STEP_SIGMA)
        nonlocal crawl, lm_final
        lm_final = final
        limit = min(limit or max_restarts, max_restarts)
        restarts(coarse, 1 if crawl is not None else limit)
        if settle and full and coarse > 1 and warm is None and limit == max_restarts > 1 \
                and not (crawl or {}).get("settled"):
            if crawl is None:
                crawl = settled_misfit_verdict(*problem_residuals(1))
            elif nint > 4 and settled_misfit_verdict(*problem_residuals(1)) is not None:
                # the crawl's misfit holds once the bias settled: from here on the coarse grid
                crawl = {**crawl, "settled": True,
                         "reason": crawl["reason"] + "; once the bias settled the residuals "
                                   "still misfit: the model ends on the coarse grid"}
        if full and coarse > 1 and not misfit_coarse():
            # a crawl the coarse grid just found limits this one too
            restarts(1, 1 if crawl is not None else limit)

    # the R0 / focal-length valley of LENSMODEL_CAHVOR and _CAHVORE: see VALLEY_JUMP_MAX
    valley = VALLEY_JUMP_MAX >= 1 and warm is None and (
        lensmodel == "LENSMODEL_CAHVOR" or lensmodel.startswith("LENSMODEL_CAHVORE"))

    def valley_u():
        # the valley's natural coordinates: log fx, log fy, cx, cy, alpha, beta, log e,
        # R1 / e, R2 / e (e = 1 + R0), then CAHVORE's E0, E1, E2 as they are; None where
        # e <= 0 (no jump from there)
        if not valley:
            return None
        i = problem["intrinsics"][0]
        e = 1.0 + i[6]
        if not (e > 0 and i[0] > 0 and i[1] > 0):
            return None
        return np.array([math.log(i[0]), math.log(i[1]), i[2], i[3], i[4], i[5],
                         math.log(e), i[7] / e, i[8] / e, *i[9:]])

    def valley_move(u, step):
        # the intrinsics at natural coordinates u, then the core and the board poses
        # settled to them (a pinhole-like solve of a few steps)
        e = math.exp(u[6])
        problem["intrinsics"][0] = [math.exp(u[0]), math.exp(u[1]), u[2], u[3], u[4], u[5],
                                    e - 1.0, u[7] * e, u[8] * e, *u[9:]]
        solve(step, do_optimize_intrinsics_core=True, do_optimize_intrinsics_distortions=False)

    def valley_jump(step, u_before, r):
        # from the state a restart reached (RMS r, natural coordinates u), the states
        # u + t (u - u_before), t = 1, 2, 4, ..., VALLEY_JUMP_MAX, each with its core and
        # board poses settled, while the RMS keeps falling; the best one is kept (or none:
        # the restart's own state). Returns the RMS of the state kept
        u = valley_u()
        cx, cy = problem["intrinsics"][0, 2:4]
        if u is None or not (0.0 <= cx <= W - 1 and 0.0 <= cy <= H - 1):
            return r
        d = u - u_before
        if not np.all(np.isfinite(d)):
            return r
        start = _snapshot(problem)
        best = (r, None)
        t = 1
        while t <= VALLEY_JUMP_MAX:
            valley_move(u + t * d, step)
            r_t = problem_rms(step)
            cx, cy = problem["intrinsics"][0, 2:4]
            if not (r_t < best[0] and 0.0 <= cx <= W - 1 and 0.0 <= cy <= H - 1):
                break
            best = (r_t, _snapshot(problem))
            _restore(problem, start)
            t *= 2
        _restore(problem, start if best[1] is None else best[1])
        return best[0]

    def restarts(step, limit):
        # restarts on the grid of every step-th row and column while each gains (the first
        # one too, over the state it starts from); returns the RMS. Along the CAHVOR valley,
        # each restart is followed by a jump along its own step (valley_jump)
        nonlocal crawl, lm_off
        rms_prev = problem_rms(step)
        for n in range(limit):
            u_before = valley_u()
            if VALLEY_LM and u_before is not None and not known_poses and not lm_off:
                before = _snapshot(problem)
                _valley_lm(problem_kw(step, do_optimize_intrinsics_core=True,
                                      do_optimize_intrinsics_distortions=True),
                           problem, nint, VALLEY_LM,
                           step_sigma=None if lm_final else LM_STEP_SIGMA)
                cx, cy = problem["intrinsics"][0, 2:4]
                if 0.0 <= cx <= W - 1 and 0.0 <= cy <= H - 1:
                    u_before = None
                else:
                    # the valley's limit of a misfit (e -> 0, fx and cx running off
                    # together: 1 CAHVOR's projection 6.8e7 px off at the corners): this
                    # restart as mrcal.optimize's, with its jump, keeping the principal
                    # point in the image (refusing the LM's steps that leave it instead
                    # stopped 5 CAHVOR's image fit at 0.17 px on its way); from then on
                    # every restart of this fit is (lm_off)
                    _restore(problem, before)
                    lm_off = True
                    solve(step, do_optimize_intrinsics_core=True,
                          do_optimize_intrinsics_distortions=True)
            else:
                solve(step, do_optimize_intrinsics_core=True,
                      do_optimize_intrinsics_distortions=True)
            r = problem_rms(step)
            gain = POLISH_GAIN_FINE if r < FINE_RMS else POLISH_GAIN
            if n + 1 < limit and u_before is not None and r >= 1e-10:
                # the restart and the jump after it gain together
                r = valley_jump(step, u_before, r)
            if r < 1e-10 or r > gain * rms_prev:
                return r
            last_gain, rms_prev = 1.0 - r / rms_prev, r
        # every restart of the budget still gained: a crawl (a warm fit's single restart is
        # no budget, and a capped polish is not the full one)
        if crawl is None and warm is None and limit == max_restarts > 1:
            crawl = crawl_verdict(*problem_residuals(1), last_gain, limit)
        return r

    def regularised_start():
        # the race's regularised start: mrcal.optimize with regularisation on the full grid,
        # or, along the CAHVOR / CAHVORE valley, _valley_lm on the same problem (mrcal's
        # regularisation terms are residuals of its optimizer_callback too), stopped by the
        # LM_STEP_SIGMA rule (the state only starts the race). mrcal.optimize ran to
        # libdogleg's iteration limit there (84 ms CAHVOR, 120 ms CAHVORE a call, up to 0.34 s
        # on 5120x3840 cameras: 2.5 of the paper campaign's 12 CPU s of mrcal image fits)
        # and stopped wherever that left it in the valley; the LM converges.
        # Measured (bench_fits.py on the paper campaign's renders, load 15-17): mrcal
        # calibrate ~11.2 -> ~9.3 CPU s (scaled by jpl's, which this does not touch). Judged
        # records move <= 0.0011 sigma in every parameter and <= 2e-4 sigma in projection
        # (5 CAHVOR's gauge figure R0_frac at the R0 limit 165 sigma, as under any change);
        # no status or flag changes; the race's winner changes for floor-far misfits only,
        # which stop elsewhere along their valleys (total projection 1 CAHVOR 2.46 -> 0.78 px,
        # 20 CAHVOR 0.66 -> 0.93 px). Where the LM does not apply or leaves the image (the
        # e -> 0 limit), mrcal.optimize as before.
        if VALLEY_LM and valley_u() is not None and not known_poses:
            before = _snapshot(problem)
            c = _valley_lm(problem_kw(1, do_optimize_intrinsics_core=True,
                                      do_optimize_intrinsics_distortions=True,
                                      do_apply_regularization=True),
                           problem, nint, VALLEY_LM, step_sigma=LM_STEP_SIGMA)
            cx, cy = problem["intrinsics"][0, 2:4]
            if c is not None and 0.0 <= cx <= W - 1 and 0.0 <= cy <= H - 1:
                return
            _restore(problem, before)
        solve(do_optimize_intrinsics_core=True, do_optimize_intrinsics_distortions=True,
              do_apply_regularization=True)

    if warm is not None:
        unpolished = nint > 4 and not regularization and b_start is None
        if regularization:
            solve(do_optimize_intrinsics_core=True, do_optimize_intrinsics_distortions=True)
        elif b_start is not None:
            polish()   # the first fit, to the detections the start's bias corrects
    elif nint > 4:
        if regularization:
            solve(do_optimize_intrinsics_core=True, do_optimize_intrinsics_distortions=True)
        else:
            # Two starts, keep the better. The R0 / focal-length valley is nearly flat:
            # unregularised from the pinhole seed the solver may slide along it and stop
            # anywhere (fx 96 -> 56 px for a MER hazcam CAHVORE) or fall into a local
            # minimum (Mastcam-Z, large R1, R2); from a regularised optimum it may crawl away
            # (MER pancam CAHVOR: fx 3628 -> 4384 px, R0 -> -0.17). Each path gets
            # RACE_RESTARTS unregularised restarts; the better one is polished in full (below,
            # after the first bias correction, or here if none follows).
            seed_state = _snapshot(problem)
            best = None
            for pre_regularised in (True, False):
                _restore(problem, seed_state)
                if pre_regularised:
                    regularised_start()
                polish(RACE_RESTARTS, full=False)
                r = problem_rms(coarse)
                if best is None or r < best[0]:
                    best = (r, _snapshot(problem), pre_regularised)
                if r < EXACT_RMS:
                    break
            _restore(problem, best[1])
            start_info["pre_regularised"] = best[2]
            unpolished = True

    if known_poses:
        Rt_ref_grid = np.array([mrcal.compose_Rt(Rt, _Rt_board_grid(origin))
                                for Rt in obs.Rt_ref_board])
        Rt_cam_grid_now = mrcal.Rt_from_rt(problem["rt_ref_frame"])
        Rt_cam_ref = mrcal.compose_Rt(Rt_cam_grid_now[0], mrcal.invert_Rt(Rt_ref_grid[0]))
        problem.update(rt_ref_frame=mrcal.rt_from_Rt(Rt_ref_grid),
                       rt_cam_ref=mrcal.rt_from_Rt(Rt_cam_ref)[None, :].copy(),
                       indices_frame_camintrinsics_camextrinsics=np.column_stack(
                           (np.arange(Nposes), np.zeros(Nposes), np.zeros(Nposes))
                       ).astype(np.int32),
                       do_optimize_frames=False, do_optimize_extrinsics=True)
        polish()
        unpolished = False

    def current():
        intr = problem["intrinsics"][0].copy()
        if known_poses:
            Rt_cam_ref = mrcal.Rt_from_rt(problem["rt_cam_ref"][0])
            Rt_cam_g = np.array([mrcal.compose_Rt(Rt_cam_ref, Rt)
                                 for Rt in mrcal.Rt_from_rt(problem["rt_ref_frame"])])
            Rt_ref_cam = mrcal.invert_Rt(Rt_cam_ref)
        else:
            Rt_cam_g = mrcal.Rt_from_rt(problem["rt_ref_frame"])
            Rt_ref_cam = np.vstack((np.eye(3), np.zeros(3)))
        cm = mrcal.cameramodel(intrinsics=(lensmodel, intr), imagersize=np.array((W, H)),
                               Rt_ref_cam=np.ascontiguousarray(Rt_ref_cam))
        model = _to_model(cm, model_name)
        Rt_grid_board = _Rt_board_grid(-origin)
        Rt_cam_board = np.array([mrcal.compose_Rt(Rt, Rt_grid_board) for Rt in Rt_cam_g])
        return cm, model, Rt_cam_board

    if unpolished and not bias_runs:
        polish(final=True)
        unpolished = False
    cm, model, Rt_cam_board = current()
    q_first = obs.q if b_start is None else obs.q - b_start
    passes = [{"pass": 1, **_rms(model, obs, Rt_cam_board, q_first, found)}]

    def refit(q_used, change):
        nonlocal cm, model, Rt_cam_board, unpolished
        problem["observations_board"] = board_obs(q_used)
        # the next bias needs the model only roughly: the coarse grid's restarts
        polish(full=False)
        unpolished = coarse > 1
        cm, model, Rt_cam_board = current()
        return {"bias_change_max": change, **_rms(model, obs, Rt_cam_board, q_used, found)}

    b_settled = None   # the bias at the final model, when the last pass found it settled

    def settled(change, q_used, b):
        nonlocal cm, model, Rt_cam_board, unpolished, b_settled
        if not unpolished:
            b_settled = b
            return None
        # the bias has settled on coarse polishes: polish on the full grid, then
        # check that the bias in use still holds for that model
        polish(settle=True, final=True)
        unpolished = False
        cm, model, Rt_cam_board = current()
        return {"bias_change_max": change, "full_grid": not misfit_coarse(),
                **_rms(model, obs, Rt_cam_board, q_used, found)}

    q_used, bias_applied = iterate_bias(
        obs, target, lambda: (model, Rt_cam_board), refit, passes,
        bias_passes=bias_passes if bias_runs else 0, bias_tolerance=bias_tolerance,
        no_dots="no dots: no centroid bias",
        tolerance=lambda passes: max(bias_tolerance, BIAS_RELATIVE * passes[-1]["rms"]),
        settled=settled, b_start=b_start)

    if unpolished:   # no bias pass ran (no dots), or they ran out before the bias settled
        polish(final=True)
        cm, model, Rt_cam_board = current()
    if warm is not None:
        # mrcal may take no step at all from a start in a flat valley (21 CAHVORE: a fit of
        # the exact observations bit for bit the image fit, renderer difference exactly 0):
        # say so, so that such a 0 is not read as agreement
        start_info["moved_from_start"] = not all(
            np.array_equal(problem[k], warm_state[k]) for k in ("intrinsics", "rt_ref_frame"))
    return fitted_result(
        NAME, LIBRARY, library_version(), model_name, t0, model=model,
        residuals=_residuals(model, obs, Rt_cam_board, q_used), found=found, max_rms=max_rms,
        Rt_cam_board=Rt_cam_board, iterations=iterations,
        info={"lensmodel": lensmodel, "known_poses": bool(known_poses),
              "world_frame": bool(known_poses), "regularization": bool(regularization),
              "bias_corrected": bias_applied, "passes": passes, "seed_pinhole": seed,
              "intrinsics": cm.intrinsics()[1], "cameramodel": cm,
              **applied_bias(obs, q_used, bias_applied), "bias_settled": b_settled,
              **({"crawl": crawl} if crawl is not None else {}), **start_info})


def grid_noise_rms(d, ok):
    r'''The detection noise (RMS of the 2-vector, px) estimated from residuals on the grid

SYNOPSIS

    noise = grid_noise_rms(d, ok)   # d (..., ny, nx, 2) residuals, ok (..., ny, nx) observed

The second difference x[i-1] - 2 x[i] + x[i+1] of independent errors of variance s2 has
variance 6 s2, while a smooth misfit of the model (a wrong distortion, a skew the model
lacks) contributes only its curvature over two grid spacings: the mean square second
difference along the rows and the columns, / 6, estimates s2 per coordinate. A misfit
that varies from dot to dot counts as noise (the estimate errs high, the safe side for
crawl_verdict); errors correlated between neighbouring dots (a renderer's sampling error
follows the dot's sub-pixel phase: harness.verdict's notes on its noise model) count
less than they are. None when no three consecutive points of a row or column were seen.
'''
    d = np.asarray(d, dtype=np.float64)
    ok = np.asarray(ok, dtype=bool)
    sq, n = 0.0, 0
    for axis in (-2, -1):   # ok's axes: along y (down a column), then along x (a row)
        a = np.moveaxis(d, axis - 1, -2)
        m = np.moveaxis(ok, axis, -1)
        dd = a[..., 2:, :] - 2.0 * a[..., 1:-1, :] + a[..., :-2, :]
        v = m[..., 2:] & m[..., 1:-1] & m[..., :-2]
        sq += float((dd[v] ** 2).sum())
        n += int(v.sum())
    if n == 0:
        return None
    return math.sqrt(2.0 * sq / (6.0 * 2 * n))


def crawl_verdict(d, ok, gain, restarts):
    r'''A crawl's verdict: a dict saying why no later polish should crawl again, or None

d, ok: the residuals on the full grid (grid_noise_rms) after a restarts() run whose
`restarts` restarts all gained more than POLISH_GAIN; gain: the last one's fractional
gain in RMS on the grid it ran on. A fit that converges to its observations ends at
residuals of the size of their noise; one still gaining at the end of its budget with
residuals MISFIT_FACTOR times the noise (harness.verdict's factor for a fit that cannot
represent the camera) is far from any noise-limited optimum: the model misfits (mrcal
CAHVOR for theta != 90 deg whose optimum lies at infinity; a CAHVORE mrcal does not
reach), its parameters run along a flat valley, and where the restarts stop is the
budget's choice (a 1e-10 px change of the bias moved R0 by 1e4 sigma). Restarting again
buys nothing the verdict can use. None when the residuals are within MISFIT_FACTOR of the
noise (a slow convergence: more restarts may still reach the noise) or the noise cannot
be estimated.
'''
    m = _misfit(d, ok)
    if m is None:
        return None
    rms, noise = m
    return {"restarts": int(restarts), "rms": rms, "noise_rms": noise,
            "reason": f"all {restarts} restarts gained (the last one {gain:.2%} on the "
                      f"grid it ran on) with the residual RMS at {rms:.3g} px, "
                      f"{rms / noise if noise > 0 else math.inf:.3g} x the detection noise "
                      f"estimated from the residuals ({noise:.3g} px): the model misfits "
                      f"these observations and where the restarts stop is the budget's "
                      f"choice; each later polish restarts once"}


def settled_misfit_verdict(d, ok):
    r'''A misfit's verdict once the bias has settled: a dict as crawl_verdict's, or None

d, ok: the residuals on the full grid (grid_noise_rms) after the coarse-grid restarts of
the polish that follows a settled bias (the detections corrected to within the bias
tolerance) ended by their gain rule. Residuals MISFIT_FACTOR times the noise estimated
from them at that point are the model's misfit, as in crawl_verdict; the full grid's
restarts would crawl along the misfit's flat valley as the coarse grid's did (9 CAHVORE
of the paper campaign: 3 full-grid restarts, 0.28 CPU s each, gaining 1.2% and 0.7% at 57x
its noise), so a model with distortions ends on the coarse grid, and a pinhole restarts
the full grid once (_fit_poses' misfit_coarse). Checked here only: before the bias has settled
the residuals hold the dot-centroid bias not yet corrected, and a run that ends after
the first bias correction can stop far above the noise and still converge in the next
(5 CAHVOR: at 30x its noise after the first correction, then 16 restarts gaining 1-2% to
its noise in the settled polish's coarse run; this check follows that run).
'''
    m = _misfit(d, ok)
    if m is None:
        return None
    rms, noise = m
    return {"restarts": 0, "rms": rms, "noise_rms": noise, "settled": True,
            "reason": f"once the bias settled, the coarse grid's restarts ended with the "
                      f"residual RMS at {rms:.3g} px, "
                      f"{rms / noise if noise > 0 else math.inf:.3g} x the detection noise "
                      f"estimated from the residuals ({noise:.3g} px): the model misfits "
                      f"these observations and where the restarts stop is the budget's "
                      f"choice; each later polish restarts once, and a model with "
                      f"distortions on the coarse grid only"}


def _misfit(d, ok):
    r'''(rms, noise) of residuals d on the grid (ok: observed) when their RMS exceeds
harness.verdict.MISFIT_FACTOR x the noise estimated from them (grid_noise_rms), else None'''
    from harness.verdict import MISFIT_FACTOR
    ok = np.asarray(ok, dtype=bool)
    dd = np.asarray(d, dtype=np.float64)[ok]
    if dd.size == 0:
        return None
    rms = float(np.sqrt(np.mean((dd * dd).sum(axis=-1))))
    noise = grid_noise_rms(d, ok)
    if noise is None or rms <= MISFIT_FACTOR * noise:
        return None
    return rms, noise


def _start_bias(start, obs):
    r'''The bias a warm fit's first fit is made with (Nposes,Npoints,2), or None

The start's bias at its final model (info["bias_settled"]) where its last bias pass
computed one, else the bias it applied (skeleton.start_bias). The first differs from the
second by up to the start's own tolerance, BIAS_RELATIVE x its RMS residual (~5e-5 px on
a rendered image), while the exact observations' model, one detection error from the
start's, moves the bias by ~1e-5 px (1e-2 of the detection error: navcam 15): from the
applied bias the warm fit's first pass found a change above the exact fit's 1e-5 px
tolerance and refitted (13 and 15 CAHVOR of the paper campaign).
'''
    b = start_bias(start, obs)
    s = (start.info or {}).get("bias_settled") if b is not None else None
    if s is not None and np.shape(s) == obs.q.shape:
        return np.asarray(s, dtype=np.float64)
    return b


def _warm_start(start, lensmodel, nint, Nposes, origin):
    r'''(intrinsics (nint,), Rt_cam_grid (Nposes,4,3)) of a start result, or None'''
    import mrcal
    if start is None or getattr(start, "status", None) != "ok":
        return None
    cm = (start.info or {}).get("cameramodel")
    Rts = start.Rt_cam_board
    if cm is None or Rts is None or (start.info or {}).get("known_poses"):
        return None
    lm, intr = cm.intrinsics()
    intr = np.asarray(intr, dtype=np.float64)
    Rts = np.asarray(Rts, dtype=np.float64)
    if lm != lensmodel or intr.shape != (nint,) or Rts.shape != (Nposes, 4, 3) or \
            not np.all(np.isfinite(intr)) or not np.all(np.isfinite(Rts)):
        return None
    Rt_board_grid = _Rt_board_grid(origin)
    return intr.copy(), np.array([mrcal.compose_Rt(Rt, Rt_board_grid) for Rt in Rts])


# _valley_lm's damping: LAM0 x the largest eigenvalue of the column-scaled J^T J to start,
# divided by at most 1 / LAM_DOWN after a step the quadratic model predicted well
LAM0 = 1e-6
LAM_DOWN = 0.01


def _valley_u(p, nint):
    # the natural coordinates of intrinsics p: O's image (cx + fx tan(alpha), cy + fy
    # tan(beta) / cos(alpha)) stays put where e -> 0 runs fx to infinity and cx with it
    e = 1.0 + p[6]
    ta, tb, ca = math.tan(p[4]), math.tan(p[5]), math.cos(p[4])
    return np.concatenate(([math.log(p[0]), math.log(p[1]), p[2] + p[0] * ta,
                            p[3] + p[1] * tb / ca, p[4], p[5],
                            math.log(e), p[7] / e, p[8] / e], p[9:nint]))


def _valley_p(u):
    e = math.exp(u[6])
    fx, fy = math.exp(u[0]), math.exp(u[1])
    ta, tb, ca = math.tan(u[4]), math.tan(u[5]), math.cos(u[4])
    return np.concatenate(([fx, fy, u[2] - fx * ta, u[3] - fy * tb / ca, u[4], u[5],
                            e - 1.0, u[7] * e, u[8] * e], u[9:]))


def _valley_T(u, nint):
    # d intrinsics / d u
    pi = _valley_p(u)
    fx, fy, e = pi[0], pi[1], 1.0 + pi[6]
    ta, tb = math.tan(u[4]), math.tan(u[5])
    sa, ca = math.sin(u[4]), math.cos(u[4])
    T = np.eye(nint)
    T[0, 0], T[1, 1] = fx, fy
    T[2, 0], T[2, 4] = -fx * ta, -fx * (1.0 + ta * ta)
    T[3, 1], T[3, 4], T[3, 5] = -fy * tb / ca, -fy * tb * sa / (ca * ca), \
        -fy * (1.0 + tb * tb) / ca
    T[6, 6] = e
    T[7, 6], T[8, 6], T[7, 7], T[8, 8] = pi[7], pi[8], e, e
    return T


class _DampedStep:
    r'''The Levenberg-Marquardt step ds = -(A + lam I)^-1 g of _valley_lm's normal equations,
for any damping lam, by the Schur complement of the board poses' blocks

SYNOPSIS

    step = _DampedStep(A, g, nint)   # A (n,n) = Js^T Js, g (n,) = Js^T x
    ds = step(lam)                   # (n,): the intrinsics' nint, then 6 per board pose

The state is nint intrinsics, then each board pose's 6 parameters; a residual depends on
the intrinsics and on its own pose only, so the poses' diagonal 6x6 blocks R_k are A's
only pose entries. Eliminating them leaves the intrinsics' nint x nint Schur complement
S(lam) = P + lam I - sum_k Q_k (R_k + lam I)^-1 Q_k^T (P, Q_k: A's intrinsics block and
its coupling to pose k): one 6x6 eigen-decomposition per pose per Jacobian, and per damping
one of S (its eigenvalues held >= lam, which S(lam) is in exact arithmetic, as the full
matrix's are held >= 0 + lam), instead of the n x n eigen-decomposition of A (n = nint + 6
x poses, 45-57 here: 0.29 ms, 30% of an iteration; 4400 iterations in the paper campaign's
mrcal fits). The valley's ill-conditioning (condition ~1e14) lies in S, which is solved by
its eigen-decomposition as A was. Measured (bench_fits.py on the paper campaign's renders,
load 14): mrcal calibrate 11.65 -> 11.23 CPU s. The steps agree with the full solve's to
rounding times the condition, so judged records move <= 0.001 sigma in every projection
and parameter figure (16 CAHVOR's at the R0 gauge's limit: 0.18 sigma in O, its gauge
figures as under any change); floor-far misfits stop elsewhere along their valleys (4
CAHVOR's total projection 0.048 -> 0.078 px); no flag changes.
'''

    def __init__(self, A, g, nint):
        n = len(g)
        npose = (n - nint) // 6
        if nint + 6 * npose != n:
            raise ValueError(f"a state of {n} parameters is not {nint} intrinsics and 6 per "
                             f"pose")
        self.nint, self.g = nint, g
        self.P = A[:nint, :nint]
        k = np.arange(npose)
        R = A[nint:, nint:].reshape(npose, 6, npose, 6)[k, :, k, :]      # (npose,6,6)
        w, U = np.linalg.eigh(R)
        self.w, self.U = np.maximum(w, 0.0).reshape(-1), U
        # in each pose's eigenvectors' coordinates: Q U (nint, 6 npose), U^T g_p (6 npose,)
        Q = A[:nint, nint:].reshape(nint, npose, 6).transpose(1, 0, 2)    # Q_k (npose,nint,6)
        self.QU = (Q @ U).transpose(1, 0, 2).reshape(nint, -1)
        self.Ug = (g[nint:].reshape(npose, 1, 6) @ U).reshape(-1)

    def __call__(self, lam):
        nint = self.nint
        inv = 1.0 / (self.w + lam)                  # the poses' (R_k + lam I)^-1, diagonal
        QUi = self.QU * inv
        S = self.P - QUi @ self.QU.T
        S[np.diag_indices(nint)] += lam
        rhs = self.g[:nint] - QUi @ self.Ug
        ws, Vs = np.linalg.eigh(S)
        ds_i = -Vs @ ((Vs.T @ rhs) / np.maximum(ws, lam))
        # ds_k = -(R_k + lam I)^-1 (g_k + Q_k^T ds_i)
        t = (self.Ug + self.QU.T @ ds_i) * inv
        ds_p = -(self.U @ t.reshape(-1, 6, 1))
        return np.concatenate((ds_i, ds_p.reshape(-1)))


def _valley_lm(kw, problem, nint, max_iter, step_sigma=None):
    r'''Levenberg-Marquardt on mrcal.optimizer_callback (kw: its arguments, problem's arrays
among them) in the valley's natural coordinates u (_valley_u: log fx, log fy, the image of
O, alpha, beta, log e, R1 / e, R2 / e, CAHVORE's E; e = 1 + R0), the board poses as they
are; written back into problem. The normal equations of the column-scaled Jacobian are
solved by the Schur complement of the board poses (_DampedStep), the intrinsics' block by
eigen-decomposition (its condition ~1e14 in the valley), Nielsen's damping
update (its decrease capped at LAM_DOWN), until a step gains less than LM_REL_TOL of the
cost (step_sigma None) or less than step_sigma^2 x cost / (residuals - state parameters),
or after max_iter steps. Returns the final cost x.x, or None where it does not
apply (the state is not intrinsics + board poses, or e <= 0)'''
    import mrcal
    b, x, J = mrcal.optimizer_callback(**kw, no_factorization=True)[:3]
    n = len(b)
    nf = problem["rt_ref_frame"].size
    if n != nint + nf:
        return None
    scale = np.ones(n)
    mrcal.unpack_state(scale, **kw)
    p = b * scale
    if not (p[0] > 0 and p[1] > 0 and 1.0 + p[6] > 0):
        return None
    u = np.concatenate((_valley_u(p[:nint], nint), p[nint:]))
    cost = float(x @ x)
    rel_tol = LM_REL_TOL if step_sigma is None else step_sigma ** 2 / max(len(x) - n, 1)
    lam, nu = None, 2.0

    def put(v):
        problem["intrinsics"][0] = _valley_p(v[:nint])
        problem["rt_ref_frame"].reshape(-1)[:] = v[nint:]

    for _ in range(max_iter):
        Jr = J.toarray() / scale
        Jr[:, :nint] = Jr[:, :nint] @ _valley_T(u[:nint], nint)
        d = np.sqrt((Jr * Jr).sum(axis=0))
        d[d == 0] = 1.0
        Js = Jr / d
        A = Js.T @ Js
        g = Js.T @ x
        step = _DampedStep(A, g, nint)
        if lam is None:
            # the damping's scale: A's largest eigenvalue at the start (1 to n: A's diagonal
            # is 1), also the scale of the give-up bound below
            S0 = float(np.linalg.eigvalsh(A)[-1])
            lam = LAM0 * S0
        accepted = False
        while lam < 1e16 * S0:
            ds = step(lam)
            pred = -(2.0 * float(ds @ g) + float(ds @ (A @ ds)))
            v = u + ds / d
            pv = _valley_p(v[:nint])
            if np.all(np.isfinite(v)) and np.all(np.isfinite(pv)):
                put(v)
                # with its Jacobian: ~92% of the trial steps are taken, and the next
                # iteration needs it there (the residuals are the same bits either way)
                x_new, J_new = mrcal.optimizer_callback(**kw, no_factorization=True)[1:3]
                c_new = float(x_new @ x_new)
            else:
                c_new = math.inf
            rho = (cost - c_new) / pred if pred > 0 else -1.0
            if rho > 0:
                accepted = True
                break
            lam *= nu
            nu *= 2.0
        if not accepted:
            put(u)
            return cost
        gain = cost - c_new
        u, cost = v, c_new
        lam *= max(LAM_DOWN, 1.0 - (2.0 * rho - 1.0) ** 3)
        nu = 2.0
        if gain <= rel_tol * cost:
            break
        x, J = x_new, J_new
    put(u)
    return cost


def _snapshot(problem):
    return {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in problem.items()}


def _restore(problem, state):
    for k, v in state.items():
        problem[k] = v.copy() if isinstance(v, np.ndarray) else v


def _to_model(cm, model_name):
    if model_name in FAMILIES:
        from reference_models.mrcal_convert import from_mrcal
        return from_mrcal(cm)
    return MrcalModel(cm, model_name)


def _residuals(model, obs, Rt_cam_board, q):
    Rt_ref_cam = model.Rt_ref_cam()
    R = np.einsum("ij,fjk->fik", Rt_ref_cam[:3], Rt_cam_board[:, :3])
    t = Rt_cam_board[:, 3] @ Rt_ref_cam[:3].T + Rt_ref_cam[3]
    p = np.einsum("fij,fnj->fni", R, obs.p_board) + t[:, None]
    return q - model.project(p)


def _rms(model, obs, Rt_cam_board, q, found):
    r = np.linalg.norm(_residuals(model, obs, Rt_cam_board, q)[found], axis=-1)
    return {"rms": float(np.sqrt(np.mean(r * r))), "max": float(r.max())}


