import subprocess
import sys
from pathlib import Path

import pytest

from harness.campaign import Campaign, CampaignError, load_campaign, parse_campaign
from harness.jobs import expand_jobs

ROOT = Path(__file__).resolve().parent.parent


def _write(tmp_path, text, name="c.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_shipped_campaigns_load_and_validate():
    quick = load_campaign(ROOT / "campaigns" / "quick.toml")
    entries = quick.validate()
    assert set(entries) == {"15", "17", "8"}
    assert quick.models == ("CAHV", "CAHVOR", "CAHVORE")
    assert [c.name for c in quick.calibrators] == ["jpl", "mrcal", "opencv"]
    paper = load_campaign(ROOT / "campaigns" / "paper.toml")
    assert paper.cameras == tuple(str(i) for i in range(1, 23))
    assert (paper.poses_n, paper.poses_seed) == (6, 0)
    jobs = expand_jobs(paper)
    # the dots under 3 families, the AprilTag grid under each camera's own ([target_models])
    assert len(jobs) == 22 * 3 + 22
    assert jobs[0].key == "1/CAHV/dots/raycast[spp=16,adaptive,coverage=area]"
    assert jobs[3].key == "1/CAHVORE/apriltag/raycast[spp=16,adaptive,coverage=area]"
    assert {(j.camera, j.family) for j in jobs if j.target == "apriltag"} == \
        {(c, e.model.family) for c, e in paper.validate().items()}
    # the quick and the paper campaigns have the AprilTag grid beside the dots, fitted by jpl
    # alone (mrcal's object is a regular grid; OpenCV's model, not the target, limits it)
    for c in (quick, paper):
        cals = {j.target: sorted({name for name, _, _ in j.calibrators})
                for j in expand_jobs(c)}
        assert cals == {"dots": ["jpl", "mrcal", "opencv"], "apriltag": ["jpl"]}, c.name
    assert jobs[0].fullname("jpl", "CAHV") == \
        "1/CAHV/dots/raycast[spp=16,adaptive,coverage=area]/jpl[CAHV]"
    assert len({j.key for j in jobs}) == len(jobs)


def test_target_models_choose_the_families_a_target_renders_under(tmp_path):
    c = load_campaign(_write(tmp_path, '''
cameras = [17, 15]
models = ["CAHV", "CAHVOR", "CAHVORE"]
targets = ["dots", "apriltag", "chessboard"]
[target_models]
apriltag = ["own"]
chessboard = ["CAHV", "own"]
'''))
    got = {(j.camera, j.family, j.target) for j in expand_jobs(c)}
    fam = {"17": "CAHVORE", "15": "CAHVOR"}
    assert got == ({(k, f, "dots") for k in fam for f in ("CAHV", "CAHVOR", "CAHVORE")}
                   | {(k, fam[k], "apriltag") for k in fam}
                   | {(k, f, "chessboard") for k in fam for f in ("CAHV", fam[k])})
    assert Campaign.from_dict(c.as_dict()) == c      # what a resumed run re-reads


@pytest.mark.parametrize("body, message", [
    ('targets = ["dots"]\n[target_models]\napriltag = ["own"]', "not among the campaign"),
    ('targets = ["dots"]\n[target_models]\ndots = ["CAHVX"]', "unknown model family"),
    ('targets = ["dots"]\n[target_models]\ndots = []', "non-empty list"),
    ('targets = ["dots"]\ntarget_models = 3', "expected a table"),
])
def test_bad_target_models(tmp_path, body, message):
    with pytest.raises(CampaignError, match=message):
        load_campaign(_write(tmp_path, "cameras = [15]\n" + body))


def test_settings_expand_to_jobs_and_family_models(tmp_path):
    c = load_campaign(_write(tmp_path, '''
cameras = [17]
models = ["CAHVOR"]
[[renderer]]
name = "raycast"
spp = [1, 4]
adaptive = [true, false]
[[calibrator]]
name = "jpl"
models = ["family", "CAHV"]
'''))
    jobs = expand_jobs(c)
    assert [j.key for j in jobs] == [
        "17/CAHVOR/dots/raycast[spp=1,adaptive,coverage=area]",
        "17/CAHVOR/dots/raycast[spp=1,full,coverage=area]",
        "17/CAHVOR/dots/raycast[spp=4,adaptive,coverage=area]",
        "17/CAHVOR/dots/raycast[spp=4,full,coverage=area]"]
    assert jobs[0].calibrators == (("jpl", "CAHVOR", {}), ("jpl", "CAHV", {}))
    assert Campaign.from_dict(c.as_dict()) == c


def test_model_file_camera_is_resolved_relative_to_the_campaign(tmp_path):
    from reference_models.catalogue import load_catalogue
    from reference_models.jpl_files import write_model
    model = load_catalogue().get(15).model
    (tmp_path / "models").mkdir()
    write_model(model, tmp_path / "models" / "nav.cahvor")
    c = load_campaign(_write(tmp_path, 'cameras = ["models/nav.cahvor"]\nmodels = ["CAHV"]\n'))
    assert c.cameras == (str(tmp_path / "models" / "nav.cahvor"),)
    jobs = expand_jobs(c)
    assert jobs[0].key == "file-nav.cahvor/CAHV/dots/raycast[spp=16,adaptive,coverage=area]"


@pytest.mark.parametrize("text, message", [
    ('cameras = [15]\ncolour = "red"\n', r"c\.toml: colour: unknown key; known keys: name, "),
    ('models = ["CAHV"]\n', r"cameras: missing"),
    ('cameras = [15]\nmodels = ["CAHVORX"]\n',
     r"models: unknown model family 'CAHVORX'; known: CAHV, CAHVOR, CAHVORE"),
    ('cameras = []\n', r"cameras: expected a non-empty list"),
    ('cameras = [15, 15]\n', r"cameras: repeated entries"),
    ('cameras = [15]\n[poses]\nn = 0\n', r"poses\.n: expected an integer >= 1; got 0"),
    ('cameras = [15]\n[poses]\ncount = 6\n', r"poses\.count: unknown key; known keys: n, seed"),
    ('cameras = [15]\n[[renderer]]\nname = "raycast"\nspp = [0]\n',
     r"renderer\[0\]\.spp: expected an integer >= 1; got 0"),
    ('cameras = [15]\n[[renderer]]\nname = "raycast"\nsamples = 4\n',
     r"renderer\[0\]\.samples: unknown key; known keys: name, spp, adaptive, options"),
    ('cameras = [15]\n[[calibrator]]\nmodels = ["CAHV"]\n', r"calibrator\[0\]\.name: missing"),
    ('cameras = [15]\n[[calibrator]]\nname = "jpl"\ntargets = ["apriltag"]\n',
     r"calibrator\[0\]\.targets: 'apriltag' is not among the campaign's targets \(dots\)"),
    ('cameras = [15]\ntargets = ["dots", "apriltag"]\n[[calibrator]]\nname = "jpl"\n'
     'targets = ["dots"]\n', r"calibrator: no calibrator fits the target 'apriltag'"),
    ('cameras = [15]\ntargets = ["checkers"]\n',
     r"targets: unknown target 'checkers'; known: apriltag, chessboard, dots or a target "
     r"\.toml file"),
    ('cameras = [15]\nkeep_images = "yes"\n', r"keep_images: expected true or false"),
    ('cameras = [15\n', r"not valid TOML"),
])
def test_structural_errors_name_the_key(tmp_path, text, message):
    with pytest.raises(CampaignError, match=message):
        load_campaign(_write(tmp_path, text))


@pytest.mark.parametrize("text, message", [
    ('cameras = [15, 99]\n', r"cameras\[1\]: no catalogue slot 99; valid: slot ids 1-22"),
    ('cameras = ["Hubble"]\n', r"cameras\[0\]: unknown camera 'Hubble'; valid: slot ids"),
    ('cameras = [15]\n[[renderer]]\nname = "blender"\n',
     r"renderer\[0\]\.name: unknown renderer 'blender'; known renderers: .*raycast"),
    ('cameras = [15]\n[[calibrator]]\nname = "bouguet"\n',
     r"calibrator\[0\]\.name: unknown calibrator 'bouguet'; known calibrators: colmap, jpl"),
    ('cameras = [15]\n[[calibrator]]\nname = "jpl"\nmodels = ["OPENCV8"]\n',
     r"calibrator 'jpl' has no model 'OPENCV8'; its models: family, CAHV, CAHVOR, CAHVORE"),
])
def test_name_errors_list_the_choices(tmp_path, text, message):
    c = load_campaign(_write(tmp_path, text))
    with pytest.raises(CampaignError, match=message):
        c.validate()


def test_missing_file_and_non_table():
    with pytest.raises(CampaignError, match="campaign file 'nope.toml' does not exist"):
        load_campaign("nope.toml")
    with pytest.raises(CampaignError, match="expected a TOML table"):
        parse_campaign([1, 2])


def test_cli_bad_campaign_is_one_line_exit_2(tmp_path):
    p = _write(tmp_path, 'cameras = [15]\n[[renderer]]\nname = "blender"\n')
    out = subprocess.run([sys.executable, "-m", "camval.cli", "verify", str(p), "--out",
                          str(tmp_path / "run")], capture_output=True, text=True, cwd=ROOT,
                         timeout=120)
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1, out.stderr
    assert "renderer[0].name: unknown renderer 'blender'" in lines[0]
    assert not (tmp_path / "run").exists()


# --- camera-response profiles ([response.NAME]) --------------------------------------
def test_response_campaign_expands_clean_and_realistic_jobs():
    c = load_campaign(ROOT / "campaigns" / "response.toml")
    assert [r.name for r in c.responses] == ["clean", "realistic"]
    assert c.response("clean").clean and not c.response("realistic").clean
    assert c.response("realistic").stages() == ["psf", "shot_noise", "read_noise", "quantise"]
    assert c.seed == 0
    jobs = expand_jobs(c)
    assert len(jobs) == 3 * 3 * 2
    assert [j.key for j in jobs[:2]] == ["15/CAHV/dots/raycast[spp=16,adaptive,coverage=area]",
                                         "15/CAHV/dots/raycast[spp=16,adaptive,coverage=area,response=realistic]"]
    # the clean jobs are the quick campaign's jobs, under the same fullnames
    quick = {j.key: j for j in expand_jobs(load_campaign(ROOT / "campaigns" / "quick.toml"))
             if j.target == "dots"}
    clean = [j for j in jobs if j.response_name == "clean"]
    assert {j.key for j in clean} == set(quick)
    assert all(j.settings == quick[j.key].settings and j.response == {} for j in clean)
    noisy = jobs[1]
    assert noisy.settings == {"spp": 16, "adaptive": True, "options": {},
                              "response": "realistic"}
    assert noisy.response == {"full_well_e": 20000, "psf": {"kind": "gaussian", "sigma_px": 0.7},
                              "shot_noise": {}, "read_noise": {"sigma_e": 12.0},
                              "quantise": {"bits": 12}}
    assert noisy.fullname("jpl", "CAHV") == \
        "15/CAHV/dots/raycast[spp=16,adaptive,coverage=area,response=realistic]/jpl[CAHV]"
    assert Campaign.from_dict(c.as_dict()) == c


def test_renderer_chooses_its_profiles_in_its_order(tmp_path):
    c = load_campaign(_write(tmp_path, '''
cameras = [17]
models = ["CAHV"]
seed = 5
[[renderer]]
name = "raycast"
spp = 4
response = ["blur", "clean"]
[[renderer]]
name = "raycast"
spp = 1
response = ["noise"]
[response.clean]
[response.noise]
shot_noise = {}
[response.blur]
psf = {sigma_px = 2.0}
'''))
    jobs = expand_jobs(c)
    assert [j.key for j in jobs] == [
        "17/CAHV/dots/raycast[spp=4,adaptive,coverage=area,response=blur]",
        "17/CAHV/dots/raycast[spp=4,adaptive,coverage=area]",
        "17/CAHV/dots/raycast[spp=1,adaptive,coverage=area,response=noise]"]
    assert [j.response_name for j in jobs] == ["blur", "clean", "noise"]
    assert {j.seed for j in jobs} == {5}
    assert Campaign.from_dict(c.as_dict()) == c
    # without renderer.response every profile runs, in file order
    c2 = load_campaign(_write(tmp_path, 'cameras = [17]\nmodels = ["CAHV"]\n'
                                        '[response.noise]\nshot_noise = {}\n[response.clean]\n',
                              "c2.toml"))
    assert [j.key for j in expand_jobs(c2)] == [
        "17/CAHV/dots/raycast[spp=16,adaptive,coverage=area,response=noise]",
        "17/CAHV/dots/raycast[spp=16,adaptive,coverage=area]"]


def test_a_campaign_document_from_before_response_profiles_still_loads():
    c = load_campaign(ROOT / "campaigns" / "quick.toml")
    old = c.as_dict()
    del old["seed"], old["response"]
    assert Campaign.from_dict(old) == c
    assert c.responses == () and [j.response for j in expand_jobs(c)] == [{}] * 18


R = 'cameras = [15]\n'


@pytest.mark.parametrize("text, message", [
    (R + '[response.noisy]\nshotnoise = {}\n',
     r"c\.toml: response\.noisy\.shotnoise: unknown key; known keys: seed, full_well_e, "
     r"vignetting, psf, motion_blur, global_gain, shot_noise, dark_current, hot_pixels, "
     r"dead_pixels, saturation, read_noise, encoding, quantise$"),
    (R + '[response.noisy]\nread_noise = {sigma = 3}\n',
     r"response\.noisy\.read_noise\.sigma: unknown key; known keys: sigma_e$"),
    (R + '[response.noisy]\nquantise = {bits = 9}\n',
     r"response\.noisy: quantise\.bits = 9; known: 8, 10, 12, 14, 16"),
    (R + '[response.noisy]\npsf = {kind = "airy"}\n',
     r"response\.noisy: psf\.kind = 'airy' is unknown; known: gaussian, disc"),
    (R + '[response.noisy]\nread_noise = {}\n', r"response\.noisy: .*needs 'sigma_e'"),
    (R + '[response.noisy]\nshot_noise = true\n',
     r"response\.noisy\.shot_noise: expected a table of the stage's parameters"),
    (R + '[response.noisy]\nseed = -1\nshot_noise = {}\n',
     r"response\.noisy\.seed: expected an integer >= 0; got -1"),
    (R + 'response = 3\n', r"response: expected tables \[response\.NAME\]"),
    (R + '[response]\nshot_noise = {}\n',
     r"response\.shot_noise: a profile named like a response setting; put the stages in a "
     r"profile table \[response\.NAME\]"),
    (R + '[response]\nfull_well_e = 1000\n', r"response\.full_well_e: expected a table"),
    (R + '[response."a b"]\nshot_noise = {}\n', r"a profile name may hold only letters"),
    (R + '[response.a]\n[response.b]\n', r"profiles 'a' and 'b' both have no stages"),
    (R + 'seed = -2\n', r"c\.toml: seed: expected an integer >= 0; got -2"),
    (R + '[[renderer]]\nname = "raycast"\nresponse = ["noisy"]\n[response.clean]\n',
     r"renderer\[0\]\.response: unknown response profile 'noisy'; known profiles: clean$"),
    (R + '[[renderer]]\nname = "raycast"\nresponse = ["noisy"]\n',
     r"unknown response profile 'noisy'; known profiles: \(none: add \[response\.NAME\]"),
])
def test_response_errors_name_the_key(tmp_path, text, message):
    with pytest.raises(CampaignError, match=message):
        load_campaign(_write(tmp_path, text))


def test_cli_bad_response_stage_is_one_line_exit_2(tmp_path):
    p = _write(tmp_path, 'cameras = [15]\n[response.noisy]\nshot_noise = {}\nblur = {}\n')
    out = subprocess.run([sys.executable, "-m", "camval.cli", "verify", str(p), "--out",
                          str(tmp_path / "run")], capture_output=True, text=True, cwd=ROOT,
                         timeout=120)
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1, out.stderr
    assert "response.noisy.blur: unknown key; known keys: seed, full_well_e, vignetting" \
        in lines[0]
    assert not (tmp_path / "run").exists()


def test_a_terrain_only_renderer_is_refused_with_the_scene_kinds(tmp_path):
    doc = {"name": "t", "cameras": [15], "models": ["CAHV"],
           "renderer": [{"name": "raycast_terrain"}], "calibrator": [{"name": "jpl"}]}
    with pytest.raises(CampaignError, match="renders terrain scenes, not the boards"):
        parse_campaign(doc).validate()


def test_a_calibrator_can_keep_to_some_targets():
    # mrcal's calibration object is a regular grid: a campaign gives it the dots only, and
    # the AprilTag jobs carry jpl alone
    c = parse_campaign({"name": "t", "cameras": [15], "models": ["CAHV"],
                        "targets": ["dots", "apriltag"],
                        "calibrator": [{"name": "jpl"}, {"name": "mrcal", "targets": ["dots"]}]})
    c.validate()
    cals = {j.target: sorted({name for name, _, _ in j.calibrators}) for j in expand_jobs(c)}
    assert cals == {"dots": ["jpl", "mrcal"], "apriltag": ["jpl"]}


def test_verdict_modes_default_order_and_errors(tmp_path):
    r'''verdict_modes: the verdict's floor and renderer projection modes; "rotation" by
default, stated in the run's campaign document; a document from before the key (which
computed every mode) reads as every mode'''
    from harness.compare import PROJECTION_MODES
    c = parse_campaign({"cameras": [15]})
    assert c.verdict_modes == ("rotation",) and c.as_dict()["verdict_modes"] == ["rotation"]
    assert {j.verdict_modes for j in expand_jobs(c)} == {("rotation",)}
    c = parse_campaign({"cameras": [15], "verdict_modes": ["world", "rotation", "intrinsics"]})
    assert c.verdict_modes == PROJECTION_MODES
    assert Campaign.from_dict(c.as_dict()) == c
    assert {j.verdict_modes for j in expand_jobs(c)} == {PROJECTION_MODES}
    old = c.as_dict()
    del old["verdict_modes"]
    assert Campaign.from_dict(old).verdict_modes == PROJECTION_MODES
    for bad, message in ((["intrinsics"], "must include 'rotation'"),
                         (["rotation", "pixels"], "unknown mode 'pixels'"),
                         ([], "expected a non-empty list")):
        with pytest.raises(CampaignError, match=message):
            parse_campaign({"cameras": [15], "verdict_modes": bad}, source="c.toml")
