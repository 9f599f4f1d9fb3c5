r'''harness.verdict: the fit of exact observations, floor / renderer / total

No rendering: the "images" are the exact observations plus a known
disturbance (a constant shift of every detection, or seeded noise), so what
the renderer comparison must find is known.
'''

import functools

import numpy as np
import pytest
from synthetic import centroid_observations

from harness import stages, verdict
from harness.records import Record


@pytest.fixture(autouse=True)
def _fresh_exact_fit_memo():
    r'''Each test starts with an empty memo of exact fits: the process-wide memo reuses a
fit of bit-identical inputs, so what one test fitted would otherwise be "reused" in
the next (the tests' results must not depend on their order)'''
    verdict._EXACT_FITS.clear()
    yield
    verdict._EXACT_FITS.clear()


@pytest.fixture(scope="module")
def navcam():
    _, truth = stages.camera_truth("15", "CAHVOR")
    target = stages.cached_target("dots")
    poses = stages.poses_stage(truth, target, 6, 0)
    # "detections" = exact centroids
    return truth, target, poses, centroid_observations(truth, target, poses)


def test_exact_observations_are_the_exact_centroids_with_the_detected_mask(navcam):
    truth, target, poses, obs = navcam
    q = obs.q.copy()
    q[0, :5] = np.nan                      # five points the detector missed
    obs_missing = obs.replace(q=q)
    x = verdict.exact_observations(obs_missing, truth, target)
    assert np.array_equal(np.isnan(x.q), np.isnan(q))
    # the same centroids, recomputed from the surveyed poses (one rigid transform and
    # back: a few ulps of the ~1000 px coordinates)
    ok = np.isfinite(q)
    assert np.max(np.abs(x.q[ok] - q[ok])) < 1e-9
    n = verdict.detection_noise(obs_missing, x)
    assert n["n"] == int(ok[..., 0].sum())
    assert n["rms"] < 1e-9


def test_detection_noise_per_pose(navcam):
    truth, target, poses, obs = navcam
    x = verdict.exact_observations(obs, truth, target)
    shifted = obs.replace(q=obs.q + np.array([0.003, -0.004]))
    n = verdict.detection_noise(shifted, x)
    assert n["rms"] == pytest.approx(0.005, rel=1e-6)
    assert n["per_pose_rms"] == pytest.approx([0.005] * 6, rel=1e-6)
    assert n["mean"] == pytest.approx([0.003, -0.004], rel=1e-6)


def test_detection_noise_takes_off_what_each_sides_corner_model_biases(navcam):
    # a blurred chessboard's corners carry their lines' bias, the sharp reference corners
    # the window's: the calibrators' bias step removes each, so it is no noise. Detections
    # that are the reference plus exactly that difference read 0 noise with the biases
    # given; without them, the bias difference itself
    from targets.detection import CORNER_LINES, CORNER_WINDOW
    truth, _, poses, obs = navcam
    chess = stages.cached_target("chessboard")
    n = chess.points().shape[0]
    # the biases depend on the model, poses and corner models, and on the detections only
    # through where the windows lie (harness.calibrators.bias.corner_bias's q_window): both
    # sides' detections the exact corners
    from targets.centroids import projected_points
    q = np.stack([projected_points(truth, chess, Rt) for Rt in poses])
    from harness.calibrators.base import Observations
    ref = Observations(q=q, p_board=chess.points(), imagersize=obs.imagersize,
                       corner_model=np.full((len(poses), n), CORNER_WINDOW),
                       corner_blur_px=np.zeros(len(poses)))
    det = ref.replace(corner_model=np.full((len(poses), n), CORNER_LINES),
                      corner_blur_px=np.full(len(poses), 0.8))
    Rts = np.asarray(poses)
    b = verdict.corner_biases(det, ref, truth, chess, Rts)
    assert b is not None and b[0].shape == b[1].shape == q.shape
    assert np.max(np.abs(b[0] - b[1])) > 1e-4        # the two models' biases differ
    moved = det.replace(q=q + (b[0] - b[1]))
    assert verdict.detection_noise(moved, ref, b)["rms"] < 1e-12
    assert verdict.detection_noise(moved, ref)["rms"] > 1e-5
    # alike on both sides, dots, or no poses: nothing to take off
    assert verdict.corner_biases(ref, ref, truth, chess, Rts) is None
    assert verdict.corner_biases(det, ref, truth, stages.cached_target("dots"), Rts) is None
    assert verdict.corner_biases(det, ref, truth, chess, None) is None


def test_two_fits_of_any_model_compare(navcam):
    truth = navcam[0]
    moved = truth.replace(H=truth.H + 0.01 * truth.A)      # Hc + 0.01 px
    d = verdict.fit_parameter_differences(truth, moved, theta_estimated=True,
                                          world_frame=True)
    assert d["Hc"] == pytest.approx(0.01, rel=1e-6)
    assert abs(d["Vc"]) < 1e-9
    same = verdict.fit_projection_difference(truth, truth, truth, mode="intrinsics")
    assert same["max"] < 1e-9
    # intrinsics mode: 0.01 px everywhere (a shift of Hc is a shift of every pixel)
    sh = verdict.fit_projection_difference(truth, moved, truth, mode="intrinsics")
    assert sh["rms"] == pytest.approx(0.01, rel=1e-3)
    # a rotation absorbs most of a centre shift: what is left is far smaller
    rot = verdict.fit_projection_difference(truth, moved, truth, mode="rotation")
    assert rot["rms"] < 0.2 * sh["rms"]


def test_a_fit_against_itself_is_zero_with_its_counts(navcam):
    # the AprilTag records' exact fit IS the image fit: every mode exactly 0 where the fit
    # projects, no rotation, and the counts those of a comparison with a copy (whose
    # differences are rounding: 1e-12 px)
    truth = navcam[0]
    fit = truth.replace(H=truth.H + 0.01 * truth.A)
    copy = fit.replace()
    for mode in ("rotation", "intrinsics", "world"):
        d = verdict.fit_projection_difference(fit, fit, truth, mode=mode)
        c = verdict.fit_projection_difference(fit, copy, truth, mode=mode)
        assert d["rms"] == 0.0 and d["max"] == 0.0 and c["max"] < 1e-9
        assert (d["n"], d["n_invalid"]) == (c["n"], c["n_invalid"]) and d["n"] > 0
        assert d.get("rotation_deg", 0.0) == 0.0


def test_opencv_fits_compare_with_each_other():
    from harness.calibrators.opencv_fit import OpenCVModel
    K = np.array([[1000.0, 0, 511.5], [0, 1000.0, 511.5], [0, 0, 1]])
    a = OpenCVModel("OPENCV5", K, [0.01, 0, 0, 0, 0], 1024, 1024)
    K2 = K.copy()
    K2[0, 2] += 0.02
    b = OpenCVModel("OPENCV5", K2, [0.01, 0.001, 0, 0, 0], 1024, 1024)
    d = verdict.fit_parameter_differences(a, b)
    assert d["Hc"] == pytest.approx(0.02, rel=1e-9)
    assert d["D1"] == pytest.approx(0.001, rel=1e-9)
    _, truth = stages.camera_truth("15", "CAHV")
    p = verdict.fit_projection_difference(a, b, truth, mode="intrinsics")
    assert 0.02 <= p["max"] < 1.0


