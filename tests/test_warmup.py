r'''harness.warmup: every kernel a campaign's jobs call is compiled before the workers start'''

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from harness.campaign import parse_campaign
from harness.jobs import expand_jobs

ROOT = Path(__file__).resolve().parent.parent


def test_warm_up_renders_each_kind_once_unless_cached(tmp_path):
    from harness.warmup import kernels_cached, warm_up
    jobs = expand_jobs(parse_campaign({"cameras": ["SuperCam", 15, 17],
                                       "models": ["CAHV", "CAHVORE"],
                                       "renderer": [{"name": "raycast", "spp": [1, 4]}]}))
    info = warm_up(jobs, force=True, workers=1)
    assert info["renders"] == ["raycast/CAHV/dots", "raycast/CAHVORE/dots",
                               "raycast/dots/largest"]
    assert info["fits"] == ["jpl/CAHV", "jpl/CAHVORE"] and info["cached"] == []
    assert set(info["parts"]) == {"renders", "fits"}
    # SuperCam sees no board, camera 15 has no CAHVORE: cameras 15 and 17 warmed those kinds
    assert info["failed"] == []
    # a kind no job can warm: each job says why
    none = warm_up(expand_jobs(parse_campaign({"cameras": ["SuperCam", 15],
                                               "models": ["CAHVORE"]})), workers=1, force=True)
    assert none["renders"] == none["fits"] == []
    assert any(f.startswith("SuperCam/CAHVORE/") for f in none["failed"])
    assert any(f.startswith("15/CAHVORE/") and "cannot be derived" in f
               for f in none["failed"])
    # now numba's cache holds the kernels: nothing to warm
    assert kernels_cached("raycast") and kernels_cached("jpl") and kernels_cached("mrcal")
    again = warm_up(jobs)
    assert again["cached"] == ["raycast", "jpl"]
    assert again["renders"] == again["fits"] == [] and again["parts"] == {}
    assert warm_up([])["renders"] == []
    # an empty cache directory (as after a kernel change): not cached
    out = subprocess.run([sys.executable, "-c", "from harness.warmup import kernels_cached; "
                          "print(kernels_cached('raycast'), kernels_cached('jpl'))"],
                         capture_output=True, text=True, cwd=ROOT, timeout=300,
                         env=dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba")))
    assert out.stdout.strip() == "False False", out.stderr


# In a fresh numba cache: the warm-up (two processes), then the jobs in this process; numba's
# dispatcher stats count a compilation as a cache miss, so a kernel the warm-up left out is
# one with misses here
_COVERAGE = r'''
import json, sys, tomllib
from numba.core.dispatcher import Dispatcher
from harness.campaign import parse_campaign
from harness.jobs import expand_jobs
from harness.runner import run_job
from harness.warmup import warm_up

def main():
    # camera 1 (5120x3840): the dot detector's large-image path (float32)
    want = {("1", "CAHV", "dots"), ("15", "CAHV", "dots"), ("15", "CAHVOR", "dots"),
            ("17", "CAHVORE", "dots"), ("17", "CAHVORE", "apriltag")}
    with open("campaigns/quick.toml", "rb") as f:
        quick = tomllib.load(f)
    jobs = [j for j in expand_jobs(parse_campaign(dict(quick, cameras=[1, 15, 17])))
            if (j.camera_key, j.family, j.target) in want]
    info = warm_up(jobs, workers=2)
    statuses = [r["status"] for j in jobs for r in run_job(j)["records"]]
    missed = {f"{name}.{k}": [str(s) for s in v.stats.cache_misses]
              for name, mod in list(sys.modules.items())
              if name.split(".")[0] in ("harness", "targets", "renderers", "reference_models")
              for k, v in list(vars(mod).items())
              if isinstance(v, Dispatcher) and v.stats.cache_misses}
    # the kernels both warm-up processes call: one signature each, so that the two never add
    # different entries to one cache index at once (harness.warmup says why)
    import reference_models.kernels as K
    shared = {k: [str(s) for s in v.signatures] for k, v in vars(K).items()
              if isinstance(v, Dispatcher) and len(v.signatures) > 1}
    print(json.dumps({"warm_up": info, "statuses": statuses, "missed": missed,
                      "shared": shared}))

if __name__ == "__main__":
    main()
'''


def _fresh_cache_script(tmp_path, source, *args):
    r'''(the JSON document a script's last line prints, its environment): source run as a
script in this repository with args, in a numba cache directory of its own under tmp_path
(kept for the next call: the same cache)'''
    script = tmp_path / "script.py"
    script.write_text(source)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    out = subprocess.run([sys.executable, str(script), *args], capture_output=True, text=True,
                         cwd=ROOT, timeout=3600, env=env)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1]), env


