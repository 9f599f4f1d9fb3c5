r'''What every benchmark shares: job lists, timing, the parser, and one JSON document per run

SYNOPSIS

    import common                                   # from a script in benchmarks/
    from common import camera_stage, poses_stage    # harness stage functions: only through here

    parser = common.parser(__doc__)                 # --out-dir, --repeats, --warmup
    parser = common.parser(__doc__, PARTS)          # or one subcommand per part
    parser.add_argument("--cameras", type=common.ids, default="15,12")
    args = parser.parse_args()
    out = common.Results("bench_render", args)      # schema, kind, commit, machine, load average
    t = common.timed(lambda: work(), repeats=args.repeats, warmup=args.warmup)
    out.add("raycast/speed/15/CAHVOR", cpu_s=t["cpu_s"], wall_s=t["wall_s"])
    path = out.write()     # benchmarks/results/<UTC stamp>-bench_render.json, never overwritten

The document: {"schema": 1, "schema_version": 1, "kind": "camval-benchmark",
"script", "created",
"commit": {"commit", "dirty"}, "machine", "environment" (numba threads, load
average at start and end), "args", "records": {fullname: {...}}}. Every
measured case is one record keyed by a stable fullname ("part/case/..."), as a
campaign's records are; a record may say "status": "failed" with a "reason".

Timings (timed): warm-up calls first (not counted), then `repeats` calls, each
measured in process CPU seconds (time.process_time: all threads of this
process) and wall seconds (time.perf_counter); reported as min, median and
every value. peak_rss_bytes() is the process's peak resident memory so far;
ProcessTree samples each descendant process's peak (a campaign's workers).

The harness's stage functions are imported lazily through this module (see
STAGES): a benchmark never imports them from their harness module itself, so
that a move of a stage changes one line here. --help stays instant: nothing
heavy is imported before the arguments are parsed.
'''

import argparse
import importlib
import os
import resource
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
# the synthetic-observation fixtures live with the tests (tests/synthetic.py)
if str(ROOT / "tests") not in sys.path:
    sys.path.append(str(ROOT / "tests"))

from harness.records import (  # noqa: E402  (light: no numba, no renderer)
    BENCHMARK_KIND,
    SCHEMA_VERSION,
    git_commit,
    machine,
    utc_now,
    utc_stamp,
    write_json_atomic,
)

RESULTS_DIR = ROOT / "benchmarks" / "results"
KIND = BENCHMARK_KIND
CAMPAIGNS = ROOT / "campaigns"
FAMILIES = ("CAHV", "CAHVOR", "CAHVORE")

# Every harness name a benchmark uses -> (module, attribute), imported on first use. When a
# stage moves or is renamed, only its entry here changes.
STAGES = {name: ("harness.stages", name) for name in (
    "camera_stage", "poses_stage", "render_stage", "detect_stage", "observations_from",
    "calibrate_stage", "compare_stage", "StageFailed", "cached_target", "cached_renderer")}
STAGES.update({name: ("harness.runner", name) for name in ("run_job", "run_campaign",
                                                           "stage_seconds")})
STAGES.update({"expand_jobs": ("harness.jobs", "expand_jobs"),
               "warm_up": ("harness.warmup", "warm_up")})
STAGES.update({name: ("harness.campaign", name) for name in ("load_campaign",
                                                             "parse_campaign")})


def __getattr__(name):
    r'''`from common import camera_stage`: the harness's function, imported only now'''
    if name not in STAGES:
        raise AttributeError(f"module 'common' has no attribute {name!r}")
    module, attribute = STAGES[name]
    return getattr(importlib.import_module(module), attribute)


def _stage(name):
    return __getattr__(name)


# ---------------------------------------------------------------- the parser

_HelpFormatter = argparse.RawDescriptionHelpFormatter


def parser(doc, parts=None, repeats=3, warmup=1):
    r'''An ArgumentParser whose --help is the script's docstring, with the shared options

--out-dir (where the JSON document goes), --repeats and --warmup (timed()).
parts {name: (function, add_arguments)}: one subcommand per part instead, each
with the shared options, its function's docstring as its --help, and
`repeats_warmup` (an attribute of the function) as its defaults.
'''
    ap = argparse.ArgumentParser(description=doc, formatter_class=_HelpFormatter)
    if parts is None:
        add_common(ap, repeats, warmup)
        return ap
    sub = ap.add_subparsers(dest="part", required=True, metavar="PART")
    for name, (fn, add_arguments) in parts.items():
        p = sub.add_parser(name, help=fn.__doc__.splitlines()[0].replace("%", "%%"),
                           description=fn.__doc__,
                           formatter_class=_HelpFormatter)
        add_common(p, *getattr(fn, "repeats_warmup", (repeats, warmup)))
        if add_arguments:
            add_arguments(p)
        p.set_defaults(run=fn)
    return ap