@pytest.mark.parametrize("cal", ["jpl", "mrcal"])
def test_assess_a_shift_of_every_detection(navcam, cal):
    r'''A renderer that draws everything 0.01 px to the right: the image fit moves by that
much from the exact fit (Hc + 0.01 px in intrinsics), the floor stays at the
calibrator's own level (jpl: exact to ~1e-6 px), and total = floor + renderer'''
    truth, target, poses, obs = navcam
    img = obs.replace(q=obs.q + np.array([0.01, 0.0]))
    cache = {}
    exact, noise, reused = verdict.exact_fit(cal, "CAHVOR", {}, img, target, truth, cache)
    assert not reused and exact.ok
    assert noise["rms"] == pytest.approx(0.01, rel=1e-6)
    res = stages.calibrate_stage(cal, img, target, "CAHVOR", truth, {})
    params, proj, _ = stages.compare_stage(truth, res)
    v = verdict.assess(truth, res, exact, noise, params, proj,
                       modes=("rotation", "intrinsics", "world"))
    assert v["floor"]["projection"]["rms"] < 1e-4
    assert not v["floor_far"] and v["floor_reason"] == ""
    r = v["renderer"]["projection"]
    assert r["intrinsics"]["rms"] == pytest.approx(0.01, rel=0.05)
    if cal == "jpl":   # world frame: the centre moves, nothing else does
        assert v["renderer"]["params"]["Hc"] == pytest.approx(0.01, rel=0.02)
        assert r["world"]["rms"] == pytest.approx(0.01, rel=0.05)
    assert v["total"]["projection"]["rms"] == proj["rms"]
    # by default (harness.campaign.VERDICT_MODES) the floor and renderer have the headline
    # mode only, the same numbers; the total keeps the record's every mode
    d = verdict.assess(truth, res, exact, noise, params, proj)
    for part in ("floor", "renderer"):
        assert set(d[part]["projection"]) == {"rms", "max", "rotation"}
        assert d[part]["projection"]["rotation"] == v[part]["projection"]["rotation"]
    assert d["renderer"]["params"] == v["renderer"]["params"]
    Record(fullname="x", camera="15", camera_label="", model="CAHVOR", target="dots",
           renderer="raycast", settings={}, calibrator=cal, calibrator_model="CAHVOR",
           status="ok", verdict=v).as_dict()


def test_twins_share_the_exact_observations_and_the_exact_fit(navcam):
    r'''A twin (the camera moved 0.1 m along H', as the catalogue's stereo partners): the
same detections at the same planned poses give the same exact observations, bit for
bit, and the same fit of a calibrator that does not read the world frame (made once);
jpl, which reads the surveyed poses, fits each camera'''
    truth, target, poses, obs = navcam
    twin = truth.replace(C=truth.C + 0.1 * truth.photogrammetric().Hp)
    obs_t = stages.observations_from(twin, target, poses, list(obs.q))
    assert not np.array_equal(obs_t.Rt_ref_board, obs.Rt_ref_board)
    ca, ct = {}, {}
    a, na, ra = verdict.exact_fit("mrcal", "CAHVOR", {}, obs, target, truth, ca,
                                  Rt_cam_board=poses)
    b, nb, rb = verdict.exact_fit("mrcal", "CAHVOR", {}, obs_t, target, twin, ct,
                                  Rt_cam_board=poses)
    assert (ra, rb) == (False, True) and a is b and nb == na
    assert np.array_equal(ca["obs"].q, ct["obs"].q, equal_nan=True)
    # each camera's exact observations keep its own surveyed poses (jpl reads them)
    assert np.array_equal(ct["obs"].Rt_ref_board, obs_t.Rt_ref_board)
    c, _, rc = verdict.exact_fit("jpl", "CAHVOR", {}, obs, target, truth, ca,
                                 Rt_cam_board=poses)
    d, _, rd = verdict.exact_fit("jpl", "CAHVOR", {}, obs_t, target, twin, ct,
                                 Rt_cam_board=poses)
    assert not rc and not rd and c is not d
    # from the surveyed poses instead of the planned ones (no Rt_cam_board), the twins'
    # exact observations agree to rounding (one rigid motion and back: ~1e-12 px of
    # ~1000 px coordinates), not bit for bit
    x = verdict.exact_observations(obs_t, twin, target)
    ok = np.isfinite(x.q)
    assert np.max(np.abs(x.q[ok] - ca["obs"].q[ok])) < 1e-9


def test_an_exact_fit_of_the_same_inputs_is_made_once_per_process(navcam):
    r'''The exact fit does not depend on the renderer: the same camera, poses and mask
under another renderer reuse it; another detected mask does not'''
    truth, target, poses, obs = navcam
    verdict._EXACT_FITS.clear()
    a, _, ra = verdict.exact_fit("jpl", "CAHV", {}, obs, target, truth, {})
    noisy = obs.replace(q=obs.q + 0.001)            # other "images", same points found
    b, _, rb = verdict.exact_fit("jpl", "CAHV", {}, noisy, target, truth, {})
    assert (ra, rb) == (False, True) and a is b
    q = obs.q.copy()
    q[0, 0] = np.nan
    c, _, rc = verdict.exact_fit("jpl", "CAHV", {}, obs.replace(q=q), target, truth, {})
    assert not rc and c is not a


def test_far_floor_says_why_in_words(navcam):
    truth = navcam[0]
    th = truth.photogrammetric().theta_deg
    far, why = verdict.floor_judgement(truth, "mrcal", "CAHVOR", {"rms": 1.3},
                                       {"rms": 1e-7}, {"rms": 0.001})
    if abs(th - 90) > verdict.THETA_NAMED_DEG:
        assert "cannot represent theta" in why
    assert far and "floor 1.3 px" in why
    far, why = verdict.floor_judgement(truth, "opencv", "OPENCV5", {"rms": 0.2},
                                       {"rms": 0.02}, {"rms": 0.001})
    assert far and "cannot fit the exact observations" in why
    assert "cannot represent the camera, or its solver stopped short" in why
    # a misfit in the truth's own family (jpl holds theta): the solver's, said so
    far, why = verdict.floor_judgement(truth, "jpl", "CAHVOR", {"rms": 0.2},
                                       {"rms": 0.02}, {"rms": 0.001})
    assert far and "solver stopped short: the truth is a CAHVOR" in why
    # below the stated tolerance, or below what the images show: not far
    assert verdict.floor_judgement(truth, "jpl", "CAHVOR", {"rms": 0.005}, {"rms": 0.0},
                                   {"rms": 0.001}) == (False, "")
    assert verdict.floor_judgement(truth, "jpl", "CAHVOR", {"rms": 0.05}, {"rms": 0.0},
                                   {"rms": 0.1}) == (False, "")