@pytest.mark.slow
def test_warm_up_compiles_every_kernel_the_jobs_call(tmp_path):
    doc, env = _fresh_cache_script(tmp_path, _COVERAGE)
    assert doc["warm_up"]["renders"] == [
        "raycast/CAHVORE/dots", "raycast/CAHVORE/apriltag", "raycast/CAHV/dots",
        "raycast/CAHVOR/dots", "raycast/dots/largest", "raycast/apriltag/largest"]
    assert sorted(doc["warm_up"]["fits"]) == ["bias/apriltag", "jpl/CAHV", "jpl/CAHVOR",
                                              "jpl/CAHVORE", "opencv/CAHV", "opencv/CAHVOR",
                                              "opencv/CAHVORE"]
    assert set(doc["statuses"]) == {"ok"}
    assert doc["missed"] == {}
    assert doc["shared"] == {}
    # the install step: the cache is current now, so it compiles nothing
    cli = subprocess.run([sys.executable, "-m", "camval.cli", "warm-up", "campaigns/quick.toml"],
                         capture_output=True, text=True, cwd=ROOT, timeout=600, env=env)
    assert cli.returncode == 0, cli.stderr
    assert "nothing to compile; cached already: raycast, jpl" in cli.stderr
    # the fork server's preload (harness.warmup.load_cached_kernels): its workers start with
    # the serial kernels of the current cache in memory, not the parallel ones (loading those
    # starts numba's thread pool, which a fork does not carry over); a cache older than
    # reference_models/kernels.py is left to the workers for the modules that carry that
    # file's code (the warm-up drops it); a detector's cache does not depend on it
    current, _ = _fresh_cache_script(tmp_path, _PRELOAD, "current")
    assert current["worker"]["targets._dot_kernels"], current
    assert all(n >= 1 for n in current["worker"]["targets._dot_kernels"].values()), current
    assert current["worker"]["renderers._raycast_kernels"] == {"render_kernel": 0,
                                                                "band_chords": 1}, current
    assert current["loaded"] > 10 and not current["threads"], current
    stale, _ = _fresh_cache_script(tmp_path, _PRELOAD, "stale")
    assert all(n >= 1 for n in stale["worker"]["targets._dot_kernels"].values()), stale
    assert stale["worker"]["renderers._raycast_kernels"]["band_chords"] == 0, stale


_PRELOAD = r'''
import json, os, sys

def overloads(modname):
    import importlib
    return {k.__name__: len(k.overloads)
            for k in importlib.import_module(modname).compiled_entry_points()}

def main():
    import reference_models.kernels as rk
    import targets._dot_kernels as D
    if sys.argv[1] == "stale":
        t = os.path.getmtime(rk.__file__) - 60
        import renderers._raycast_kernels as R
        for k in [*D.compiled_entry_points(), *R.compiled_entry_points()]:
            os.utime(k._cache._cache_file._index_path, (t, t))
    from harness.executors import local_pool
    with local_pool(2) as pool:
        worker = {m: pool.submit(overloads, m).result()
                  for m in ("targets._dot_kernels", "renderers._raycast_kernels")}
    import numba.np.ufunc.parallel as P
    from harness.warmup import load_cached_kernels
    n = load_cached_kernels()
    print(json.dumps({"worker": worker, "loaded": n, "threads": bool(P._is_initialized)}))

if __name__ == "__main__":
    main()
'''


