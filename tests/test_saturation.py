r'''Clipped pixels and column bleed (targets.saturation) on real renders: the ray caster's dots
on constructed cameras through renderers.response's stages, and what the record, the gate
and the report say of them

A CCD 15% overexposed without anti-blooming (the `blooming` variant of
benchmarks/bench_photometric.py) spills its wells' excess along the columns: the dots move
0.3-0.6 px, a true bias of the images. Its records must say so in words; a plain clip (30%
overexposed, `saturation`), the clean render and the other photometric stages must not.
'''

from pathlib import Path

import numpy as np
import pytest

from reference_models.catalogue import load_model_file
from targets import saturation as ts
from targets.boards import load_target

ROOT = Path(__file__).resolve().parents[1]
FULL_WELL_E = 20000
CLIP = {"global_gain": {"gain": 1.3}, "saturation": {}}
BLOOM = {"global_gain": {"gain": 1.15}, "saturation": {"blooming": True}}


def _pinhole_640():
    r'''A constructed camera of this test: a 640x480 CAHV of 60 deg, centred'''
    from targets_render import pinhole
    return pinhole(640, 480, 554.0)


@pytest.fixture(scope="module")
def renders():
    r'''{camera: (model, [clean ray-caster renders])}: the barrel CAHVOR of campaigns/cameras
(2 poses) and a 640x480 pinhole (2 poses), 16 samples a side, adaptive, area coverage'''
    from harness.stages import poses_stage, render_stage
    target = load_target("dots")
    out = {}
    for name, model in (("barrel", load_model_file(ROOT / "campaigns" / "cameras" /
                                                   "barrel-1024x768.cahvor")),
                        ("pinhole", _pinhole_640())):
        poses = poses_stage(model, target, 6, 0)[:2]
        imgs = [r.image for r in render_stage("raycast", model, target, poses,
                                              {"spp": 16, "adaptive": True,
                                               "options": {}})[0]]
        out[name] = (model, imgs)
    return out


def _respond(cfg, img, model, seed=0):
    from renderers.response import ResponseChain
    return ResponseChain.from_config({"full_well_e": FULL_WELL_E, "seed": seed, **cfg}) \
        .apply(img, model=model).image


def _summary(cfg, renders, cam, transpose=False):
    model, imgs = renders[cam]
    ms = []
    for i, img in enumerate(imgs):
        if transpose:   # the same sensor turned a quarter: its charge runs along the rows
            out = _respond(cfg, np.ascontiguousarray(img.T), model, seed=i).T
        else:
            out = _respond(cfg, img, model, seed=i)
        ms.append(ts.measure(out))
    return ts.summarise(ms)


@pytest.mark.parametrize("cam", ["barrel", "pinhole"])
def test_blooming_is_named_and_a_plain_clip_is_not(renders, cam):
    model, imgs = renders[cam]
    # the clean render's white board (albedo 0.9) never reaches full scale
    assert ts.measure(imgs[0])["fraction"] == 0.0
    assert ts.summarise([ts.measure(im) for im in imgs]) is None
    clip = _summary(CLIP, renders, cam)
    bloom = _summary(BLOOM, renders, cam)
    # both clip nearly all the board: only its dots' rims stay below full scale
    assert clip["fraction"] > 0.9 and bloom["fraction"] > 0.9
    assert not clip["blooming"] and ts.sentence(clip) == ""
    # a sampled boundary's lone jumps are 2 px at most: the clip has none of 3 px or more
    assert clip["column_jumps"] == 0, clip
    assert bloom["blooming"], bloom
    assert bloom["column_jumps"] > 3 * bloom["row_jumps"] + 20, bloom
    assert bloom["bleed_px"] >= ts.JUMP_MIN
    text = ts.sentence(bloom)
    assert text.startswith(f"the images are saturated ({100 * bloom['fraction']:.0f}% of the "
                           f"board at full scale, bleed along columns up to "
                           f"{bloom['bleed_px']} px)")
    assert text.endswith("the detector's positions move with the blooming, not the "
                         "renderer's geometry")


def test_bleed_along_rows_is_not_bleed_along_columns(renders):
    # the same blooming on a sensor turned a quarter: the charge runs along the image's
    # rows; the columns are the control then, and nothing is said of columns
    s = _summary(BLOOM, renders, "barrel", transpose=True)
    assert s["fraction"] > 0.9
    assert s["row_jumps"] > 3 * s["column_jumps"] + 20 and not s["blooming"], s