def test_old_records_load_without_a_verdict():
    d = Record(fullname="x", camera="15", camera_label="", model="CAHVOR", target="dots",
               renderer="raycast", settings={}, calibrator="jpl", calibrator_model="CAHVOR",
               status="ok").as_dict()
    del d["verdict"]
    assert Record.from_dict(d).verdict is None


def test_report_rows_show_floor_renderer_total_side_by_side():
    from reports.tables import summary_tables, verdict_rows
    base = dict(camera="15", camera_label="", model="CAHVOR", target="dots",
                renderer="raycast", settings={}, calibrator="mrcal", calibrator_model="CAHVOR",
                status="ok", projection={"rms": 1.3, "max": 2.0})
    far = {"floor": {"projection": {"rms": 1.29}}, "renderer": {"projection": {"rms": 0.001}},
           "total": {"projection": {"rms": 1.3}}, "floor_far": True,
           "floor_reason": "mrcal's model frame cannot represent theta = 90.076 deg"}
    recs = {"a": Record(fullname="a", verdict=far, **base).as_dict(),
            "b": Record(fullname="b", **base).as_dict()}      # an old record: no verdict
    rows = verdict_rows(recs)
    assert rows == [("a", "1.29", "0.001", "—", "1.3",
                     "mrcal's model frame cannot represent theta = 90.076 deg")]
    (t,) = summary_tables(recs)
    cells = {row[0]: row[3] for row in t.rows}
    assert cells["floor: exact-observation fit vs truth, projection RMS, worst"] == "1.29"
    assert "1 ok with a floor far from the truth" in t.note


@pytest.mark.parametrize("cal, model", [("jpl", "CAHVOR"), ("mrcal", "CAHVOR"),
                                        ("opencv", "OPENCV5")])
def test_scatter_of_seeded_noise(navcam, cal, model):
    r'''0.001 px of isotropic Gaussian detection noise: the noise per image is measured
back (within 15%: 100 points per image), every sigma is positive and finite and the
z-scores of one draw are of order one (a z above 6 has probability 2e-9 per quantity;
8 draws of each gave mean-square z 0.1-1.3 for navcam 15)'''
    truth, target, poses, obs = navcam
    rng = np.random.default_rng(7)
    img = obs.replace(q=obs.q + rng.normal(0, 0.001 / np.sqrt(2), obs.q.shape))
    exact, noise, _ = verdict.exact_fit(cal, model, {}, img, target, truth, {})
    res = stages.calibrate_stage(cal, img, target, model, truth, {})
    params, proj, _ = stages.compare_stage(truth, res)
    v = verdict.assess(truth, res, exact, noise, params, proj, obs=img)
    assert v["scatter"]["noise_per_pose"] == pytest.approx([0.001] * 6, rel=0.15)
    sigma = v["renderer"]["sigma"]
    assert {"Hc", "Vc", "Hs", "Vs", "projection_rms"} <= set(sigma)
    assert all(s >= 0 and np.isfinite(s) for s in sigma.values())
    assert 1e-4 < sigma["projection_rms"] < 0.01
    assert max(v["renderer"]["z"].values()) < 6
    if cal == "jpl":
        assert sigma["Hc"] == pytest.approx(0.00106, rel=0.2)


def test_an_off_axis_camera_is_not_applicable_with_its_reason():
    r'''SuperCam's optical centre lies far outside its image: the planner's refusal is a
not-applicable record with the reason, not a failure'''
    _, truth = stages.camera_truth("SuperCam", "CAHV")
    with pytest.raises(stages.StageFailed) as e:
        stages.poses_stage(truth, stages.cached_target("dots"), 6, 0)
    assert e.value.status == "not-applicable"
    assert "far outside" in e.value.reason and "deg off its axis" in e.value.reason


@pytest.mark.slow
def test_renderer_gate_passes_the_exact_renderer_and_flags_a_half_pixel_shift(tmp_path):
    from harness.campaign import parse_campaign
    from harness.gate import DEFAULT_SPEC, check, load_gate_spec
    from harness.mutation import campaign_doc
    from harness.runner import run_campaign
    spec = load_gate_spec(DEFAULT_SPEC)
    verdict._EXACT_FITS.clear()        # the module's other tests fit these exact observations
    cals = [{"name": "jpl"}, {"name": "mrcal"}, {"name": "opencv", "models": ["OPENCV5"]}]
    out = {}
    for fault in (None, "half_pixel"):
        doc = dict(campaign_doc(15, "CAHVOR", fault), calibrator=cals)
        run = run_campaign(parse_campaign(doc), tmp_path / str(fault), progress=False,
                           workers=1)
        out[fault] = (run, check(run, spec))
    run, failures = out[None]
    assert failures == []
    recs = run["records"]
    assert all(r["status"] == "ok" and r["verdict"]["renderer"]["z"] for r in recs.values())
    jpl = next(r for k, r in recs.items() if "/jpl[" in k)
    assert jpl["verdict"]["floor"]["projection"]["rms"] < 1e-5     # jpl is exact on exact data
    assert jpl["seconds"]["exact_fit"] > 0
    # the exact observations are computed once per job, by its first calibrator (jpl), and
    # their cost is counted there (job_records: exact_observations), not left out
    assert jpl["seconds"]["exact_observations"] > 0
    # the exact fits start from each job's image fit (harness.job_records): not shared
    assert run["minimum_detectable_faults"]["cameras"]["15"]["Hc shift"]["value"] < 0.01
    opencv = next(r for k, r in recs.items() if "/opencv[" in k)
    assert opencv["verdict"]["floor_far"] and "floor" in opencv["reason"]
    _, failures = out["half_pixel"]
    flagged = {f.fullname.rsplit("/", 1)[-1] for f in failures}
    assert {"jpl[CAHVOR]", "opencv[OPENCV5]"} <= flagged
    assert any(f.field == "verdict.renderer.params.Hc" and "sigma" in f.value
               for f in failures)


@pytest.mark.parametrize("cal, model", [("opencv", "OPENCV5"), ("mrcal", "CAHVOR")])
def test_blockwise_pose_jacobian_is_the_full_one(navcam, cal, model):
    r'''A board pose's columns are differenced on its own rows only: the same numbers
(bit for bit: every other row's difference is exactly zero)'''
    truth, target, poses, obs = navcam
    q = obs.q.copy()
    q[2, :10] = np.nan                       # an image with points missing
    obs = obs.replace(q=q)
    res = stages.calibrate_stage(cal, obs, target, model, truth, {})
    lin = verdict.linearisation(res, obs)
    full = verdict._central_jacobian(lin.project, lin.x0, lin.steps)
    assert np.array_equal(lin.jacobian(), full)


