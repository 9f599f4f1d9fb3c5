r'''The corner model of each detection and the calibrators' bias step (issue 16)

corner_bias is the bias of the corner WINDOW model (targets.corners: straight edges fitted
in a window on edges that distortion bends). Corners found otherwise (targets.tag_edges on
a blurred image: whole border edges fitted as curves) have none, and subtracting it from
them moves the fit: 1.73x the dots' residual on camera 8 CAHVORE under the `realistic`
response before the detections carried their corner model to the bias step.'''

import numpy as np
import pytest
from synthetic import exact_observations, synthetic_poses

from harness.calibrators import calibrate
from harness.calibrators.bias import corner_bias
from harness.calibrators.skeleton import NO_BIAS
from harness.compare import projection_difference
from reference_models.cahvore import CAHVORE
from targets.boards import load_target
from targets.detection import CORNER_WINDOW, TAG_EDGES

TARGET = load_target("apriltag")


def _fisheye():
    r'''An 800x600 CAHVORE fisheye (type 3, linearity 0.6, non-central E, O tilted 0.5 deg),
built here: its board edges bend by ~1e-3 / px, so the window model's corners are off by
corner_bias ~ k w^2 / 10 of a few thousandths of a pixel'''
    A = np.array([0.0, 0.0, 1.0])
    O = np.array([0.008, -0.003, 1.0])
    return CAHVORE(C=[0, 0, 0], A=A, H=[300.0, 0, 0] + 401.5 * A, V=[0, 300.0, 0] + 297.0 * A,
                   O=O / np.linalg.norm(O), R=[0.0, 0.006, -0.002], E=[0.0, 0.004, -0.001],
                   model_type=3, linearity=0.6, width=800, height=600)


def _rms(x):
    n = np.linalg.norm(x, axis=-1)
    return float(np.sqrt(np.nanmean(n ** 2)))


@pytest.fixture(scope="module")
def scene():
    truth = _fisheye()
    Rts = synthetic_poses(truth, TARGET)
    obs = exact_observations(truth, TARGET, Rts)
    b = np.array([corner_bias(truth, TARGET, Rt, TARGET.points()) for Rt in Rts])
    return truth, obs, b


def _fit(truth, obs):
    r = calibrate("jpl", obs, TARGET, "CAHVORE", truth=truth)
    assert r.status == "ok", r.reason
    d = projection_difference(truth, r.model, mode="rotation", step=32)
    return r.residual_stats()["rms"], d["rms"], r


def test_corners_of_the_edge_model_get_no_window_bias(scene):
    r'''Exact corners labelled as the edge model's are fitted as they are: the bias loop
finds no point to correct and the fit is the exact one (residual and projection
difference at the solver's tolerance, 1e-9 px with bias_correction off:
tests/test_jpl_fit.py). The same corners labelled as the window model's (what every
corner was taken for before) get corner_bias subtracted: the fit is off by a sizeable
part of it, which is what the first assertion guards against.'''
    truth, obs, b = scene
    bias_rms = _rms(np.where(obs.found[..., None], b, np.nan))
    assert bias_rms > 1e-3, bias_rms           # the camera bends the edges: the test can see
    res_w, proj_w, _ = _fit(truth, obs.replace(corner_model=np.where(obs.found, CORNER_WINDOW,
                                                                     "")))
    res_e, proj_e, r = _fit(truth, obs.replace(corner_model=np.where(obs.found, TAG_EDGES, "")))
    assert r.info["passes"][-1].get("skipped") == NO_BIAS
    # measured 8e-14 / 2e-13 px
    assert res_e < 1e-6 and proj_e < 1e-6, (res_e, proj_e)
    # the wrong correction (measured: corner_bias 0.0059 px RMS -> residual 0.0037,
    # projection difference 0.0028 px): the model absorbs part of a smooth bias, the rest
    # stays in the residuals
    assert res_w > 0.3 * bias_rms and proj_w > 0.1 * bias_rms, (res_w, proj_w, bias_rms)


def _window_detections(truth, obs, b):
    r'''(q, settled): q (Nposes,Npoints,2) what a window fit puts at each corner, the
projection plus the bias of a window laid about the detection itself (the refiner lays its
window about its own first pass; the bias step about the detection, corner_bias' q_window):
the fixed point of b -> corner_bias(q_window=projection + b), from the bias about the
projection. settled (Nposes,Npoints): the corners of the tags that reach it; a corner whose
window has a pixel at its edge may have none (one pixel in, the bias moves the window's edge
past it, and back: 2 of the 864 corners here alternate by 7.3e-4 px), and its tag is left out
(a tag's corners place each other's windows: corner_steps).'''
    Rts = synthetic_poses(truth, TARGET)
    for _ in range(5):
        b1 = np.array([corner_bias(truth, TARGET, Rt, TARGET.points(), q_window=q)
                       for Rt, q in zip(Rts, obs.q + b, strict=True)])
        if np.array_equal(b1, b, equal_nan=True):
            break
        b, b1 = b1, b
    same = np.all((b1 == b) | np.isnan(b), axis=-1)
    settled = np.repeat(same.reshape(len(b), -1, 4).all(axis=-1), 4, axis=-1)
    return obs.q + b, settled


