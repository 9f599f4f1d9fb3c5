'''harness.quiet: C-library messages are kept off fds 1/2 and counted for the record'''

import os
import sys
import threading

import numpy as np
from synthetic import catalogue_models, default_target, exact_observations, synthetic_poses

from harness.quiet import capture, diagnostics_of, kind_of

# a CAHVORE whose projection of a point far off-axis fails inside mrcal.c: mrcal prints
# "mrcal.c(NNNN): CAHVORE PROJECTION OF (...) FAILED" to stderr (fd 2) from C
CAHVORE_INTRINSICS = np.array([500, 500, 512, 512, 0.01, 0.02, 0.1, 0.2, 0.3, 0.1, 0.1, 0.1])


def test_fd_writes_are_captured_and_python_prints_are_not(capfd):
    with capture() as cap:
        os.write(1, b"from C on fd 1\n")
        os.write(2, b"libdogleg at dogleg.c:1651: CHOLMOD warning: not positive definite\n")
        print("a progress line")
        print("an error line", file=sys.stderr)
    out, err = capfd.readouterr()
    assert "from C" not in out and "CHOLMOD" not in err
    assert "a progress line" in out and "an error line" in err
    assert cap.lines == ["from C on fd 1",
                         "libdogleg at dogleg.c:1651: CHOLMOD warning: not positive definite"]
    assert cap.summary()["kinds"] == {"other": 1, "CHOLMOD warning": 1}
    # the descriptors are back
    os.write(2, b"after\n")
    assert capfd.readouterr().err == "after\n"


def test_mrcal_cahvore_failure_is_silent_and_kept(capfd):
    import mrcal
    p = np.array([[10.0, 0.0, 0.1]])
    with capture() as cap:
        mrcal.project(p, "LENSMODEL_CAHVORE_linearity=1.0", CAHVORE_INTRINSICS)
    out, err = capfd.readouterr()
    assert out == "" and err == ""
    assert any(kind_of(x) == "CAHVORE projection failed" for x in cap.lines), cap.lines


def test_nested_and_threaded_blocks_each_get_their_lines(capfd):
    seen = {}
    barrier = threading.Barrier(2)

    def work(i):
        with capture() as cap:
            barrier.wait()
            os.write(2, f"thread {i}\n".encode())
            barrier.wait()
        seen[i] = cap.lines

    with capture() as outer:
        threads = [threading.Thread(target=work, args=(i,)) for i in range(2)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    assert capfd.readouterr().err == ""
    # overlapping blocks share their lines: none lost, each sees its own
    for i in range(2):
        assert f"thread {i}" in seen[i]
    assert sorted(outer.lines) == ["thread 0", "thread 1"]


def test_a_calibrator_record_carries_the_diagnostics(capfd):
    calls = []

    @diagnostics_of("mrcal")
    def fit(obs, target, model_name, truth=None):
        import mrcal
        mrcal.project(np.array([[10.0, 0.0, 0.1]]), "LENSMODEL_CAHVORE_linearity=1.0",
                      CAHVORE_INTRINSICS)
        calls.append(model_name)
        from harness.calibrators.base import CalibrationFailed
        raise CalibrationFailed("diverged: test")

    r = fit(None, None, "CAHVORE")
    assert capfd.readouterr() == ("", "")
    assert r.status == "failed" and r.reason == "diverged: test"
    d = r.info["diagnostics"]
    assert d["kinds"]["CAHVORE projection failed"] == 1 and d["n"] >= 1
    assert any("FAILED" in x for x in d["first"])


def test_mrcal_calibrate_result_has_diagnostics(capfd):
    from harness.calibrators import calibrate
    truth = dict(catalogue_models())["15"].with_theta_90()
    target = default_target()
    obs = exact_observations(truth, target, synthetic_poses(truth, target))
    r = calibrate("mrcal", obs, target, "CAHVOR", truth=truth, bias_correction=False)
    assert r.status == "ok", r.reason
    out, err = capfd.readouterr()
    assert out == "" and err == ""
    d = r.info["diagnostics"]
    assert set(d) == {"n", "kinds", "first"} and d["n"] == sum(d["kinds"].values())