def test_fits_in_different_minima_are_named():
    r'''The image fit could take the exact fit's parameters: a residual RMS far above
noise + the exact fit's residual means it stopped in another minimum (the numbers of
mrcal CAHVOR on camera 5, K=16)'''
    from harness.calibrators.base import CalibrationResult

    def fit(rms):
        r = np.zeros((1, 2, 2))
        r[0, :, 0] = rms
        return CalibrationResult(calibrator="mrcal", model_name="CAHVOR", status="ok",
                                 residuals=r)
    dis, why = verdict.minima_judgement(fit(0.0229), fit(3.7e-9), {"rms": 0.00124})
    assert dis and "image fit stopped in another minimum" in why
    assert verdict.minima_judgement(fit(0.0011), fit(1e-8), {"rms": 0.00124}) == (False, "")
    # a fault the model cannot absorb shows in the detections too: not a disagreement
    assert verdict.minima_judgement(fit(0.3), fit(1e-8), {"rms": 0.35}) == (False, "")


@pytest.mark.parametrize("cal, model", [("jpl", "CAHVOR"), ("mrcal", "CAHVOR"),
                                        ("opencv", "OPENCV5")])
def test_warm_started_exact_fit_is_the_cold_one(navcam, cal, model):
    r'''The exact fit started from the image fit (job_records: start=res) is the cold
exact fit where the cold one is in the image fit's minimum (navcam 15, 0.001 px of
seeded noise). Measured warm - cold projection RMS: jpl 4e-12 px, OpenCV 3e-9 px, mrcal
7e-7 px (mrcal's cold restarts crawl on along its flat R0 / focal-length valley; the warm
fit stops where the image fit's minimum is: floor 5e-8 px against 8e-7 px). Held to
1e-5 px, 1% of the detection noise: the renderer verdict resolves the noise's scatter
(sigma of the projection RMS > 1e-4 px: test_scatter_of_seeded_noise), so a difference
a hundred times below it cannot move a verdict. The cold fit's bias passes run to a
tolerance of 1e-10 px: at the calibrators' 1e-5 px (the warm fit's) the cold OpenCV fit
is itself 1.1e-5 px (max) from its converged value.
All three start from the image fit's bias (skeleton.start_bias; mrcal from the bias its
image fit settled at): a solve or two instead of a solve without the bias and the passes
that bring it back (3-5 solves). jpl and OpenCV hold it (one solve, no bias pass: the bias
the verdict's scatter holds, jpl_fit.fit's note); the bias at the warm fit's own model
differs by ~1e-5 px (the bias tolerance), which the tolerances below cover.'''
    truth, target, poses, obs = navcam
    rng = np.random.default_rng(11)
    img = obs.replace(q=obs.q + rng.normal(0, 0.001 / np.sqrt(2), obs.q.shape))
    res = stages.calibrate_stage(cal, img, target, model, truth, {})
    verdict._EXACT_FITS.clear()
    tight = {"bias_tolerance": 1e-10, "bias_passes": 12}
    cold, noise, _ = verdict.exact_fit(cal, model, tight, img, target, truth, {})
    warm, _, reused = verdict.exact_fit(cal, model, {}, img, target, truth, {}, start=res)
    assert not reused and warm is not cold          # another start: not the memo's fit
    assert warm.ok and warm.info["warm_start"] is True
    assert warm.info["bias"] is not None and len(warm.info["passes"]) <= 2
    if cal in ("jpl", "opencv"):
        # the image fit's bias, held: obs.q - (obs.q - b) rounds b's last bits only
        assert len(warm.info["passes"]) == 1
        np.testing.assert_allclose(warm.info["bias"], res.info["bias"], rtol=0, atol=1e-12)
    d = verdict.fit_projection_difference(cold.model, warm.model, truth)
    # OpenCV fits float32 points: each coordinate rounded by up to 6e-5 px at 1000 px (RMS
    # 3.5e-5), and two fits to points 1e-5 px apart round them differently: the fitted
    # projection moves by ~3.5e-5 sqrt(n / N) = 6e-6 px RMS (n = 40 numbers, N = 1200
    # coordinates); measured warm - tight cold 7e-6 px RMS, 1.2e-5 px max
    tol = (2e-5, 5e-5) if cal == "opencv" else (1e-5, 1e-5)
    assert d["rms"] < tol[0] and d["max"] < tol[1]
    params, proj, _ = stages.compare_stage(truth, res)
    vc = verdict.assess(truth, res, cold, noise, params, proj)
    vw = verdict.assess(truth, res, warm, noise, params, proj)
    for part in ("floor", "renderer"):
        assert vw[part]["projection"]["rms"] == pytest.approx(vc[part]["projection"]["rms"],
                                                              abs=tol[0])
    assert vw["floor_far"] == vc["floor_far"]
    # the same start again: the memo's fit
    again, _, reused = verdict.exact_fit(cal, model, {}, img, target, truth, {}, start=res)
    assert reused and again is warm


def test_a_fractional_difference_of_a_parameter_near_zero_is_judged_like_the_parameter():
    r'''A CAHVOR lens with R1 ~ 0 (navcam 15 with R1 = 1e-8: a nearly distortion-free lens;
the same happened to Mastcam-Z Z110's R2 on the exact ray caster). The exact fit's R1 is
~1e-8, the image fit's ~1e-5 (R1's sigma under 0.001 px of noise is 7e-6), so R1_frac =
(image - exact) / |exact| is ~1e3. Its sigma must be taken over the same |exact|: then
R1_frac's z is R1's (a fractional difference is the absolute one over a constant) and
the renderer gate passes this perfect renderer. Taken over the image fit's |R1| it was
z 1270: a false alarm.'''
    from harness.gate import DEFAULT_SPEC, check, load_gate_spec
    _, t15 = stages.camera_truth("15", "CAHVOR")
    truth = t15.replace(R=np.array([t15.R[0], 1e-8, t15.R[2]]))
    target = stages.cached_target("dots")
    poses = stages.poses_stage(truth, target, 6, 0)
    obs = centroid_observations(truth, target, poses)
    rng = np.random.default_rng(1)
    img = obs.replace(q=obs.q + rng.normal(0, 0.001 / np.sqrt(2), obs.q.shape))
    exact, noise, _ = verdict.exact_fit("jpl", "CAHVOR", {}, img, target, truth, {})
    res = stages.calibrate_stage("jpl", img, target, "CAHVOR", truth, {})
    params, proj, _ = stages.compare_stage(truth, res)
    v = verdict.assess(truth, res, exact, noise, params, proj, obs=img)
    z = v["renderer"]["z"]
    # the case: R1 far below its own sigma, so its fractional difference is huge ...
    assert abs(v["renderer"]["params"]["R1_frac"]) > 100
    assert 0.5 < z["R1"] < 3          # ... while R1 itself moved by an ordinary amount
    assert z["R1_frac"] == pytest.approx(z["R1"], rel=1e-6)
    name = "navcam-R1-0/CAHVOR/dots/raycast/jpl[CAHVOR]"
    run = {"records": {name: {"status": "ok", "calibrator": "jpl", "verdict": v}}}
    assert check(run, load_gate_spec(DEFAULT_SPEC)) == []