def add_common(ap, repeats=3, warmup=1):
    ap.add_argument("--out-dir", type=Path, default=RESULTS_DIR,
                    help="directory of the JSON document (<UTC stamp>-<script>.json)")
    ap.add_argument("--repeats", type=int, default=repeats, help="timed repetitions")
    ap.add_argument("--warmup", type=int, default=warmup, help="untimed calls first")
    return ap


def ids(text):
    r'''"5,8,15" or "5 8 15" -> ["5", "8", "15"] (catalogue slots as the campaigns key them)'''
    return [s for s in text.replace(",", " ").split() if s]


def families(text):
    out = ids(text)
    for f in out:
        if f not in FAMILIES:
            raise argparse.ArgumentTypeError(f"{f!r} is not a model family; known: "
                                             f"{', '.join(FAMILIES)}")
    return out


# ---------------------------------------------------------------- timing

def timed(fn, repeats=3, warmup=1):
    r'''Call fn `warmup` times untimed, then `repeats` times timed -> dict

{"cpu_s": {"min", "median", "values"}, "wall_s": {...}, "result": fn's last return value}
'''
    for _ in range(warmup):
        fn()
    cpus, walls = [], []
    result = None
    for _ in range(max(1, repeats)):
        c0, t0 = time.process_time(), time.perf_counter()
        result = fn()
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    return {"cpu_s": summary(cpus), "wall_s": summary(walls), "result": result}


class Stopwatch:
    r'''with Stopwatch() as sw: ...; sw.cpu_s, sw.wall_s'''

    def __enter__(self):
        self._c, self._t = time.process_time(), time.perf_counter()
        return self

    def __exit__(self, *exc):
        self.wall_s = time.perf_counter() - self._t
        self.cpu_s = time.process_time() - self._c
        return False


def summary(values):
    r'''{"min", "median", "values"} of a list of seconds (empty -> None figures)'''
    values = [float(v) for v in values]
    if not values:
        return {"min": None, "median": None, "values": []}
    return {"min": min(values), "median": statistics.median(values), "values": values}


