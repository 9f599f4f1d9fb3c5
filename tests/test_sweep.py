'''Stability sweeps: level configurations, breakdown bookkeeping, and a noise sweep'''

import json

import numpy as np
import pytest

from harness.sweep import DIFFICULTIES, SweepError, breakdowns, response_for, run_sweep
from renderers.response import ResponseChain


def test_levels_are_valid_response_configurations():
    for d in ("noise", "blur", "motion"):
        for lv in DIFFICULTIES[d]["levels"]:
            chain = ResponseChain.from_config(response_for(d, lv))
            assert (len(chain.stages) == 0) == (lv == 0)
    assert response_for("noise", 50)["read_noise"] == {"sigma_e": 50.0}


def test_breakdown_is_the_first_broken_level():
    recs = [{"level": lv, "calibrator": "a", "model": "M", "status": "ok",
             "detection_rate": 1.0, "projection_rms_px": rms, "broken": rms > 0.05}
            for lv, rms in ((0, 0.01), (1, 0.02), (2, 0.09), (3, 0.04))]
    recs += [{"level": lv, "calibrator": "b", "model": "M", "status": "ok",
              "detection_rate": 1.0, "projection_rms_px": 0.01, "broken": False}
             for lv in range(4)]
    b = breakdowns(recs, [0, 1, 2, 3])
    assert b["a/M"]["level"] == 2 and "0.09 px" in b["a/M"]["reason"]
    assert b["b/M"] == {"level": None, "reason": None}


def test_unknown_difficulty_names_the_choices():
    with pytest.raises(SweepError, match="known: noise, blur, motion, spp, poses, tilt, range, dots, fov"):
        run_sweep(17, difficulty="fog")


@pytest.mark.slow
def test_noise_sweep_degrades_monotonically_and_breaks(tmp_path):
    sw = run_sweep(17, "CAHVOR", "dots", "noise", levels=[0, 1000, 4000, 10000], spp=2,
                   n_poses=4, calibrators=(("jpl", "CAHVOR"),))
    recs = [r for r in sw["records"] if r["calibrator"] == "jpl"]
    assert [r["level"] for r in recs] == [0, 1000, 4000, 10000]
    ok = [r for r in recs if r["status"] == "ok"]
    assert len(ok) >= 3
    rms = np.array([r["projection_rms_px"] for r in ok])
    assert np.all(np.diff(rms) > 0), rms
    assert rms[0] < 0.03
    assert recs[-1]["detection_rate"] < 1.0 or recs[-1]["status"] != "ok"
    b = sw["breakdown"]["jpl/CAHVOR"]
    assert b["level"] in (4000, 10000)
    json.dumps(sw, allow_nan=False)