def test_corner_targets_are_judged_against_the_detector_on_exact_renders():
    # a constructed camera (not from the catalogue): 800x600 CAHVOR with mild distortion
    from reference_models.cahvore import CAHVOR
    from renderers.base import RenderSettings
    from renderers.raycast import RaycastRenderer
    from targets.centroids import projected_points
    from targets.detect import detect

    f, W, H = 700.0, 800, 600
    truth = CAHVOR(C=[0, 0, 0], A=[0, 0, 1], H=[f, 0, W / 2 - 0.5 + 3.2],
                   V=[0, f, H / 2 - 0.5 - 1.7], O=[0.01, -0.02, 1.0], R=[0, -0.05, 0.01],
                   width=W, height=H)
    target = stages.cached_target("apriltag")
    poses = stages.poses_stage(truth, target, 3, 0)
    r = RaycastRenderer()
    rs = RenderSettings(spp=16, adaptive=True, options=dict(verdict.REFERENCE_RENDER["options"]))

    def observe(model):
        dets = [detect(r.render(model, target.pattern(), Rt, rs).image, target) for Rt in poses]
        return stages.observations_from(truth, target, poses, dets)

    obs = observe(truth)
    assert obs.found.sum() > 100
    obs_x = verdict.exact_observations(obs, truth, target)
    # the images ARE the reference renders (the poses' round trip through the world frame
    # moves them by float rounding only): the renderer's share is nil ...
    d = np.linalg.norm(obs.q - obs_x.q, axis=-1)[obs.found]
    assert d.max() < 1e-6
    # ... while the detector's own share is in the reference, not charged to the images:
    # exact projections differ from it by the corner refiner's bias (0 < ... < 0.005 px)
    exact = np.stack([projected_points(truth, target, Rt) for Rt in poses])
    bias = np.linalg.norm(obs_x.q - exact, axis=-1)[obs.found]
    assert 1e-6 < np.sqrt(np.mean(bias ** 2)) < 0.005
    # a renderer whose principal point is off by 0.01 px shows exactly that against it
    shifted = CAHVOR(C=truth.C, A=truth.A, H=truth.H + 0.01 * truth.A, V=truth.V, O=truth.O,
                     R=truth.R, width=W, height=H)
    dx = (observe(shifted).q - obs_x.q)[..., 0][obs.found]
    assert abs(np.median(dx) - 0.01) < 0.002
    # detections fitted under a blur (a response's PSF): the exact observations' corners come
    # from the sharp reference render, and so does the blur the bias step corrects them
    # under; the job's own detections as the reference keep theirs
    blurred = obs.replace(corner_blur_px=np.full(len(poses), 0.7))
    assert verdict.exact_observations(blurred, truth, target).corner_blur_px is None
    own = verdict.exact_observations(blurred, truth, target, reference=obs.q)
    assert np.array_equal(own.corner_blur_px, blurred.corner_blur_px)


@pytest.mark.parametrize("cal, model", [("jpl", "CAHVOR"), ("mrcal", "CAHVOR"),
                                        ("opencv", "OPENCV5")])
def test_one_pass_model_jacobians_are_the_separate_ones(navcam, cal, model):
    r'''scatter() differences the quantities and the image grid on one set of stepped
models (Linearisation.model_jacobians): the same numbers as differencing each on its
own, bit for bit (the same models, the same steps); jpl's own Jacobian (compiled) agrees
with differencing its projection'''
    truth, target, poses, obs = navcam
    res = stages.calibrate_stage(cal, obs, target, model, truth, {})
    lin = verdict.linearisation(res, obs)
    P = verdict.projection_points(truth)
    grid = verdict._grid_projector(P)
    rest = lin.x0[lin.n_model:]
    Jg, = lin.model_jacobians([grid])
    sep = verdict._central_jacobian(lambda y: grid(lin.model(np.concatenate((y, rest)))),
                                    lin.x0[:lin.n_model], lin.steps[:lin.n_model])
    assert Jg.shape == (2 * len(P), lin.n_model) and np.array_equal(Jg, sep)
    if cal == "jpl":
        # the fit's own Jacobian in closed form (jpl_linearisation: jpl_grid_jacobian on its
        # world points) against central differences of its projection on built models:
        # their truncation and rounding (measured <= 1.2e-6 of a column's scale against the
        # compiled differences on the paper campaign's jpl records; here within 1e-6)
        J = lin.jacobian()
        ref = verdict._central_jacobian(lin.project, lin.x0, lin.steps)
        scale = np.max(np.abs(ref), axis=0)
        assert J.shape == ref.shape and np.all(np.abs(J - ref) <= 1e-6 * scale)


def test_checked_once_builds_the_same_model_without_its_geometry_checks():
    r'''reference_models.cahvore.checked_once (model_jacobians' stepped models): the fields are
converted, normalised and frozen as always (a model that passes the checks comes out bit
for bit the same); only the geometry checks are skipped, inside the context only'''
    from reference_models.cahvore import CAHVORE, ModelError, checked_once
    _, truth = stages.camera_truth("15", "CAHVOR")
    kw = dict(C=truth.C, A=truth.A * (1 + 1e-9), H=truth.H, V=truth.V, O=truth.O, R=truth.R,
              E=np.array([0.0, 0.01, -0.02]), model_type=3, linearity=0.5,
              width=truth.width, height=truth.height)
    a = CAHVORE(**kw)
    with checked_once():
        b = CAHVORE(**kw)
        # A along H: no horizontal focal length, built unchecked inside the context
        CAHVORE(**{**kw, "H": 5.0 * truth.A})
    for f in ("C", "A", "H", "V", "O", "R", "E"):
        assert np.array_equal(getattr(a, f), getattr(b, f))
        assert not getattr(b, f).flags.writeable
    assert b.linearity == a.linearity and b.width == a.width
    with pytest.raises(ModelError, match="parallel"):
        CAHVORE(**{**kw, "H": 5.0 * truth.A})


def test_is_reference_render_names_the_reference_settings_only():
    # the default ray caster at K=16 adaptive (area coverage by default, given or not) is the
    # reference render; any other sampling, renderer or a camera response is not
    assert verdict.is_reference_render("raycast", {"spp": 16, "adaptive": True, "options": {}})
    assert verdict.is_reference_render(
        "raycast", {"spp": 16, "adaptive": True, "options": {"coverage": "area"},
                    "label": "mine"}, {})
    assert not verdict.is_reference_render(
        "raycast", {"spp": 16, "adaptive": True, "options": {"coverage": "point"}})
    assert not verdict.is_reference_render("raycast", {"spp": 4, "adaptive": True,
                                                       "options": {}})
    assert not verdict.is_reference_render("command", {"spp": 16, "adaptive": True,
                                                       "options": {}})
    assert not verdict.is_reference_render(
        "raycast", {"spp": 16, "adaptive": True, "options": {}}, {"psf": {"sigma_px": 0.7}})


