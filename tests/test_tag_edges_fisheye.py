r'''targets.tag_edges on a fisheye built here (not a catalogue slot): blurred AprilTag
corners from the exact ray caster against the exact corner projections on all six planned
poses (the span/degree chosen per corner, tag_edges._span_choice), and NEIGHBOUR_REACH
(chosen on catalogue camera 8, the MER hazcam) checked on another camera'''

import numpy as np
import pytest

import targets.tag_edges as tag_edges
from reference_models.cahvore import CAHVORE
from renderers.base import RenderSettings, get_renderer
from renderers.response import ResponseChain
from targets.boards import load_target
from targets.centroids import projected_points
from targets.detect import detect
from targets.poses import plan_poses

# the `realistic` profile of campaigns/response.toml without its noise: its blur only
BLUR = {"psf": {"kind": "gaussian", "sigma_px": 0.7}}
TARGET = load_target("apriltag")


def _fisheye():
    r'''An 800x640 CAHVORE fisheye of 155 x 129 deg (type 3, linearity 0.6, f 250 px,
centre 4.5 / -3 px off the image's, O tilted 0.4 deg, R and E of the hazcams' size and
other signs). Camera 8 is 1024x1024, f ~350 px, linearity 0.37, 124 deg across: this one
is wider at fewer pixels, so the board lines bend more per pixel'''
    W, H, f = 800, 640, 250.0
    A = np.array([0.0, 0.0, 1.0])
    O = np.array([0.006, 0.004, 1.0])
    return CAHVORE(C=[0, 0, 0], A=A, H=[f, 0, 0] + ((W - 1) / 2 + 4.5) * A,
                   V=[0, f, 0] + ((H - 1) / 2 - 3.0) * A, O=O / np.linalg.norm(O),
                   R=[0.0, -0.02, -0.003], E=[0.0005, 0.003, -0.001],
                   model_type=3, linearity=0.6, width=W, height=H)


@pytest.fixture(scope="module")
def scene():
    r'''(camera, poses, {pose index: (blurred noise-free image, exact corners)}) for the six
planned poses: the near pose 0 (tags of 40-94 px edges), the four corner poses 1-4 (tilted
boards in the fisheye's corners, tags of 20-80 px) and the middle tilted pose 5'''
    m = _fisheye()
    poses = plan_poses(m, TARGET, n=6, seed=0)
    r = get_renderer("raycast")
    chain = ResponseChain.from_config(BLUR)
    out = {}
    for i in range(6):
        img = r.render(m, TARGET.pattern(), poses[i], RenderSettings(spp=16)).image
        out[i] = (chain.apply(img).image, projected_points(m, TARGET, poses[i]))
    return m, poses, out


def _errors(image, truth):
    det = detect(image, TARGET)
    e = np.linalg.norm(det.q - truth, axis=-1)
    kept = np.isfinite(e)
    assert np.all(det.corner_model[kept] == "tag edges")
    return e[kept], det


def _rms(e):
    return float(np.sqrt(np.mean(e ** 2)))


@pytest.mark.slow
def test_blurred_fisheye_corners_from_the_edges(scene):
    r'''Noise-free blur (the realistic profile's PSF, sigma 0.7 px), blur kind and sigma
estimated by the detector as in a campaign, every planned pose. The render is exact to
~1e-4 px of edge (area coverage); what is left is the edge model's: each edge's span and
degree per corner chosen by bias^2 + variance (tag_edges._span_choice; noise-free, the
variance is the tabulation's, so the least bias wins). Bar: issue 16's 0.005 px RMS (what
the corners must reach for the recalibration) on every pose, max 0.03 px (~6x the RMS: a
board line's end, or a weak edge placed by its neighbours). Measured (h-cubic): poses 0-5
0.0016, 0.0010, 0.0017, 0.0034, 0.0008, 0.0011 px RMS, max 0.0069, 0.0065, 0.0123, 0.0199,
0.0049, 0.0110; 144, 127, 124, 122, 144, 128 of 144 corners kept (the rest's bits too small
for the blur). Before, with a length rule chosen on camera 8 (the three edges' cubic up to
64 px): 0.0038, 0.0015, 0.0045, 0.0091, 0.0029, 0.0021, max up to 0.040 (pose 3's big tags
near the image corner, edges of 51-66 px). Pose 3's maximum, 0.020 px, is a tag whose
edges are seen from their light side only, placed by their board lines (the same under
any span choice: 0.0032 px RMS on that pose for the best choice per corner in hindsight).
Since session 19 a bit's depth across an edge is measured across it (the sheared tags of
the fisheye's rim have bits shallower than long) and a corner needs its edges' dark side
in the half next to it (tag_edges._sees_dark_near): poses 0-5 0.0014, 0.0014, 0.0019,
0.0027, 0.0009, 0.0005 px RMS, max 0.0051, 0.0053, 0.0123, 0.0149, 0.0045, 0.0021, on
144, 121, 116, 108, 137, 121 of 144 corners: more edges of the small tilted tags are seen
from their light side only (dropped with that reason), so the count's bar is 70% (it was
80% with the deeper bits: 122 on pose 3)'''
    _, _, images = scene
    for i, (im, truth) in images.items():
        e, det = _errors(im, truth)
        assert abs(det.info["psf_sigma_px"] - 0.7) < 0.01, det.info["psf_sigma_px"]
        # the near pose's tags are all big enough for the blur; the others drop the small
        # far ones with a reason
        assert e.size >= (TARGET.Npoints if i == 0 else 0.7 * TARGET.Npoints), (i, e.size)
        assert _rms(e) < 0.005 and e.max() < 0.03, (i, _rms(e), e.max())


@pytest.mark.slow
def test_half_the_neighbour_beats_the_whole_on_big_bent_tags(scene, monkeypatch):
    r'''NEIGHBOUR_REACH = 0.5 was chosen on camera 8's near pose; here, on the near pose
of a camera built for it (tags of 40-94 px, board lines bent across 155 deg), reaching
over half the neighbour does at least as well as over all of it, on every corner and on
the inner 4 x 4 tags' (each of whose edges has a neighbour at both ends; a corner at a
board line's end has none beyond it and is fitted the same at either reach: the maximum,
0.0145 px, is one). Measured (h-fish): all 144 corners 0.0038 px RMS at reach 0.5 against
0.0043 at 1.0 (0.25: 0.0039, 0.7: 0.0040), inner tags 0.0022 against 0.0030; on corner
pose 2 (not asserted) 0.0045 against 0.0081, max 0.021 against 0.048'''
    _, _, images = scene
    im, truth = images[0]
    inner = np.zeros((6, 6, 4), bool)
    inner[1:5, 1:5] = True
    inner = inner.reshape(-1)
    got = {}
    for reach in (0.5, 1.0):
        monkeypatch.setattr(tag_edges, "NEIGHBOUR_REACH", reach)
        det = detect(im, TARGET)
        e = np.linalg.norm(det.q - truth, axis=-1)
        assert np.all(np.isfinite(e))
        got[reach] = (_rms(e), _rms(e[inner]))
    assert got[0.5][0] <= got[1.0][0] and got[0.5][1] <= got[1.0][1], got
