'''harness.model_benchmark: floors of the candidate lens models, the choice per calibrator'''

import pytest

from camval.cli import main
from harness.model_benchmark import CANDIDATES, benchmark, best_model, choose
from reference_models.catalogue import load_catalogue

CAT = load_catalogue()
NAVCAM = CAT.get(15).model                   # MER B navcam, CAHVOR, theta != 90
# exactness: the fits are least squares on exact data; 1e-6 px is far above their rounding
# (1e-12 px) and far below any floor a misfit model leaves (> 1e-3 px for these cameras)
EXACT = 1e-6


@pytest.fixture(autouse=True)
def _own_cache(monkeypatch, tmp_path):
    r'''best_model keeps its choices on disk: here in the test's directory, not ~/.cache'''
    import harness.model_benchmark as mb
    monkeypatch.setenv(mb.CACHE_ENV, str(tmp_path / "cache"))
    monkeypatch.setattr(mb, "_MEMO", {})


def _rows(b):
    return {r["name"]: r for r in b["rows"]}


def test_a_pinhole_camera_is_exact_in_every_pinhole_based_model():
    # constructed: the navcam's CAHV, theta made 90 deg: every model holds it exactly
    pinhole = NAVCAM.to_cahv().with_theta_90()
    names = ["CAHV", "LENSMODEL_PINHOLE", "LENSMODEL_OPENCV5", "cv2 5 (OPENCV5)",
             "cv2 fisheye (FISHEYE, COLMAP OPENCV_FISHEYE)"]
    b = benchmark(pinhole, candidates=names)
    rows = _rows(b)
    for n in names[:4]:
        assert rows[n]["status"] == "ok" and rows[n]["n_invalid"] == 0
        assert rows[n]["max"] < EXACT, (n, rows[n]["max"])
    # the fisheye's polynomial in the angle only approximates tan (1.2e-4 px at 32 deg)
    assert rows[names[4]]["max"] > 100 * EXACT
    assert b["recommended"]["name"] == "LENSMODEL_PINHOLE"
    assert b["recommended"]["nparams"] == 4
    # the fisheye (8 parameters) is within 0.01 px and simpler than OPENCV5 (9)
    assert b["per_calibrator"]["opencv"]["model"] == "FISHEYE"
    assert b["per_calibrator"]["jpl"]["model"] == "CAHV"


def test_navcam_needs_cahvor_and_cahv_is_not_enough():
    b = benchmark(NAVCAM, candidates=["CAHV", "CAHVOR", "LENSMODEL_CAHVOR", "cv2 5 (OPENCV5)"])
    rows = _rows(b)
    assert rows["CAHVOR"]["max"] < EXACT
    # a pinhole misses the navcam's radial distortion by ~0.5 px at the corners
    assert rows["CAHV"]["max"] > 0.1 and rows["CAHV"]["corner"] is not None
    assert b["recommended"]["name"] == "CAHVOR"
    c = b["per_calibrator"]["jpl"]
    assert c["model"] == "CAHVOR" and "CAHV" in c["why"]
    # mrcal's CAHVOR holds theta != 90 deg only far along its R0 / focal-length valley: the
    # direct fit crawls there and stops short (0.23 px) ...
    assert rows["LENSMODEL_CAHVOR"]["max"] > 0.01
    # ... mrcal's own solver gets there, and the choice is made on its own fit
    c = b["per_calibrator"]["mrcal"]
    assert c["model"] == "CAHVOR" and c["floor"] < EXACT, c
    assert "its own fit" in c["why"]


def test_theta_90_cahvor_is_exact_in_mrcal_and_best_model_picks_it():
    truth = NAVCAM.with_theta_90()
    model, why = best_model(truth, "mrcal")
    assert model == "CAHVOR", why
    assert "simplest mrcal model" in why and "CAHV" in why


def test_a_wide_lens_beyond_90_deg_is_outside_the_pinhole_models_domain():
    hazcam = CAT.get(9).model      # corners 94 deg off the axis
    # the direct fits only: the choice from rows that cannot see the whole field
    b = benchmark(hazcam, candidates=["cv2 5 (OPENCV5)", "CAHVORE"], own_fits=())
    rows = _rows(b)
    assert rows["cv2 5 (OPENCV5)"]["n_invalid"] > 0
    assert rows["CAHVORE"]["max"] < EXACT and rows["CAHVORE"]["n_invalid"] == 0
    c = choose(b, "opencv")
    assert c["model"] == "OPENCV5" and "90 deg" in c["why"]


def test_a_failing_fit_is_a_row_with_its_reason(monkeypatch):
    import harness.model_benchmark as mb

    def boom(*a, **k):
        raise RuntimeError("no convergence")
    monkeypatch.setattr(mb, "_fit_fisheye", boom)
    b = benchmark(NAVCAM, candidates=["cv2 fisheye (FISHEYE, COLMAP OPENCV_FISHEYE)"])
    r = b["rows"][0]
    assert r["status"] == "failed" and "no convergence" in r["reason"]
    assert b["recommended"] is None