@pytest.mark.slow
def test_a_reference_render_job_is_not_rendered_again_for_its_corners(tmp_path, monkeypatch):
    # a job whose images are the reference render gives its own detections as the reference
    # corners; the records are those of a job that renders them again (the same render and
    # detector, the poses' round trip through the world frame aside: ~1e-9 px)
    from harness.campaign import parse_campaign
    from harness.runner import run_campaign
    doc = {"name": "ref", "cameras": [17], "models": ["CAHVOR"], "targets": ["apriltag"],
           "poses": {"n": 3, "seed": 0}, "renderer": [{"name": "raycast", "spp": 16}],
           "calibrator": [{"name": "jpl"}]}
    calls = []
    real = verdict.reference_corners
    monkeypatch.setattr(verdict, "reference_corners",
                        lambda *a: calls.append(1) or real(*a))
    reused = run_campaign(parse_campaign(doc), tmp_path / "reused", progress=False, workers=1)
    assert calls == []
    verdict._EXACT_FITS.clear()
    monkeypatch.setattr(verdict, "is_reference_render", lambda *a: False)
    rendered = run_campaign(parse_campaign(doc), tmp_path / "rendered", progress=False,
                            workers=1)
    assert calls == [1]
    (a,), (b,) = reused["records"].values(), rendered["records"].values()
    assert a["status"] == b["status"] == "ok"
    # the renderer share of the job's own reference is nil: its exact observations are its
    # detections, so the exact fit is the image fit, not fitted again (job_records._exact_fit);
    # re-rendered, float rounding only
    # (a model against itself: the fitted rotation's rounding at most)
    assert a["verdict"]["renderer"]["projection"]["rms"] < 1e-12
    assert a["seconds"]["exact_fit"] == 0.0
    assert b["verdict"]["renderer"]["projection"]["rms"] < 1e-6
    assert a["verdict"]["floor"]["projection"]["rms"] == pytest.approx(
        b["verdict"]["floor"]["projection"]["rms"], rel=1e-3, abs=1e-7)


def test_start_bias_is_the_bias_the_start_was_fitted_with(navcam):
    r'''A fit keeps the bias it applied last (info["bias"] = obs.q - the detections it
fitted); start_bias hands it on only for an ok start of observations of the same shape'''
    from harness.calibrators.skeleton import start_bias
    truth, target, poses, obs = navcam
    res = stages.calibrate_stage("jpl", obs, target, "CAHVOR", truth, {})
    b = res.info["bias"]
    # the dot-centroid bias of a navcam: 0.1 px mean, 0.3 px max (harness.calibrators.bias)
    assert b.shape == obs.q.shape and 0.01 < np.nanmax(np.abs(b)) < 1.0
    assert np.array_equal(start_bias(res, obs), b)
    assert start_bias(res, obs.replace(q=obs.q[:3], p_board=obs.p_board[:3],
                                       Rt_ref_board=obs.Rt_ref_board[:3])) is None
    assert start_bias(res.replace(status="failed"), obs) is None
    assert start_bias(None, obs) is None


@pytest.mark.slow
def test_a_warm_exact_fit_of_other_corner_models_fits_its_own_bias():
    r'''The exact observations of a blurred image's corners are the sharp reference render's,
fitted under another corner model (the window's, no blur) than the image's (its board lines
under the blur): their bias differs by up to 0.02 px. The warm exact fit must not hold the
image fit's bias on them (skeleton.start_bias: bias_for differs): held, it put a constructed
768x1024 CAHVOR's exact chessboard fit 0.0099 px RMS off the truth (the verdict's floor),
against 1.5e-5 px cold, and the verdict then blamed the calibrator. Here the warm exact fit
is the cold one and the truth's to what the sharp corners allow (1e-4 px: their fits land
1e-5 px from the truth), on a camera built here (not a catalogue slot).'''
    from reference_models.cahvore import CAHVOR
    from renderers.base import RenderSettings
    from renderers.raycast import RaycastRenderer
    from renderers.response import ResponseChain
    from targets.detect import detect

    f, W, H = 650.0, 768, 1024
    truth = CAHVOR(C=[0, 0, 0], A=[0, 0, 1], H=[f, 0, W / 2 - 0.5 - 2.3],
                   V=[0, f, H / 2 - 0.5 + 1.4], O=[0.02, 0.01, 1.0], R=[0, -0.08, 0.02],
                   width=W, height=H)
    target = stages.cached_target("chessboard")
    poses = stages.poses_stage(truth, target, 4, 0)
    r = RaycastRenderer()
    rs = RenderSettings(spp=16, adaptive=True, options=dict(verdict.REFERENCE_RENDER["options"]))
    psf = ResponseChain.from_config({"psf": {"kind": "gaussian", "sigma_px": 0.7}})
    dets = [detect(psf.apply(r.render(truth, target.pattern(), Rt, rs).image, model=truth,
                             seed=0).image, target) for Rt in poses]
    obs = stages.observations_from(truth, target, poses, dets)
    assert obs.found.sum() > 300 and obs.corner_blur_px is not None
    res = stages.calibrate_stage("jpl", obs, target, "CAHVOR", truth, {})
    assert res.ok
    verdict._EXACT_FITS.clear()
    cache = {}
    warm, _, reused = verdict.exact_fit("jpl", "CAHVOR", {}, obs, target, truth, cache,
                                        start=res, Rt_cam_board=list(poses))
    cold, _, _ = verdict.exact_fit("jpl", "CAHVOR", {}, obs, target, truth, {},
                                   Rt_cam_board=list(poses))
    assert not reused and warm.ok and warm.info["warm_start"] is True
    assert verdict.fit_projection_difference(cold.model, warm.model, truth)["rms"] < 1e-5
    assert verdict.fit_projection_difference(truth, warm.model, truth)["rms"] < 1e-4
    # its own passes: the bias of the window corners, not the image's lines'
    assert len(warm.info["passes"]) >= 2
    from harness.calibrators.skeleton import bias_inputs, start_bias
    obs_x = cache["obs"]
    assert res.info["bias_for"] == bias_inputs(obs) != bias_inputs(obs_x)
    assert start_bias(res, obs_x) is None and start_bias(res, obs) is not None


def test_variances_are_sums_of_squares_in_an_ill_conditioned_direction():
    # two parameter columns that differ by 1e-2 in 1e8 (mrcal's CAHVOR R0 / focal valley:
    # the fit barely tells them apart) and the quantity that is their difference. Its
    # variance is eps^2 g^T D g = 1e-4 x 3; the covariance's entries are ~1e16, so the
    # triple product a^T cov a cancels to rounding of order 1 (it came out <= 0 on a real
    # record). As sums of squares it is the difference of the columns, computed to
    # 1e-8 / 1e-2 = 1e-6 relative (stored columns' rounding); the QR factor of
    # D^1/2 F adds its backward error, a few 50 eps |F| / |F a| ~ 1e-6 (seeds 0-9:
    # <= 1.7e-6), inside the 1e-5 asserted.
    rng = np.random.default_rng(3)
    f = 1e8 * (1.0 + rng.random(50))
    g = rng.standard_normal(50)
    eps = 1e-2
    F = np.stack([f, f + eps * g], axis=1)
    D = 0.5 + rng.random(50)
    A = np.array([[1.0, -1.0], [1.0, 0.0]])
    v = verdict._variances(verdict._gram_factor(F, D), A)
    exact = eps ** 2 * float(D @ (g * g))
    assert v[0] > 0
    assert abs(v[0] - exact) <= 1e-5 * exact
    assert abs(v[1] - float(D @ (f * f))) <= 1e-12 * v[1]


