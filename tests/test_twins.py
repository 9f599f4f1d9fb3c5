r'''Cameras that are one camera: found exactly, rendered once, each with its own records

The catalogue's derived slots (stereo partners and rear-facing copies: 5-7 of
8, 9-11 of 12, 14 of 13, 18 of 17) image every camera-frame point at the same
pixel as their source. A campaign renders them once (harness.jobs.group_twins)
and must give exactly the records it gives without sharing, apart from timings
and info["shared"].
'''

import json

import numpy as np
import pytest

from harness.calibrators import uses_world_frame
from harness.campaign import CampaignError, load_campaign, parse_campaign
from harness.compare import _model_key
from harness.jobs import (
    camera_frame_exact,
    camera_frame_model,
    expand_jobs,
    group_twins,
    same_camera,
)
from harness.records import RunStore, job_filename, without_timings
from harness.runner import run_campaign, stage_seconds
from reference_models.cahvore import truncate
from reference_models.catalogue import load_catalogue
from reports.tables import run_facts

CAT = load_catalogue()


def _model(slot, family=None):
    m = CAT.get(slot).model
    return truncate(m, family) if family else m


@pytest.mark.parametrize("a, b", [(8, 5), (8, 6), (8, 7), (12, 9), (12, 10), (12, 11),
                                  (13, 14), (17, 18)])
def test_derived_slots_are_the_same_camera(a, b):
    assert same_camera(_model(a), _model(b))
    assert same_camera(_model(b), _model(a))
    for family in ("CAHV", "CAHVOR"):
        assert same_camera(_model(a, family), _model(b, family))


@pytest.mark.parametrize("a, b", [(15, 16), (21, 22), (1, 2), (5, 9)])
def test_other_slots_are_not(a, b):
    assert not same_camera(_model(a), _model(b))


def test_a_change_far_below_a_pixel_is_a_different_camera():
    m = _model(17)
    assert same_camera(m, m)
    # the image centre moved by 1e-7 px: H = Hs H' + Hc A
    moved = m.replace(H=np.asarray(m.H) + 1e-7 * np.asarray(m.A))
    assert not same_camera(m, moved)
    assert not same_camera(m, truncate(m, "CAHVOR"))   # the class differs
    assert not same_camera(_model(15), _model(15).replace(width=1023))


def test_paper_campaign_folds_the_derived_slots():
    jobs = expand_jobs(load_campaign("campaigns/paper.toml"))
    grouped = group_twins(jobs)
    twins = {j.key: [k for _, k in j.twins] for j in grouped if j.twins}
    # the dots: 22 cameras x 3 families; the AprilTag grid: each camera under its own
    # family ([target_models]); folded alike
    assert len(jobs) == 66 + 22 and len(grouped) == 57
    own = {"5": "CAHVORE", "9": "CAHVORE", "13": "CAHVOR", "17": "CAHVORE"}
    of = {"5": ["6", "7", "8"], "9": ["10", "11", "12"], "13": ["14"], "17": ["18"]}
    fams = {"13": ("CAHV", "CAHVOR")}
    key = "{}/{}/{}/raycast[spp=16,adaptive,coverage=area]"
    assert twins == {
        **{key.format(c, f, "dots"): of[c] for c in of
           for f in fams.get(c, ("CAHV", "CAHVOR", "CAHVORE"))},
        **{key.format(c, own[c], "apriltag"): of[c] for c in of}}
    # every job is there once, as itself or as a twin
    members = [m.key for j in grouped for m in j.members()]
    assert sorted(members) == sorted(j.key for j in jobs)
    # the pancams' CAHVORE jobs are not-applicable (no CAHVORE of a CAHVOR): not folded
    assert "14/CAHVORE/dots/raycast[spp=16,adaptive,coverage=area]" in {j.key for j in grouped}


@pytest.mark.parametrize("a, b", [(8, 5), (8, 6), (8, 7), (12, 9), (12, 10), (12, 11),
                                  (13, 14), (17, 18)])
def test_twins_have_the_same_camera_frame_model_bit_for_bit(a, b):
    # what the verdict computes from it (harness.verdict.exact_fit) is then computed once
    for family in ("CAHV", "CAHVOR", "CAHVORE"):
        if family == "CAHVORE" and a == 13:    # the pancams are CAHVOR
            continue
        ma, mb = camera_frame_model(_model(a, family)), camera_frame_model(_model(b, family))
        assert _model_key(ma) == _model_key(mb)