def test_models_command_prints_the_table(capsys):
    assert main(["models", "15", "--only", "CAHV", "--only", "CAHVOR"]) == 0
    out = capsys.readouterr().out
    assert "recommended: CAHVOR (9 parameters" in out
    assert out.count("jpl (scipy)") == 2


def test_every_candidate_names_its_calibrator_models_once():
    seen = {}
    for c in CANDIDATES:
        for cal, m in c.calibrators.items():
            assert (cal, m) not in seen, (cal, m)
            seen[(cal, m)] = c.name
    from harness.calibrators import models_of
    for cal in ("jpl", "mrcal", "opencv", "colmap"):
        assert {m for (k, m) in seen if k == cal} == set(models_of(cal))


@pytest.mark.slow
@pytest.mark.parametrize("key", [e.key for e in CAT])
def test_every_catalogue_camera_has_a_model_within_tolerance(key):
    b = benchmark(CAT.get(key).model, candidates=["CAHV", "CAHVOR", "CAHVORE"])
    assert b["recommended"] is not None
    assert b["recommended"]["max"] <= 0.01


CAMPAIGN = '''
cameras = [15]
models = ["CAHV"]
[poses]
n = 4
[[renderer]]
name = "raycast"
spp = 1
[[calibrator]]
name = "jpl"
models = ["best"]
[[calibrator]]
name = "opencv"
models = ["best", "OPENCV5"]
options = {best_tolerance = 0.5}
'''


def test_campaign_best_picks_per_camera_and_records_why(tmp_path):
    from harness.campaign import MODEL_CHOICE, load_campaign
    from harness.jobs import expand_jobs
    p = tmp_path / "c.toml"
    p.write_text(CAMPAIGN)
    (job,) = expand_jobs(load_campaign(p))
    cals = {(c, m): o for c, m, o in job.calibrators}
    # the navcam's CAHV truncation is a CAHV: jpl's CAHV holds it exactly
    assert "simplest jpl model" in cals[("jpl", "CAHV")][MODEL_CHOICE]
    # OpenCV has no skew: its floors on the navcam's CAHV (theta != 90 deg) are ~0.16 px,
    # within the campaign's 0.5 px; the fisheye (8 parameters) is the simplest. The
    # tolerance option is not passed on to the fit
    assert set(cals) == {("jpl", "CAHV"), ("opencv", "FISHEYE"), ("opencv", "OPENCV5")}
    why = cals[("opencv", "FISHEYE")][MODEL_CHOICE]
    assert "simplest opencv model" in why and "<= 0.5 px" in why
    assert cals[("opencv", "FISHEYE")] == {MODEL_CHOICE: why}
    assert cals[("opencv", "OPENCV5")] == {}


@pytest.mark.slow
def test_a_best_job_runs_and_its_records_say_why(tmp_path):
    from harness.campaign import load_campaign
    from harness.jobs import expand_jobs
    from harness.runner import run_job
    p = tmp_path / "c.toml"
    p.write_text(CAMPAIGN.replace('models = ["best", "OPENCV5"]', 'models = ["best"]'))
    (job,) = expand_jobs(load_campaign(p))
    recs = run_job(job)["records"]
    assert [r["status"] for r in recs] == ["ok", "ok"], [r.get("reason") for r in recs]
    assert [r["calibrator_model"] for r in recs] == ["CAHV", "FISHEYE"]
    assert all("simplest" in r["info"]["model_choice"] for r in recs)
    assert recs[1]["info"]["diagnostics"]["n"] >= 0


def test_best_models_are_chosen_before_the_jobs_with_progress(tmp_path, monkeypatch):
    import io

    import harness.model_benchmark as mb
    from harness.campaign import load_campaign, resolve_best
    from harness.progress import Progress
    calls = []

    def fake(truth, calibrator, tolerance=0.01, criterion="max"):
        calls.append((truth.family, calibrator, tolerance))
        return "CAHV" if calibrator == "jpl" else "FISHEYE", "because"
    monkeypatch.setattr(mb, "best_model", fake)
    p = tmp_path / "c.toml"
    p.write_text(CAMPAIGN)
    c = load_campaign(p)
    out = io.StringIO()
    got = resolve_best(c, c.validate(), Progress(stream=out))
    assert [(g[0], g[1], g[2], g[3]) for g in got] == [("15", "CAHV", "jpl", "CAHV"),
                                                       ("15", "CAHV", "opencv", "FISHEYE")]
    assert calls == [("CAHV", "jpl", 0.01), ("CAHV", "opencv", 0.5)]
    text = out.getvalue()
    assert "best models (2) ..." in text
    assert "[2/2] camera 15 CAHV opencv: FISHEYE" in text