def test_a_failed_fit_names_what_its_model_cannot_represent():
    r'''mrcal CAHV on a theta = 88 deg camera ends above max_rms at its best misfit: its
reason says theta, not only "diverged"; jpl (which holds theta) and a square camera
keep the plain reason'''
    from pathlib import Path

    from harness.calibrators.base import CalibrationResult
    from harness.job_records import _failure_reason
    from reference_models.jpl_files import read_model
    cams = Path(__file__).resolve().parents[1] / "campaigns" / "cameras"
    skewed = read_model(cams / "theta88-800x600.cahv")
    assert abs(skewed.photogrammetric().theta_deg - 90.0) > 1.0
    failed = CalibrationResult(calibrator="mrcal", model_name="CAHV", status="failed",
                               reason="diverged: RMS residual 1.02 px > 1 px")
    why = _failure_reason(failed, skewed, "mrcal")
    assert why.startswith("diverged: RMS residual 1.02 px > 1 px; ")
    assert "mrcal's model frame cannot represent theta = 88" in why
    assert "best misfit" in why
    assert _failure_reason(failed, skewed, "jpl") == failed.reason
    other = CalibrationResult(calibrator="mrcal", model_name="CAHV", status="failed",
                              reason="exception inside mrcal: boom")
    assert _failure_reason(other, skewed, "mrcal") == other.reason
    square = read_model(cams / "tiny-320x240.cahvor")       # theta 90 deg
    assert abs(square.photogrammetric().theta_deg - 90.0) < 1e-9
    assert _failure_reason(failed, square, "mrcal") == failed.reason
    assert verdict.unrepresentable(skewed, "opencv") and not verdict.unrepresentable(skewed,
                                                                                    "jpl")


def _perturbed(m, rng, scale=1e-4):
    r'''m with its vectors moved by ~scale (relative): a fit near the model, neither the
truth nor exactly on a symmetry'''
    from reference_models.cahvore import CAHV, CAHVOR, CAHVORE

    def mv(v):
        v = np.asarray(v, dtype=np.float64)
        return v + scale * np.linalg.norm(v) * rng.standard_normal(3)
    kw = dict(C=mv(m.C) + 1e-3, A=mv(m.A), H=mv(m.H), V=mv(m.V), width=m.width,
              height=m.height)
    if m.family == "CAHV":
        return CAHV(**kw)
    kw.update(O=mv(m.O), R=np.asarray(m.R) * (1 + scale * rng.standard_normal(3)))
    if m.family == "CAHVOR":
        return CAHVOR(**kw)
    return CAHVORE(E=np.asarray(m.E) + scale * rng.standard_normal(3),
                   model_type=m.model_type, linearity=m.linearity, **kw)


def _camera(case):
    r'''(truth, fit) of one of CHART_CASES'''
    return _cameras()[CHART_CASES.index(case)]


CHART_CASES = ("15 CAHV", "13 CAHVOR", "17 CAHVOR", "17 CAHVORE", "22 CAHVORE",
               "17 CAHVORE L=0.0", "17 CAHVORE L=0.5", "17 CAHVORE L=-0.5",
               "17 CAHVORE L=1.0", "13 CAHVOR theta")


@functools.cache
def _cameras():
    r'''[(truth, fit)] of CHART_CASES: over the three families: a narrow and a wide camera, CAHVORE
perspective, fisheye and in between (linearity 1, 0, 0.5 and -0.5), theta off 90 deg'''
    import dataclasses
    rng = np.random.default_rng(5)
    out = []
    for case in CHART_CASES[:5]:
        _, truth = stages.camera_truth(*case.split())
        out.append((truth, _perturbed(truth, rng)))
    _, t17 = stages.camera_truth("17", "CAHVORE")
    for L in (0.0, 0.5, -0.5, 1.0):
        t = dataclasses.replace(t17, linearity=L)
        out.append((t, _perturbed(t, rng)))
    # theta 90.05 deg: V' turned in the image plane
    _, t = stages.camera_truth("13", "CAHVOR")
    ph = t.photogrammetric()
    c, s = np.cos(np.radians(0.05)), np.sin(np.radians(0.05))
    t = t.with_photogrammetric(dataclasses.replace(ph, Vp=c * ph.Vp - s * ph.Hp))
    out.append((t, _perturbed(t, rng)))
    return out


@pytest.mark.parametrize("case", CHART_CASES)
def test_closed_form_chart_derivatives_are_the_differences(case):
    r'''jpl_quantity_jacobian and jpl_grid_jacobian (the scatter of a jpl fit) against central
differences over stepped models (Linearisation.model_jacobians, steps 1e-6 of each chart
parameter): the differences' own error is their truncation (~h^2 times the third
derivative) and rounding (eps |f| / h ~ 1e-10 relative), measured <= 1.2e-6 of a column's
scale on the paper campaign's jpl records. C moves the frame and the points alike: its
grid columns are zero in closed form, the differences' rounding (~1e-7 px per m against
columns of ~1e3 px) elsewhere.'''
    from harness.calibrators.jpl_fit import _Chart
    truth, fit = _camera(case)
    R0 = float(fit.R[0]) if fit.family != "CAHV" else 0.0
    chart = _Chart(fit.family, fit, getattr(fit, "model_type", None),
                   getattr(fit, "linearity", None), R0)
    x0 = chart.x0()
    lin = verdict.Linearisation(x0, None, chart.model, None, 1e-6 * np.maximum(np.abs(x0), 1.0))
    m0 = chart.model(x0)
    ref = truth     # the exact fit the differences are taken against
    q0 = verdict._signed_quantities(ref, m0, True, True)
    names = list(q0)

    def qvec(m):
        q = verdict._signed_quantities(ref, m, True, True)
        return np.array([q.get(k, 0.0) for k in names])
    P = verdict.projection_points(truth)
    with np.errstate(all="ignore"):
        G, Jg = lin.model_jacobians([qvec, verdict._grid_projector(P)])
    Ga = verdict.jpl_quantity_jacobian(chart, m0, ref, names, True)
    Ja = verdict.jpl_grid_jacobian(chart, m0, P)
    assert Ga is not None and Ga.shape == G.shape and Ja.shape == Jg.shape
    assert {"theta_deg", "C_mm[0]", "A_deg[1]", "roll_deg"} <= set(names)
    gs = np.max(np.abs(G), axis=1, keepdims=True)
    assert np.all(np.abs(Ga - G) <= 1e-6 * gs + 1e-300)
    ok = np.all(np.isfinite(Jg), axis=1)
    assert ok.mean() > 0.5
    assert np.array_equal(ok, np.all(np.isfinite(Ja), axis=1))
    Jg, Ja = Jg[ok], Ja[ok]
    assert np.all(Ja[:, :3] == 0) and np.all(np.abs(Jg[:, :3]) <= 1e-9 * np.abs(Jg).max())
    scale = np.max(np.abs(Jg), axis=0)
    assert np.all(np.abs(Ja - Jg)[:, 3:] <= 1e-5 * scale[3:])
    # fixed world points (the fit's own Jacobian, jpl_linearisation): C's columns too
    from harness.compare import _rotated_into
    from reference_models.kernels import project
    W = _rotated_into(m0.Rt_ref_cam(), P)
    Jf = verdict._central_jacobian(lambda x: project(chart.model(x), W), x0, lin.steps)
    Jwld = verdict.jpl_grid_jacobian(chart, m0, W, world=True)
    okw = np.all(np.isfinite(Jf), axis=1)
    assert np.array_equal(okw, np.all(np.isfinite(Jwld), axis=1))
    assert np.all(np.abs(Jwld - Jf)[okw] <= 1e-5 * np.max(np.abs(Jf[okw]), axis=0))
    # the turns of the points (_projection_sigma's Jw), against its differences (steps 1e-7)
    Jt = verdict.jpl_grid_jacobian(chart, m0, P, turns=True)
    J0 = verdict.jpl_grid_jacobian(chart, m0, P)
    assert np.array_equal(np.isfinite(Jt[:, :-3]), np.isfinite(J0))
    assert np.all(np.abs(Jt[:, :-3] - J0)[ok] <= 1e-12 * np.max(np.abs(J0[ok]), axis=0) + 1e-300)
    assert np.all(np.abs(_turn_differences(m0, P) - Jt[:, -3:])[ok]
                  <= 1e-5 * np.max(np.abs(Jt[:, -3:][ok]), axis=0))


