r'''harness.stages.render_detect_stage: image by image, the values of render_stage,
response_stage and detect_stage run one after the other, and the same failure'''

import dataclasses

import numpy as np
import pytest

from harness.campaign import parse_campaign
from harness.jobs import expand_jobs
from harness.stages import (
    StageFailed,
    cached_target,
    camera_stage,
    detect_stage,
    poses_stage,
    render_detect_stage,
    render_stage,
    response_stage,
)

REALISTIC = {"full_well_e": 20000, "psf": {"kind": "gaussian", "sigma_px": 0.7},
             "shot_noise": {}, "read_noise": {"sigma_e": 12.0}, "quantise": {"bits": 12}}


@pytest.fixture(scope="module")
def job():
    (j,) = expand_jobs(parse_campaign({
        "name": "t", "cameras": [17], "models": ["CAHVOR"],
        "renderer": [{"name": "raycast", "spp": 2}], "calibrator": [{"name": "jpl"}]}))
    j = dataclasses.replace(j, response=REALISTIC, response_name="realistic", poses_n=3)
    _, truth = camera_stage(j)
    target = cached_target(j.target)
    return j, truth, target, poses_stage(truth, target, j.poses_n, j.poses_seed)


def test_same_values_as_the_stages_in_a_row(job):
    j, truth, target, poses = job
    renders, _, version = render_stage(j.renderer, truth, target, poses, j.settings)
    images, rsecs = response_stage(j, truth, [r.image for r in renders])
    dets, _ = detect_stage(images, target)
    out = render_detect_stage(j, truth, target, poses, keep_images=True)
    assert out.failure is None and out.version == version
    assert [m["samples"] for m in out.metadata] == [r.metadata["samples"] for r in renders]
    assert set(out.response_seconds) == set(rsecs)
    # the noise of image i comes from noise_seed(job, i): the same images bit for bit
    for a, b in zip(out.images, images, strict=True):
        assert np.array_equal(a, b)
    for a, b in zip(out.detections, dets, strict=True):
        assert a.n_found == b.n_found > 0
        assert np.array_equal(np.asarray(a.q), np.asarray(b.q), equal_nan=True)
    assert render_detect_stage(j, truth, target, poses).images is None


def test_failures_come_in_the_order_of_the_stages(job):
    j, truth, target, poses = job
    bad = dataclasses.replace(j, response={"quantise": {"bits": 9}})
    out = render_detect_stage(bad, truth, target, poses)
    assert out.failure.stage == "response"
    assert out.failure.reason == "quantise.bits = 9; known: 8, 10, 12, 14, 16"
    assert len(out.metadata) == len(poses) and out.detections == []
    # a render failure of any pose wins over a response failure
    broken = list(poses[:-1]) + [np.zeros((3, 3))]
    with pytest.raises(StageFailed) as e:
        render_detect_stage(bad, truth, target, broken)
    assert e.value.stage == "render"


def test_images_dropped_by_the_caller_are_rendered_into_one_buffer(job):
    r'''iter_renders holds no image while the next pose renders: a caller that drops each
image gets the next one in the same memory (renderers.memory.ImagePool), so a job of
5120x3840 images faults in one 79 MB buffer, not two'''
    from harness.stages import iter_renders
    j, truth, target, poses = job
    addresses = []
    for result, _ in iter_renders(j.renderer, truth, target, poses, j.settings):
        addresses.append(result.image.__array_interface__["data"][0])
        del result
    assert len(poses) == 3 and len(set(addresses)) == 1