def test_the_camera_frame_model_images_the_camera_frame_as_the_model_does():
    from targets.centroids import board_to_ref
    for slot in (7, 15, 17, 21):
        m = _model(slot)
        c = camera_frame_model(m)
        assert np.array_equal(c.C, np.zeros(3)) and type(c) is type(m)
        # its camera frame is its world frame: the identity, to rounding
        assert np.allclose(c.Rt_ref_cam(), np.vstack((np.eye(3), np.zeros(3))), atol=1e-15)
        p_cam = np.array([[0.3, -0.2, 2.0], [-1.0, 0.5, 4.0], [0.0, 0.0, 0.4]])
        I = np.vstack((np.eye(3), np.zeros(3)))
        q = m.project(board_to_ref(m, I, p_cam))
        # the same pixels to the rounding of one rotation (1e-16 relative) over ~1e3 px
        assert np.max(np.abs(c.project(p_cam) - q)) < 1e-9
    # a same_camera twin by an arbitrary rotation: the same camera, not the same bits
    m = _model(15)
    th = 0.3
    R = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1.0]])
    turned = m.replace(C=m.C @ R.T, A=m.A @ R.T, H=m.H @ R.T, V=m.V @ R.T, O=m.O @ R.T)
    assert same_camera(m, turned)
    assert _model_key(camera_frame_model(m)) != _model_key(camera_frame_model(turned))
    # any other model: itself
    from harness.calibrators.opencv_fit import OpenCVModel
    cv = OpenCVModel("OPENCV5", np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]]),
                     np.zeros(5), 640, 480)
    assert camera_frame_model(cv) is cv


def test_only_exact_renderers_and_clean_jobs_share():
    c = parse_campaign({"cameras": [17, 18], "models": ["CAHV"],
                        "renderer": [{"name": "raycast"}, {"name": "povray"}],
                        "response": {"clean": {}, "noisy": {"read_noise": {"sigma_e": 5.0}}}},
                       source="c.toml")
    grouped = group_twins(expand_jobs(c))
    shared = [j.key for j in grouped if j.twins]
    assert shared == ["17/CAHV/dots/raycast[spp=16,adaptive,coverage=area]"]
    assert len(grouped) == len(expand_jobs(c)) - 1
    # the legacy renderer's defects may depend on where the camera is: it renders every one
    assert camera_frame_exact("raycast") and not camera_frame_exact("faulty")
    # finished jobs are left as they are
    assert not any(j.twins for j in group_twins(expand_jobs(c), skip={shared[0]}))


def test_calibrators_say_whether_they_read_the_world_frame():
    assert uses_world_frame("jpl", {})
    assert not uses_world_frame("mrcal", {})
    assert uses_world_frame("mrcal", {"known_poses": True})
    assert not uses_world_frame("opencv", {})
    assert not uses_world_frame("colmap", {})


def test_campaign_key_share_identical_cameras():
    c = parse_campaign({"cameras": [17], "share_identical_cameras": False}, source="c.toml")
    assert c.share_identical_cameras is False
    assert c.as_dict()["share_identical_cameras"] is False
    assert parse_campaign({"cameras": [17]}, source="c.toml").share_identical_cameras is True
    with pytest.raises(CampaignError, match="share_identical_cameras"):
        parse_campaign({"cameras": [17], "share_identical_cameras": "yes"}, source="c.toml")


def _without_sharing_info(r):
    r = without_timings(r)
    r["info"] = {k: v for k, v in r["info"].items() if k != "shared"}
    return json.dumps(r, sort_keys=True)


@pytest.mark.slow
def test_shared_records_equal_unshared_records(tmp_path):
    spec = {"cameras": [17, 18], "models": ["CAHVOR"],
            "renderer": [{"name": "raycast", "spp": 4}],
            "calibrator": [{"name": "jpl"}, {"name": "mrcal"},
                           {"name": "opencv", "models": ["OPENCV5"]}]}
    docs = {}
    for share in (True, False):
        c = parse_campaign(dict(spec, share_identical_cameras=share), source="c.toml")
        docs[share] = run_campaign(c, tmp_path / str(share), workers=1, progress=False)
    shared, alone = docs[True]["records"], docs[False]["records"]
    assert sorted(shared) == sorted(alone) and len(shared) == 6
    for k in shared:
        assert _without_sharing_info(shared[k]) == _without_sharing_info(alone[k]), k
    assert docs[True]["execution"]["twins"] == {
        "17/CAHVOR/dots/raycast[spp=4,adaptive,coverage=area]": ["18"]}
    assert docs[True]["execution"]["jobs_run"] == 2
    facts = dict(run_facts(docs[True]))
    assert facts["cameras rendered once for others (identical in their camera frames)"] == \
        "17 for 18"
    assert not any(k.startswith("cameras rendered once") for k, _ in run_facts(docs[False]))
    key = "18/CAHVOR/dots/raycast[spp=4,adaptive,coverage=area]"
    jpl, mrcal = shared[key + "/jpl[CAHVOR]"], shared[key + "/mrcal[CAHVOR]"]
    assert jpl["info"]["shared"] == {"with": "17", "stages": ["poses", "render", "detect"]}
    # mrcal does not read the world frame: its fit, comparison and verdict (computed in the
    # camera frame, the same bits for both cameras) are the first camera's
    assert mrcal["info"]["shared"] == {"with": "17",
                                       "stages": ["poses", "render", "detect", "calibrate",
                                                  "compare", "verdict"]}
    jpl17 = "17/CAHVOR/dots/raycast[spp=4,adaptive,coverage=area]/jpl[CAHVOR]"
    assert shared[jpl17]["info"]["shared"] == {"twins": ["18"]}
    # the twin's own work is timed, the shared work is not counted twice
    assert jpl["seconds"]["render"] == 0.0 and jpl["seconds"]["detect"] == 0.0
    assert jpl["seconds"]["calibrate"] > 0.0 and mrcal["seconds"]["calibrate"] == 0.0
    assert jpl["seconds"]["exact_fit"] > 0.0
    assert all(mrcal["seconds"][k] == 0.0 for k in ("compare", "exact_fit", "verdict"))
    assert jpl["seconds"]["render_per_image"] == \
        shared["17/CAHVOR/dots/raycast[spp=4,adaptive,coverage=area]/jpl[CAHVOR]"]["seconds"]["render_per_image"]
    # the images are counted once: the twin rendered none
    stages, images = stage_seconds(shared)
    assert images == 6 and stage_seconds(alone)[1] == 12
    assert stages["calibrate:mrcal"] == pytest.approx(
        shared["17/CAHVOR/dots/raycast[spp=4,adaptive,coverage=area]/mrcal[CAHVOR]"]["seconds"]["calibrate"])
    # each camera has its own job file, so a lost twin is redone alone on resume
    store = RunStore.open(tmp_path / "True")
    assert {"17/CAHVOR/dots/raycast[spp=4,adaptive,coverage=area]", key} <= store.done_jobs()
    (store.records_dir / job_filename(key)).unlink()
    c = parse_campaign(dict(spec, share_identical_cameras=True), source="c.toml")
    again = run_campaign(c, tmp_path / "True", resume=True, workers=1, progress=False)
    assert again["execution"]["jobs_run"] == 1 and again["execution"]["twins"] == {}
    for k in shared:
        assert _without_sharing_info(again["records"][k]) == _without_sharing_info(alone[k]), k