@pytest.mark.parametrize("cfg", [
    # overexposed and then blurred, noisy or quantised, as a real camera's clip would be
    {**CLIP, "psf": {"kind": "gaussian", "sigma_px": 0.7}},
    {**CLIP, "shot_noise": {}, "read_noise": {"sigma_e": 12.0}, "quantise": {"bits": 12}},
    {**CLIP, "hot_pixels": {"fraction": 1e-4, "charge_e": 10000.0}},
    {**CLIP, "encoding": {"kind": "srgb"}, "quantise": {"bits": 8}},
    # not overexposed: nothing at full scale at all
    {"psf": {"kind": "gaussian", "sigma_px": 1.5}},
    {"vignetting": {"model": "cos4"}},
], ids=["clip+psf", "clip+noise+12bit", "clip+hot", "clip+srgb8", "psf_wide", "vignetting"])
def test_other_photometry_is_not_blooming(renders, cfg):
    s = _summary(cfg, renders, "barrel")
    if "saturation" not in cfg:
        assert s is None
        return
    assert s["fraction"] > 0.5 and not s["blooming"], s


def test_detect_stores_the_measure_once_per_image(renders):
    from targets.detect import detect
    model, imgs = renders["pinhole"]
    target = load_target("dots")
    det = detect(_respond(BLOOM, imgs[0], model), target)
    sat = det.info["saturation"]
    assert det.status == "ok" and sat["fraction"] > 0.9 and sat["column_jumps"] > 0
    assert "saturation" in det.as_dict()["info"]
    clean = detect(imgs[0], target)
    assert clean.info["saturation"] == {"full_scale": 1.0, "fraction": 0.0, "clipped": 0,
                                        "light": 0}


def test_uint8_full_scale_is_its_top_code():
    img = np.full((40, 60), 200, np.uint8)
    img[10:30, 20:40] = 255
    m = ts.measure(img)
    assert m["full_scale"] == 1.0 and m["clipped"] == 400 and m["fraction"] == 1.0
    # a float image beyond 1 has no converter: its maximum is its full scale
    m = ts.measure(img.astype(np.float64) * 2.0)
    assert m["full_scale"] == 510.0 and m["clipped"] == 400


def _det(n_found, saturation):
    from targets.detection import Detection
    return Detection(q=np.zeros((4, 2)), found=np.ones(4, bool), status="ok", reason="",
                     n_expected=4, n_found=n_found, info={"saturation": saturation})


def test_record_reason_gate_cause_and_report(tmp_path):
    from harness.gate import check, format_failures, load_gate_spec, record_cause
    from harness.job_records import detections_summary, pose_subset
    from reports.build import failure_causes, failure_header, verdict
    bloom = {"full_scale": 1.0, "fraction": 0.98, "clipped": 980, "light": 1000,
             "feature_px": 12, "column_jumps": 40, "row_jumps": 2, "bleed_px": 9}
    clip = dict(bloom, column_jumps=0, row_jumps=1, bleed_px=0)
    summary = detections_summary([_det(4, bloom), _det(4, bloom), _det(4, clip)])
    sat = summary["saturation"]
    assert sat["blooming"] and sat["bleed_px"] == 9 and sat["column_jumps"] == 80
    assert sat["fraction"] == pytest.approx(0.98)
    # a calibrator fitting the first pose only: its images' summary (40 vs 2: still blooms)
    sub = pose_subset({"obs": _obs(3), "detections": summary}, 1)["detections"]
    assert sub["saturation"]["column_jumps"] == 40 and len(sub["saturation"]["per_pose"]) == 1
    assert "saturation" not in detections_summary([_det(4, {"full_scale": 1.0, "fraction":
                                                               0.0, "clipped": 0,
                                                               "light": 0})])
    # the gate: a failing record whose images bloom names the cause; a clipped one does not
    spec = load_gate_spec(ROOT / "campaigns" / "gate-renderer.toml")
    rec = {"fullname": "b/CAHVOR/dots/raycast/jpl[CAHVOR]", "camera": "b", "status": "ok",
           "calibrator": "jpl", "detections": summary,
           "verdict": {"renderer": {"joint": {"chi2": 500.0, "dof": 15, "z": 14.0},
                                    "params": {}, "projection": {"rms": 0.0},
                                    "sigma": {}}}}
    plain = dict(rec, fullname="c/CAHVOR/dots/raycast/jpl[CAHVOR]",
                 detections=detections_summary([_det(4, clip)]))
    doc = {"records": {rec["fullname"]: rec, plain["fullname"]: plain}}
    failures = [f for f in check(doc, spec) if f.field.endswith("joint.chi2")]
    by = {f.fullname: f for f in failures}
    text = ("the images are saturated (98% of the board at full scale, bleed along columns up "
            "to 9 px): the detector's positions move with the blooming, not the renderer's "
            "geometry")
    assert by[rec["fullname"]].cause == text == record_cause(rec)
    assert by[plain["fullname"]].cause == "" and record_cause(plain) == ""
    assert by[rec["fullname"]].as_dict()["cause"] == text
    assert f"{rec['fullname']}: {text}" in format_failures(failures)
    line, rows = verdict(doc, spec)
    assert "1 of these records name the cause" in line
    assert failure_header(rows)[-1] == "cause"
    assert failure_causes(rows) == [(rec["fullname"], text)]


def _obs(n):
    from harness.calibrators.base import Observations
    return Observations(q=np.zeros((n, 4, 2)), p_board=np.zeros((4, 3)), imagersize=(64, 48))