def test_a_blurring_response_makes_the_blurred_apriltag_path_its_own_kind():
    from harness.warmup import BLURRED_DETECTORS, _blurred, _render_kinds
    doc = {"cameras": [17], "models": ["CAHVORE"], "targets": ["apriltag", "dots"],
           "renderer": [{"name": "raycast", "response": ["clean", "realistic"]}],
           "response": {"clean": {}, "realistic": {"psf": {"kind": "gaussian",
                                                           "sigma_px": 0.7}}}}
    jobs = expand_jobs(parse_campaign(doc))
    blurred = {j.key: _blurred(j) for j in jobs}
    # the blurred AprilTag job only: its detector takes targets.tag_edges' kernels
    assert sorted(v for v in blurred.values() if v) == ["apriltag"]
    assert BLURRED_DETECTORS["apriltag"] == "targets._tag_edge_kernels"
    kinds = {k for k, _ in _render_kinds(jobs)}
    assert ("raycast", "CAHVORE", "apriltag", "blurred") in kinds
    assert ("raycast", "CAHVORE", "apriltag") in kinds          # the sharp one stays
    assert not any(len(k) == 4 and k[2] == "dots" for k in kinds)


# In a fresh numba cache: the warm-up of a sharp AprilTag job (as the install step's warm-up
# of the paper campaign leaves the cache), then that of the same job under a camera response
# that blurs, then (argument "job", a fresh process, as a worker) the blurred job: the blurred
# path's kernels (targets._tag_edge_kernels) loaded from the cache, none compiled (a miss)
_BLURRED = r'''
import json, sys
from numba.core.dispatcher import Dispatcher
from harness.campaign import parse_campaign
from harness.jobs import expand_jobs
from harness.warmup import warm_up

def main():
    doc = {"cameras": [17], "models": ["CAHVORE"], "targets": ["apriltag"],
           "calibrator": [{"name": "jpl"}],
           "renderer": [{"name": "raycast", "spp": 4, "response": ["clean", "realistic"]}],
           "response": {"clean": {},
                        "realistic": {"psf": {"kind": "gaussian", "sigma_px": 0.7}}}}
    jobs = expand_jobs(parse_campaign(doc))
    if sys.argv[1] == "warm":
        sharp = warm_up([j for j in jobs if not j.response], workers=2)
        print(json.dumps({"sharp": sharp, "warm_up": warm_up(jobs, workers=2)}))
        return
    from harness.runner import run_job
    recs = [r for j in jobs if j.response for r in run_job(j)["records"]]
    import targets._tag_edge_kernels as T
    kernels = [v for v in vars(T).values() if isinstance(v, Dispatcher)]
    print(json.dumps({"statuses": [r["status"] for r in recs],
                      "missed": sum(len(v.stats.cache_misses) for v in kernels),
                      "hits": sum(len(v.stats.cache_hits) for v in kernels)}))

if __name__ == "__main__":
    main()
'''


@pytest.mark.slow
def test_warm_up_compiles_the_blurred_apriltag_path(tmp_path):
    warm, _ = _fresh_cache_script(tmp_path, _BLURRED, "warm")
    job, _ = _fresh_cache_script(tmp_path, _BLURRED, "job")
    assert warm["sharp"]["renders"][0] == "raycast/CAHVORE/apriltag"
    # the render set ran again for the blurred kind: its detector's kernels were not cached
    assert "raycast/CAHVORE/apriltag/blurred" in warm["warm_up"]["renders"]
    assert set(job["statuses"]) == {"ok"}
    # the worker's detector took the blurred path, its kernels loaded from the cache
    assert job["hits"] > 0 and job["missed"] == 0, job