def _turn_differences(m, P):
    r'''_projection_sigma's central differences of the grid in a turn of the points'''
    from harness.compare import _projector
    from reference_models.poseutils import transform_point_Rt
    project, Rt = _projector(m), m.Rt_ref_cam()
    with np.errstate(all="ignore"):
        return verdict._central_jacobian(
            lambda w: project(transform_point_Rt(Rt, P @ verdict._rodrigues(w).T)),
            np.zeros(3), np.full(3, 1e-7))


def _closed_and_differenced(lin, m0, ref, theta, P):
    r'''(names, G, Jg, Ga, Ja, Jw) of a posed fit's linearisation lin at m0: the quantities'
(fit - ref, signed) and the grid P's Jacobians by central differences over stepped models
(model_jacobians: G, Jg) and as the scatter takes them (quantity_jacobian, grid_jacobian:
Ga, Ja and the turns' Jw)'''
    names = list(verdict._signed_quantities(ref, m0, theta, False))

    def qvec(m):
        q = verdict._signed_quantities(ref, m, theta, False)
        return np.array([q.get(k, 0.0) for k in names])
    with np.errstate(all="ignore"):
        G, Jg = lin.model_jacobians([qvec, verdict._grid_projector(P)])
    Ga = lin.quantity_jacobian(m0, ref, names, theta, qvec)
    Ja, Jw = lin.grid_jacobian(P)
    return names, G, Jg, Ga, Ja, Jw


@pytest.mark.parametrize("model", ["CAHV", "CAHVOR"])
def test_mrcal_model_jacobians_are_the_differences(navcam, model):
    r'''A mrcal fit's scatter takes the image grid's derivatives from mrcal.project and the
quantities' in closed form (but R0's column, differenced: the truth side moves with it):
against central differences over stepped models (model_jacobians) to the differences'
own error'''
    truth, target, poses, obs = navcam
    res = stages.calibrate_stage("mrcal", obs, target, model, truth, {})
    lin = verdict.linearisation(res, obs)
    assert lin.grid_jacobian is not None and lin.quantity_jacobian is not None
    m0 = lin.model(lin.x0)
    P = verdict.projection_points(truth)
    names, G, Jg, Ga, Ja, Jw = _closed_and_differenced(lin, m0, truth, res.theta_estimated, P)
    assert np.all(np.abs(_turn_differences(m0, P) - Jw) <= 1e-5 * np.max(np.abs(Jw), axis=0))
    assert Ga is not None and Ga.shape == G.shape and Ja.shape == Jg.shape
    if model == "CAHVOR":
        assert {"O_deg[0]", "R1_frac", "R0"} <= set(names)
    assert np.all(np.abs(Ga - G) <= 1e-6 * np.max(np.abs(G), axis=1, keepdims=True))
    ok = np.all(np.isfinite(Jg), axis=1)
    assert ok.all()
    assert np.all(np.abs(Ja - Jg) <= 1e-6 * np.max(np.abs(Jg), axis=0))


def test_opencv_model_jacobians_are_the_differences(navcam):
    r'''An OpenCV fit's scatter takes the quantities' derivatives (linear in its intrinsics)
and the image grid's (the 5-coefficient model's, _opencv_grid_jacobian) in closed form:
against central differences over stepped models (model_jacobians) to their own error'''
    truth, target, poses, obs = navcam
    res = stages.calibrate_stage("opencv", obs, target, "OPENCV5", truth, {})
    lin = verdict.linearisation(res, obs)
    m0 = lin.model(lin.x0)
    ex = stages.calibrate_stage("opencv", obs.replace(q=obs.q + 0.01), target, "OPENCV5",
                                truth, {})
    P = verdict.projection_points(truth)
    # another OpenCV fit (ex.model) is the differences' reference
    names, G, Jg, Ga, Ja, Jw = _closed_and_differenced(lin, m0, ex.model,
                                                       res.theta_estimated, P)
    assert Jw is None and {"Hc", "Vs", "D0", "D4"} <= set(names)
    assert np.all(np.abs(Ga - G) <= 1e-6 * np.max(np.abs(G), axis=1, keepdims=True))
    ok = np.all(np.isfinite(Jg), axis=1)
    assert ok.all() and np.all(np.abs(Ja - Jg) <= 1e-6 * np.max(np.abs(Jg), axis=0))
    # the 8-coefficient model's k4..k6 columns too
    d = np.concatenate((lin.x0[:9], [0.01, -0.002, 0.0005]))
    J8 = verdict._opencv_grid_jacobian(d, P)
    from harness.calibrators.opencv_fit import OpenCVModel

    def grid8(t):
        K = np.array([[t[0], 0, t[2]], [0, t[1], t[3]], [0, 0, 1.0]])
        return OpenCVModel("RATIONAL", K, t[4:], m0.width, m0.height).project(P)
    F8 = verdict._central_jacobian(grid8, d, 1e-6 * np.maximum(np.abs(d), 1.0))
    assert np.all(np.abs(J8 - F8) <= 1e-6 * np.max(np.abs(F8), axis=0))
