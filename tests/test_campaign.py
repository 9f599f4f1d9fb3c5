import subprocess
import sys
from pathlib import Path

import pytest

from harness.campaign import Campaign, CampaignError, load_campaign, parse_campaign
from harness.runner import expand_jobs

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
    assert len(jobs) == 22 * 3
    assert jobs[0].key == "1/CAHV/dots/raycast[spp=16,adaptive]"
    assert jobs[0].fullname("jpl", "CAHV") == "1/CAHV/dots/raycast[spp=16,adaptive]/jpl[CAHV]"
    assert len({j.key for j in jobs}) == len(jobs)


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
        "17/CAHVOR/dots/raycast[spp=1,adaptive]", "17/CAHVOR/dots/raycast[spp=1,full]",
        "17/CAHVOR/dots/raycast[spp=4,adaptive]", "17/CAHVOR/dots/raycast[spp=4,full]"]
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
    assert jobs[0].key == "file-nav.cahvor/CAHV/dots/raycast[spp=16,adaptive]"


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
    ('cameras = [15]\ntargets = ["checkers"]\n',
     r"targets: unknown target 'checkers'; known: dots, apriltag, chessboard"),
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
    out = subprocess.run([sys.executable, "-m", "harness.cli", "verify", str(p), "--out",
                          str(tmp_path / "run")], capture_output=True, text=True, cwd=ROOT,
                         timeout=120)
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1, out.stderr
    assert "renderer[0].name: unknown renderer 'blender'" in lines[0]
    assert not (tmp_path / "run").exists()
