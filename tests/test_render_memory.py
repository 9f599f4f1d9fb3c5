r'''renderers.memory: the memory a render needs, and images too large for the machine refused
before anything of their size is allocated (camval render, campaigns)'''

import resource

import numpy as np
import pytest

from camval.cli import main
from harness.campaign import parse_campaign
from harness.jobs import expand_jobs
from harness.runner import run_job
from reference_models.cahvore import CAHV, CAHVORE
from renderers.base import RendererError, RenderSettings, get_renderer
from renderers.memory import (
    RenderTooLargeError,
    check_render_memory,
    memory_limit,
    render_memory,
)
from renderers.raycast import RaycastRenderer

# a CAHVOR of 100000 x 100000 pixels: 40 GB of float32 image (its rays, 240 GB cached, are
# traced per tile)
HUGE = """\
Model = CAHVOR = perspective, distortion
Dimensions = 100000 100000
C = 0.1 0.2 0.3
A = 0 0 1
H = 120000 0 49999.5
V = 0 120000 49999.5
O = 0 0.00999950003749688 0.99995000374968752
R = 0.001 -0.01 0.02
"""


def _cahv(W, H, f=500.0):
    return CAHV(C=np.zeros(3), A=np.array([0.0, 0, 1]), H=np.array([f, 0, (W - 1) / 2]),
                V=np.array([0.0, f, (H - 1) / 2]), width=W, height=H)


def _cahvore(W, H, E):
    return CAHVORE(C=np.zeros(3), A=np.array([0.0, 0, 1]), H=np.array([300.0, 0, (W - 1) / 2]),
                   V=np.array([0.0, 300, (H - 1) / 2]), O=np.array([0.0, 0, 1]),
                   R=np.array([0.0, -0.01, 0.0]), E=np.array(E, dtype=float),
                   model_type=1, linearity=1.0, width=W, height=H)


def test_raycast_needs_its_image():
    # the float32 image; no ray cache (renderers/raycast.py traces the rays it reads)
    W, H = 640, 480
    need = render_memory("raycast", _cahv(W, H), RenderSettings(spp=16))
    assert need.parts == {"image": 4 * W * H}
    # a noncentral CAHVORE the same; K costs nothing
    nc = render_memory("raycast", _cahvore(W, H, [0.001, 0.002, 0.0]), RenderSettings(spp=1))
    assert nc.parts == {"image": 4 * W * H}


def test_supersampling_and_warp_settings_count_where_they_allocate():
    m = _cahv(100, 50)
    npx = 5000
    t1 = render_memory("raycast_terrain", m, RenderSettings(spp=1)).total
    t4 = render_memory("raycast_terrain", m, RenderSettings(spp=4)).total
    # (48 bytes of rays + 17 of shading) per subsample, 13 per pixel
    assert t4 - t1 == 65 * 15 * npx
    base = render_memory("osmesa", m, RenderSettings(spp=4))
    finer = render_memory("osmesa", m, RenderSettings(spp=4, options={"warp_scale": 2.0}))
    assert finer.parts["pinhole image"] == 4 * base.parts["pinhole image"] == 4 * 8 * npx
    # POV-Ray renders K = 16 as 8 x 8 anti-aliasing on a pinhole 2 times finer
    pov = render_memory("povray", m, RenderSettings(spp=16))
    assert pov.parts["pinhole image"] == 4 * 8 * npx
    assert render_memory("povray", m, RenderSettings(options={"camera": "mesh"})).total == 9 * npx
    assert render_memory("command", m).parts == {"image": 4 * npx}


def test_a_renderer_may_declare_its_own_needs():
    class Big:
        name = "big"

        def render_bytes(self, model, settings):
            return {"scratch": 10 ** 15}

    with pytest.raises(RenderTooLargeError, match=r"with big \(scratch 1e\+06 GB\)"):
        check_render_memory(Big(), _cahv(10, 10))


def test_the_limit_is_the_machine_and_the_check_says_both_figures():
    limit, source = memory_limit()
    assert source in ("MemTotal", "cgroup memory limit", "RLIMIT_AS")
    assert 0 < limit <= 1 << 50
    m = _cahv(1000, 1000)
    need = check_render_memory("raycast", m, limit=5_000_000)
    assert need.total == 4_000_000
    with pytest.raises(RenderTooLargeError) as e:
        check_render_memory("raycast", m, limit=need.total - 1)
    msg = str(e.value)
    assert isinstance(e.value, RendererError) and "\n" not in msg
    assert msg.startswith("a 1000x1000 image needs at least 0.004 GB to render with raycast")
    assert msg.endswith("this machine has 0.004 GB (the limit given)")


def test_camval_render_refuses_a_huge_model_in_one_line(tmp_path, capsys):
    f = tmp_path / "huge.cahvor"
    f.write_text(HUGE)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    rc = main(["render", str(f), "-o", str(tmp_path / "x.png")])
    err = capsys.readouterr().err
    assert rc == 2
    assert err.count("\n") == 1 and "Traceback" not in err
    # the image alone (no ray cache)
    assert err.startswith("camval render: error: a 100000x100000 image needs at least 40 GB "
                          "to render with raycast (image 40 GB)")
    assert not (tmp_path / "x.png").exists() and not (tmp_path / "x.json").exists()
    # refused before anything of the image's size was allocated: the peak grew < 1 GB
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 1 << 20   # kB


def test_a_campaign_job_on_a_huge_model_is_a_failed_render_record(tmp_path):
    f = tmp_path / "huge.cahvor"
    f.write_text(HUGE)
    (job,) = expand_jobs(parse_campaign({
        "name": "huge", "cameras": [str(f)], "models": ["CAHV"],
        "renderer": [{"name": "raycast", "spp": 4}], "calibrator": [{"name": "jpl"}]}))
    (rec,) = run_job(job)["records"]
    assert (rec["status"], rec["stage"]) == ("failed", "render")
    # its image alone
    assert rec["reason"].startswith("a 100000x100000 image needs at least 40 GB to render "
                                    "with raycast")


def test_an_ordinary_camera_passes_the_check():
    r = get_renderer("raycast")
    need = check_render_memory(r, _cahv(5120, 3840), RenderSettings(spp=16))
    # camera 1's size: 79 MB of image, far below any machine of this kind
    assert need.total == 4 * 5120 * 3840
    assert check_render_memory(RaycastRenderer(), _cahv(5120, 3840),
                               RenderSettings(spp=16)).total == 4 * 5120 * 3840