def test_each_corner_gets_the_bias_of_its_own_model(scene):
    r'''Every other tag's corners carry the window model's bias (the detections of a
window fit), the rest none (the edge model's): the bias loop corrects the first only
and recovers the camera. What is left is the loop's own convergence (bias_tolerance
1e-5 px: the bias under the fit differs from the truth's by the model's error times the
bias's sensitivity to it, far below that) and the solver's. The window fit's detections
carry the bias of a window laid about themselves (_window_detections), as the bias step
lays it: the bias of the window about the projection (one pixel more or less at some
corners) left 5.0e-5 / 1.7e-5 px; the corners of a tag without a fixed point are left out.'''
    truth, obs, b = scene
    tag = np.arange(obs.Npoints) // 4
    q_window, settled = _window_detections(truth, obs, b)
    found = obs.found & settled
    window = np.broadcast_to(tag % 2 == 0, obs.found.shape) & found
    model = np.where(window, CORNER_WINDOW, np.where(found, TAG_EDGES, ""))
    q = np.where(window[..., None], q_window, np.where(found[..., None], obs.q, np.nan))
    res, proj, r = _fit(truth, obs.replace(q=q, corner_model=model))
    assert r.info["bias_corrected"]
    # measured 1.2e-7 / 2.6e-8 px; every corner taken as the window's (as before the
    # corner models travelled with the observations): 0.0036 / 0.0044 px
    assert res < 1e-5 and proj < 1e-5, (res, proj)


def _spans(Nposes):
    r'''A tag-edges span record for every corner of TARGET (Observations.corner_spans): a
functional missing a line's quartic and quintic terms at the ends, as a cubic over a span
extrapolated does, the realistic blur's variance (0.7^2 + 1/6 px^2), the span's reach (the
edge and half of each neighbour), each edge's other corner's row'''
    ids = TARGET.point_ids()
    row = {int(pid): j for j, pid in enumerate(ids)}
    rec = np.zeros((len(ids), 2, 10))
    rec[:, :, 4:6] = [-0.6, -0.2]
    rec[:, 1, 5] = 0.2
    rec[:, :, 6] = 0.49 + 1.0 / 6.0
    rec[:, :, 7:9] = [-2.0, 2.0]
    for j, pid in enumerate(ids):
        t, k = divmod(int(pid), 4)
        rec[j, 0, 9], rec[j, 1, 9] = row[4 * t + (k - 1) % 4], row[4 * t + (k + 1) % 4]
    return np.broadcast_to(rec, (Nposes,) + rec.shape).copy()


def test_tag_edges_corners_get_their_spans_bias(scene):
    r'''Corners of the tag edges' model placed where their spans' polynomials and the blur
put them (tag_edges_bias under the true camera: the bend of each board line the span
cannot follow, the blurred edge's shift towards its centre of curvature) are corrected by
the bias loop when their span records travel with them (Observations.corner_spans),
and the camera is recovered; without the records they are fitted as they are.'''
    from harness.calibrators.bias import tag_edges_bias
    truth, obs, _ = scene
    Rts = synthetic_poses(truth, TARGET)
    spans = _spans(obs.Nposes)
    b = np.array([tag_edges_bias(truth, Rt, TARGET.points(), s)
                  for Rt, s in zip(Rts, spans, strict=True)])
    bias_rms = _rms(np.where(obs.found[..., None], b, np.nan))
    assert np.isfinite(b[obs.found]).all() and bias_rms > 1e-4, bias_rms
    model = np.where(obs.found, TAG_EDGES, "")
    q = obs.q + b
    res, proj, r = _fit(truth, obs.replace(q=q, corner_model=model, corner_spans=spans))
    assert r.info["bias_corrected"]
    res0, proj0, _ = _fit(truth, obs.replace(q=q, corner_model=model))
    assert res < 1e-5 and proj < 1e-5, (res, proj, res0, proj0, bias_rms)
    assert proj0 > 10 * proj, (proj0, proj)


def test_observations_check_the_corner_models_shape(scene):
    from harness.calibrators.base import CalibratorError
    _, obs, _ = scene
    with pytest.raises(CalibratorError, match="corner_model must have shape"):
        obs.replace(corner_model=np.full(obs.Npoints, TAG_EDGES))


