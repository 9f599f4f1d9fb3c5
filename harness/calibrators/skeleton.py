r'''What the four calibrators share: the iterated bias correction and the result

SYNOPSIS

    from harness.calibrators.skeleton import board_residuals, fitted_result, iterate_bias

    passes = [{"pass": 1, ...}]                        # the first fit's figures
    q_used, bias_applied = iterate_bias(
        obs, target, lambda: (model, Rt_cam_board), refit, passes,
        bias_passes=bias_passes if bias_correction else 0, bias_tolerance=1e-5)
    # refit(q_used, change) fits again to the corrected detections q_used
    # (Nposes,Npoints,2) and returns that pass's figures (a dict)

    return fitted_result(NAME, LIBRARY, library_version(), model_name, t0,
                         model=model, residuals=q_used - projected, found=obs.found,
                         max_rms=max_rms, Rt_cam_board=Rt_cam_board, iterations=n,
                         info={"passes": passes, "bias_corrected": bias_applied, ...})

Every calibrator fits once to the detections, then corrects each detection by
the dot-centroid bias computed with its current model and board poses
(bias.bias_step) and fits again, until the bias changes by less than a
tolerance or the passes run out (iterate_bias). Its result is the last fit
with the residuals of every detected point and status "ok", unless the RMS
residual shows that the fit diverged (fitted_result raises CalibrationFailed).
What differs between the calibrators is given to iterate_bias as callbacks:
the fit itself (refit), a tolerance that depends on the fit so far (mrcal's
relative one), and what to do once the bias has settled (mrcal polishes a
coarse-grid fit on the full grid and checks the bias again).
'''

import math
import time

import numpy as np

from .base import CalibrationFailed, CalibrationResult
from .bias import bias_step

# iterate_bias's pass record when every point's bias is 0 (Observations.corner_model: no
# corner of the window model)
NO_BIAS = "no point has a bias to correct (no corner of the window model)"


def start_bias(start, obs):
    r'''The bias a warm start's last fit was made to (Nposes,Npoints,2), or None

SYNOPSIS

    b0 = start_bias(start, obs)      # start: the image fit (harness.verdict.exact_fit)
    q_first = obs.q if b0 is None else obs.q - b0   # the first fit's detections
    iterate_bias(..., b_start=b0)

A fit of the exact observations from the image fit (harness.verdict) starts its
bias from the image fit's (its info["bias"]: applied_bias, the bias its last model
was fitted with; the same observations then give the same fit): the two
models differ by the detection error (~1e-3 px), which moves a dot's bias by ~1e-5 px.
The calibrators hold that bias in a warm fit (no bias pass: iterate_bias's b_start says why), so
the fit is one solve instead of a solve without bias and the passes that bring it
back. None when start is not an ok fit of observations of this shape, or when its bias
was computed for other corner inputs than obs's (info["bias_for"], bias_inputs: the
image's blurred corners carry their board lines' or tag edges' bias, the sharp reference
corners of the exact observations the window's; holding the one on the other put the
exact fit 0.01 px off the truth, a constructed 768x1024 CAHVOR chessboard under the
realistic profile): the warm fit then runs its own bias passes from the start's model.
'''
    if getattr(start, "status", None) != "ok":
        return None
    b = (start.info or {}).get("bias")
    if b is None or np.shape(b) != obs.q.shape or \
            (start.info or {}).get("bias_for") != bias_inputs(obs):
        return None
    return np.asarray(b, dtype=np.float64)


def bias_inputs(obs):
    r'''A digest of what a point's bias depends on besides the model and the poses: the
observations' corner models, corner blurs and tag edges' span records (Observations.
corner_model, corner_blur_px, corner_spans: bias.bias_step's inputs); the same string for
every dot target'''
    import hashlib
    h = hashlib.sha256()
    for a in (obs.corner_model, obs.corner_blur_px, obs.corner_spans):
        if a is None:
            h.update(b"-")
        else:
            a = np.asarray(a)
            h.update(repr((a.dtype.str, a.shape)).encode())
            h.update(np.ascontiguousarray(a.astype(str) if a.dtype == object else a).tobytes())
    return h.hexdigest()


def applied_bias(obs, q_used, bias_applied):
    r'''{"bias": obs.q - q_used, the bias iterate_bias applied last (what start_bias reads
from a fit's info["bias"]), or None; "bias_for": bias_inputs(obs), what it was computed
for}: a calibrator's result info takes both'''
    return {"bias": obs.q - q_used if bias_applied else None, "bias_for": bias_inputs(obs)}


