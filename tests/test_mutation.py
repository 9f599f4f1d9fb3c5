import pytest

from harness.mutation import (
    BELOW_DETECTION,
    FAULT_CASES,
    FAULT_FIELDS,
    campaign_doc,
    run_suite,
)
from reference_models.catalogue import load_catalogue
from renderers.legacy import FAULTS


def test_every_fault_has_a_case_and_named_parameters():
    assert set(FAULT_CASES) == set(FAULTS) == set(FAULT_FIELDS)
    assert len(set(FAULTS) - set(BELOW_DETECTION)) >= 8
    for fault, fields in FAULT_FIELDS.items():
        assert fields or fault in BELOW_DETECTION


def test_each_fault_moves_its_camera_beyond_the_gate():
    # the cases are chosen so that the fault changes the model measurably
    cat = load_catalogue()
    for fault in ("round_centre", "rounded_aspect", "theta90"):
        camera, family = FAULT_CASES[fault]
        m = cat.get(camera).model
        m = m.to_cahv() if family == "CAHV" else m
        a, b = m.photogrammetric(), FAULTS[fault](m).photogrammetric()
        moved = max(abs(a.Hc - b.Hc), abs(a.Vc - b.Vc), abs(a.Hs - b.Hs),
                    abs(a.theta_deg - b.theta_deg) * 100)
        assert moved > 0.1, fault


def test_campaign_doc():
    d = campaign_doc(15, "CAHVOR", "half_pixel", spp=4, poses=3)
    assert d["renderer"] == [{"name": "faulty", "spp": 4, "options": {"fault": "half_pixel"}}]
    assert d["cameras"] == [15] and d["models"] == ["CAHVOR"] and d["poses"]["n"] == 3
    assert campaign_doc(8, "CAHVORE")["renderer"] == [{"name": "raycast", "spp": 16}]


@pytest.mark.slow
def test_gate_catches_every_fault_and_passes_the_clean_renderer_over_10_reruns(tmp_path):
    report = run_suite(tmp_path, reruns=10)
    for fault, r in report["faults"].items():
        if fault in BELOW_DETECTION:
            assert r["verdict"] == "below detection"
        else:
            assert r["verdict"] == "caught", (fault, r)
            assert set(r["named"]) <= set(FAULT_FIELDS[fault]) and r["named"]
    assert len(report["clean"]) == 10 + 2    # 10 reruns of the first case, the others once
    assert all(c["passed"] for c in report["clean"]), [c for c in report["clean"]
                                                       if not c["passed"]]
    assert report["ok"]