@pytest.mark.slow
def test_shared_corner_records_equal_unshared_records(tmp_path, monkeypatch):
    r'''A corner target under other render settings than the reference render: the
verdict renders the reference corners (harness.verdict.reference_corners) once, for
both cameras, through the camera-frame model, and the records are those of an
unshared run'''
    spec = {"cameras": [17, 18], "models": ["CAHVORE"], "targets": ["apriltag"],
            "renderer": [{"name": "raycast", "spp": 4}],
            "calibrator": [{"name": "jpl"}, {"name": "opencv", "models": ["OPENCV5"]}]}
    from harness import verdict
    renders = []
    reference_corners = verdict.reference_corners

    def counted(truth, target, Rts):
        renders.append(len(Rts))
        return reference_corners(truth, target, Rts)
    monkeypatch.setattr(verdict, "reference_corners", counted)   # workers=1: in this process
    docs = {}
    for share in (True, False):
        verdict._EXACT_OBS.clear()
        c = parse_campaign(dict(spec, share_identical_cameras=share), source="c.toml")
        docs[share] = run_campaign(c, tmp_path / str(share), workers=1, progress=False)
    # rendered once for both cameras in each run: in the unshared one camera 18's job finds
    # camera 17's in the process's memo (the same bits: same poses, detections and
    # camera-frame model)
    assert renders == [6, 6]
    shared, alone = docs[True]["records"], docs[False]["records"]
    assert sorted(shared) == sorted(alone) and len(shared) == 4
    for k in shared:
        assert shared[k]["status"] == "ok", (k, shared[k]["reason"])
        assert _without_sharing_info(shared[k]) == _without_sharing_info(alone[k]), k
    key = "{}/CAHVORE/apriltag/raycast[spp=4,adaptive,coverage=area]/{}"
    assert shared[key.format(18, "opencv[OPENCV5]")]["info"]["shared"]["stages"][-2:] == \
        ["compare", "verdict"]


def test_a_job_function_that_forgets_a_twin_leaves_it_to_resume(tmp_path):
    from harness.executors import run_jobs
    from harness.records import RunStore
    from harness.runner import run_job
    c = parse_campaign({"cameras": [17, 18], "models": ["CAHV"],
                        "renderer": [{"name": "raycast", "spp": 1}],
                        "calibrator": [{"name": "jpl"}]}, source="c.toml")
    (job,) = group_twins(expand_jobs(c))
    assert [k for _, k in job.twins] == ["18"]

    def leader_only(j):
        out = run_job(j)
        return dict(out, records=[r for r in out["records"] if r["camera"] == "17"])

    store = RunStore.create(tmp_path / "run", c.as_dict())
    run_jobs([job], store, fn=leader_only, workers=1, progress=False)
    recs = store.records()
    twin = recs["18/CAHV/dots/raycast[spp=1,adaptive,coverage=area]/jpl[CAHV]"]
    assert (twin["status"], twin["stage"]) == ("failed", "internal")
    assert "no records for camera 18" in twin["reason"]
    assert store.done_jobs() == {"17/CAHV/dots/raycast[spp=1,adaptive,coverage=area]"}