def peak_rss_bytes():
    r'''Peak resident memory of this process so far (Linux: ru_maxrss is in KiB)'''
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def proc_status(pid="self", field="VmHWM"):
    r'''A field of /proc/<pid>/status in bytes (VmHWM: peak resident, VmRSS: resident now);
0 where there is none (not Linux, or the process is gone)'''
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith(field + ":"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


def _proc_stat(pid):
    r'''(parent pid, CPU seconds user + system, minor page faults, system CPU seconds) of a
live process, or None'''
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    tick = os.sysconf("SC_CLK_TCK")
    return (int(fields[1]), (int(fields[11]) + int(fields[12])) / tick, int(fields[7]),
            int(fields[12]) / tick)


class ProcessTree:
    r'''Peak resident memory and CPU seconds of each descendant process, sampled

SYNOPSIS

    with common.ProcessTree() as tree:       # a thread reads /proc every `interval` s
        run_campaign(...)                    # local workers: grandchildren (forkserver)
    tree.processes   # [{"pid", "role", "peak_rss_bytes", "cpu_s", "sys_s", "minflt"}, ...]

getrusage(RUSAGE_CHILDREN) cannot say this: it holds the largest child already
waited for, and a forkserver's workers are its children, not this process's.
The peak (VmHWM) only grows, so the last sample of a process is its peak up to
`interval` before it ended; the CPU seconds likewise. role: "worker" (a
child of a child: a forkserver's), "child" (a direct child: the forkserver, the
resource tracker, a fork-started worker). Empty where /proc is not readable.
'''

    def __init__(self, interval=0.2):
        self.interval = interval
        self._seen = {}
        self._stop = None

    def _sample(self):
        me = os.getpid()
        parents = {}
        for name in os.listdir("/proc"):
            if name.isdigit():
                st = _proc_stat(name)
                if st is not None:
                    parents[int(name)] = st
        for pid, (_, cpu, minflt, sys_s) in parents.items():
            depth, p = 0, pid
            while p in parents and p != me and depth < 8:
                p, depth = parents[p][0], depth + 1
            if p != me or pid == me:
                continue
            hwm = proc_status(pid, "VmHWM")
            rec = self._seen.setdefault(pid, {"pid": pid, "role": "child" if depth == 1
                                              else "worker", "peak_rss_bytes": 0,
                                              "cpu_s": 0.0, "sys_s": 0.0, "minflt": 0})
            rec["peak_rss_bytes"] = max(rec["peak_rss_bytes"], hwm)
            rec["cpu_s"] = max(rec["cpu_s"], cpu)
            rec["sys_s"] = max(rec["sys_s"], sys_s)
            rec["minflt"] = max(rec["minflt"], minflt)

    def _run(self):
        while not self._stop.wait(self.interval):
            self._sample()

    def __enter__(self):
        import threading
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        if os.path.isdir("/proc/self"):
            self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()
        return False

    @property
    def processes(self):
        return sorted(self._seen.values(), key=lambda r: r["pid"])


def numba_threads():
    r'''numba's thread count (NUMBA_NUM_THREADS, else the cores), without importing numba'''
    return int(os.environ.get("NUMBA_NUM_THREADS") or os.cpu_count())


# ---------------------------------------------------------------- the jobs

def campaign_jobs(name="paper", cameras=None, families=None, sizes=None, targets=None):
    r'''The jobs of campaigns/<name>.toml (or a path), in the campaign's order, filtered

cameras: catalogue slots ("15"); families: "CAHVOR"...; sizes: (width, height) pairs of
the camera. The jobs are harness Job values, as the campaign's runner builds them.
'''
    load_campaign, expand_jobs = _stage("load_campaign"), _stage("expand_jobs")
    path = Path(name)
    if not path.suffix:
        path = CAMPAIGNS / f"{name}.toml"
    jobs = expand_jobs(load_campaign(path))
    if cameras:
        order = {str(c): i for i, c in enumerate(cameras)}
        jobs = sorted((j for j in jobs if j.camera_key in order),
                      key=lambda j: order[j.camera_key])
    if families:
        jobs = [j for j in jobs if j.family in families]
    if targets:
        jobs = [j for j in jobs if j.target in targets]
    if sizes:
        from reference_models.catalogue import load_catalogue
        cat = load_catalogue()
        jobs = [j for j in jobs
                if (cat.get(j.camera_key).model.width, cat.get(j.camera_key).model.height)
                in set(map(tuple, sizes))]
    return jobs


def job_inputs(job):
    r'''(truth model, target, poses) of a job, as the campaign makes them (or StageFailed)'''
    cached_target, camera_stage, poses_stage = map(_stage, ("cached_target", "camera_stage",
                                                           "poses_stage"))
    _, truth = camera_stage(job)
    target = cached_target(job.target)
    return truth, target, poses_stage(truth, target, job.poses_n, job.poses_seed,
                                       job.poses_cover)


def catalogue_slots(size=None):
    r'''Catalogue slots as strings, those of one (width, height) when size is given'''
    from reference_models.catalogue import load_catalogue
    return [str(e.id) for e in load_catalogue().slots()
            if size is None or (e.model.width, e.model.height) == tuple(size)]


# ---------------------------------------------------------------- the document

class Results:
    r'''One benchmark run's JSON document: add() records, write() once

Written through harness.records (atomic, NaN-free) to
<out_dir>/<UTC stamp>-<script>[-<part>].json; a name that exists already gets
"-2", "-3"...: a run never overwrites another.
'''

    def __init__(self, script, args=None, out_dir=None):
        self.script = script
        part = getattr(args, "part", None)
        self.name = f"{script}-{part}" if part else script
        self.out_dir = Path(out_dir or getattr(args, "out_dir", None) or RESULTS_DIR)
        # schema_version as a run document has it: `camval gate` reads this document too
        self.doc = {"schema": SCHEMA_VERSION, "schema_version": SCHEMA_VERSION, "kind": KIND,
                    "script": script, "part": part,
                    "created": utc_now(), "commit": git_commit(ROOT), "machine": machine(),
                    "environment": {"numba_threads": numba_threads(),
                                    "omp_threads": os.environ.get("OMP_NUM_THREADS"),
                                    "load_average_start": list(os.getloadavg())},
                    "argv": sys.argv[1:],
                    "args": {k: str(v) if isinstance(v, Path) else v
                             for k, v in sorted(vars(args or argparse.Namespace()).items())
                             if k != "run"},
                    "records": {}}

    @property
    def records(self):
        return self.doc["records"]

    def add(self, fullname, record=None, **fields):
        r'''Record one measured case under its fullname (twice is a bug: raises)'''
        if fullname in self.records:
            raise ValueError(f"benchmark record {fullname!r} added twice")
        rec = dict(record or {}, **fields)
        rec.setdefault("status", "ok")
        rec["fullname"] = fullname
        self.records[fullname] = rec
        return rec

    def write(self):
        self.doc["environment"]["load_average_end"] = list(os.getloadavg())
        self.doc["environment"]["peak_rss_bytes"] = peak_rss_bytes()
        self.out_dir.mkdir(parents=True, exist_ok=True)
        stamp = utc_stamp()
        for i in range(1, 1000):
            path = self.out_dir / (f"{stamp}-{self.name}.json" if i == 1 else
                                   f"{stamp}-{self.name}-{i}.json")
            try:
                # claim the name: O_EXCL fails if another run has it
                os.close(os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644))
            except FileExistsError:
                continue
            try:
                write_json_atomic(path, self.doc)
            except BaseException:
                path.unlink()
                raise
            print(f"wrote {path}", flush=True)
            return path
        raise FileExistsError(f"{self.out_dir}: no free name for {stamp}-{self.name}")


def main(script, ap, argv=None):
    r'''Parse, run the chosen part (args.run(args, results)), write the document -> exit status'''
    args = ap.parse_args(argv)
    out = Results(script, args)
    status = args.run(args, out) or 0
    out.write()
    return status