@pytest.mark.slow
def test_the_apriltag_detector_records_its_corner_model():
    r'''A sharp render: every corner from the window fit; blurred (the `realistic`
profile's Gaussian PSF, sigma 0.7 px): from the tags' whole edges. The labels travel
through observations_from to the calibrators.'''
    from targets_render import pinhole, render

    from harness.stages import observations_from
    from renderers.response import ResponseChain
    from targets.detect import detect
    m = pinhole(640, 640, 600.0, R=[0.0, -0.2, 0.0])
    Rt = np.array([[0.9, -0.3, 0.3], [0.35, 0.93, -0.05], [-0.26, 0.16, 0.95],
                   [-0.5, -0.45, 1.6]])
    U, _, Vt = np.linalg.svd(Rt[:3])
    Rt[:3] = U @ Vt
    img = render(m, TARGET.pattern(), Rt, K=8)
    blurred = ResponseChain.from_config({"psf": {"kind": "gaussian", "sigma_px": 0.7}}) \
        .apply(img).image.astype(np.float64)
    dets = [detect(img, TARGET), detect(blurred, TARGET)]
    for det, want in zip(dets, (CORNER_WINDOW, TAG_EDGES), strict=True):
        assert det.n_found > 0.5 * TARGET.Npoints
        assert set(det.corner_model[det.found]) == {want}
        assert set(det.corner_model[~det.found]) <= {""}
    obs = observations_from(m, TARGET, [Rt, Rt], dets)
    assert obs.corner_model.shape == (2, TARGET.Npoints)
    assert (obs.corner_model[1][dets[1].found] == TAG_EDGES).all()
    # the tag edges' span records travel too (the sharp view has none)
    assert obs.corner_spans.shape[:3] == (2, TARGET.Npoints, 2)
    assert np.isnan(obs.corner_spans[0]).all()
    assert np.isfinite(obs.corner_spans[1][dets[1].found]).all()


def test_detection_noise_takes_off_the_tag_edges_span_bias(scene):
    r'''The verdict's detection noise (harness.verdict.corner_biases) takes off each side's
bias as the calibrators' bias step does, a tag-edge corner's from its own span record: a
blurred job's corners that are the sharp reference's plus exactly the difference of the
two biases read no noise; without the span records the tag edges' bias is noise.'''
    from harness import verdict
    from harness.calibrators.bias import tag_edges_bias
    truth, obs, b_window = scene
    Rts = np.asarray(synthetic_poses(truth, TARGET))
    spans = _spans(obs.Nposes)
    t = np.array([tag_edges_bias(truth, Rt, TARGET.points(), s)
                  for Rt, s in zip(Rts, spans, strict=True)])
    # the reference's window fit: its bias is the window's laid about its detections
    q_window, settled = _window_detections(truth, obs, b_window)
    found = obs.found & settled
    b_window = q_window - obs.q
    ref = obs.replace(q=np.where(found[..., None], q_window, np.nan),
                      corner_model=np.where(found, CORNER_WINDOW, ""))
    det = obs.replace(q=np.where(found[..., None], obs.q + t, np.nan),
                      corner_model=np.where(found, TAG_EDGES, ""),
                      corner_blur_px=np.full(obs.Nposes, 0.7), corner_spans=spans)
    b = verdict.corner_biases(det, ref, truth, TARGET, Rts)
    assert b is not None
    # each side's bias is its own corner model's: the spans' on the job's, the window's on
    # the reference's (the camera-frame truth: the same projections to rounding)
    assert np.abs(b[0] - t)[found].max() < 1e-9
    assert np.abs(b[1] - b_window)[found].max() < 1e-9
    assert verdict.detection_noise(det, ref, b)["rms"] < 1e-9
    # the span record is what carries the tag edges' bias: without it, it reads as noise
    no_spans = det.replace(corner_spans=None)
    n = verdict.detection_noise(no_spans, ref,
                                verdict.corner_biases(no_spans, ref, truth, TARGET, Rts))
    assert n["rms"] > 0.5 * _rms(np.where(found[..., None], t, np.nan)) > 1e-4


def test_exact_observations_keep_their_own_span_records(monkeypatch):
    r'''The verdict's exact observations are the reference corners, with the span records
the reference detections made (the bias step computes a TAG_EDGES corner's bias from
them), never the job's: a sharp reference render records none; a reference detected on
tag edges (stood in for here) brings its own; the job's own detections as the reference
keep the job's.'''
    from harness import stages, verdict
    truth = _fisheye()
    Rts = np.asarray(synthetic_poses(truth, TARGET))[:2]
    exact = exact_observations(truth, TARGET, Rts)
    job = stages.observations_from(truth, TARGET, Rts, [q for q in exact.q])
    found = job.found
    job = job.replace(corner_model=np.where(found, TAG_EDGES, ""),
                      corner_blur_px=np.full(2, 0.7), corner_spans=_spans(2))
    # a sharp reference render: window corners, no span record
    sharp = verdict.exact_observations(job, truth, TARGET, Rt_cam_board=Rts)
    assert sharp.corner_model is not None
    assert set(sharp.corner_model[found]) == {CORNER_WINDOW}
    assert sharp.corner_spans is None
    # a reference found on the tag edges carries its own records
    own_spans = _spans(2)
    own_spans[..., 4:6] *= 2.0
    monkeypatch.setattr(verdict, "reference_corners", lambda camera, target, Rts_: (
        exact.q, np.where(found, TAG_EDGES, ""), np.full(2, 0.7), own_spans))
    edged = verdict.exact_observations(job, truth, TARGET, Rt_cam_board=Rts)
    assert np.array_equal(edged.corner_spans, own_spans, equal_nan=True)
    # the job's own detections as the reference keep the job's records
    mine = verdict.exact_observations(job, truth, TARGET, reference=job.q, Rt_cam_board=Rts)
    assert np.array_equal(mine.corner_spans, job.corner_spans, equal_nan=True)