def iterate_bias(obs, target, current, refit, passes, *, bias_passes, bias_tolerance,
                 views=None, no_dots=None, tolerance=None, settled=None, b_start=None):
    r'''The iterated dot-centroid bias correction; returns (q_used, bias_applied)

SYNOPSIS

    q_used, bias_applied = iterate_bias(obs, target, current, refit, passes,
                                        bias_passes=4, bias_tolerance=1e-5)
    # q_used (Nposes,Npoints,2): the detections the last fit was made to
    # (obs.q when no bias was applied); passes has one entry more per pass

Each pass computes the bias b (Nposes,Npoints,2) of every dot under the fit
current() -> (model, Rt_cam_board (Nposes,4,3)) (poses outside `views`, when
given, get none; corners that obs.corner_model says are not the window model's
get none: bias.bias_step). A first bias that is 0 everywhere ends the passes
({"pass": i, "skipped": NO_BIAS}): the fit is already the fit to obs.q. The
passes stop when the bias changes by less than the tolerance since the previous
pass, or after bias_passes passes (0: none).
Otherwise the detections are corrected, q_used = obs.q - b, and
refit(q_used, change) fits again and returns the pass's figures: passes gets
{"pass": i, **figures} (the first fit is pass 1).

ARGUMENTS

- target: the target; a target without dots (or None) ends the passes; with
  no_dots (a string) passes then gets {"pass": i, "skipped": no_dots}
- tolerance: None (bias_tolerance), or tolerance(passes) -> px, the
  tolerance given the passes so far
- settled: None (the bias has settled: stop), or settled(change, q_used, b) ->
  the figures of a pass that refits without a new bias (appended to passes,
  and the passes go on), or None to stop; b: the bias just computed (not applied)
- b_start: None, or the bias the first fit was made with (start_bias: obs.q -
  b_start were its detections), a warm start's: that bias is held, no pass runs
  (obs.q - b_start, True). The warm fit is the verdict's exact fit from the image fit
  (harness.verdict): the renderer difference between them is then the response of one
  fit to the change of the observations under one bias, which is what the verdict's
  expected scatter predicts (its linearisation holds the bias fixed), and the bias's own
  convergence error, which the image fit carries (up to its tolerance), cancels. A pass
  would recompute the bias at the warm fit's model, ~1e-5 px from the start's (1.5e-5 to
  2.2e-5 px on jpl paper records, 7 of 30 above the 1e-5 px tolerance: a second solve),
  for 40-65% of a jpl or OpenCV exact fit's time (mrcal's: 1.48 -> 0.84 CPU s over the
  paper campaign)
'''
    if b_start is not None:
        return obs.q - b_start, True
    q_used = obs.q
    bias_applied = False
    b_prev = None
    for ipass in range(bias_passes):
        model, Rt_cam_board = current()
        b, change = bias_step(model, target, Rt_cam_board, obs.p_board, b_prev, views,
                              obs.corner_model, obs.corner_blur_px, obs.corner_spans,
                              corner_q=obs.q)
        if b is None:
            if no_dots is not None:
                passes.append({"pass": ipass + 2, "skipped": no_dots})
            break
        if b_prev is None and not np.any(b):
            # no point carries a bias (corners of a model without one): the fit stands
            passes.append({"pass": ipass + 2, "skipped": NO_BIAS})
            break
        if b_prev is not None and change < (bias_tolerance if tolerance is None
                                            else tolerance(passes)):
            figures = None if settled is None else settled(change, q_used, b)
            if figures is None:
                break
            passes.append({"pass": ipass + 2, **figures})
            continue
        b_prev = b
        q_used = obs.q - b
        bias_applied = True
        passes.append({"pass": ipass + 2, **refit(q_used, change)})
    return q_used, bias_applied


def board_residuals(model, Rt_cam_board, p_board, q):
    r'''q - the projection of the board points placed in the camera frame, px

SYNOPSIS

    r = board_residuals(model, Rt_cam_board, obs.p_board, q_used)
    # Rt_cam_board (Nposes,4,3), p_board (Nposes,Npoints,3), q (Nposes,Npoints,2);
    # r (Nposes,Npoints,2)

For a model whose camera frame is its world frame (OpenCV, COLMAP fits).
'''
    p = np.einsum("fij,fnj->fni", Rt_cam_board[:, :3], p_board) + Rt_cam_board[:, None, 3]
    return q - model.project(p)


def fitted_result(calibrator, library, library_version, model_name, t0, *, model, residuals,
                  found, max_rms, Rt_cam_board, iterations, info):
    r'''The CalibrationResult of a fit that ended; raises CalibrationFailed if it diverged

SYNOPSIS

    return fitted_result(NAME, LIBRARY, library_version(), model_name, t0, model=model,
                         residuals=residuals, found=obs.found, max_rms=1.0,
                         Rt_cam_board=Rts, iterations=n, info=info)

residuals (Nposes,Npoints,2) are set to NaN where not found (in place); the
fit diverged if their RMS norm is not finite or above max_rms px. seconds is
the time since t0 (time.perf_counter()).
'''
    residuals[~found] = np.nan
    rn = np.linalg.norm(residuals, axis=-1)
    rms = float(np.sqrt(np.nanmean(rn ** 2)))
    if not math.isfinite(rms) or rms > max_rms:
        raise CalibrationFailed(f"diverged: RMS residual {rms:.4g} px > {max_rms:g} px")
    return CalibrationResult(
        calibrator=calibrator, model_name=model_name, status="ok", model=model,
        residuals=residuals, Rt_cam_board=Rt_cam_board, iterations=iterations,
        seconds=time.perf_counter() - t0, library=library, library_version=library_version,
        info=info)
