r'''The calibrate + compare stages of a campaign's jobs: CPU per job and calibrator, and
how far a change moved the records, in units of their sigma

SYNOPSIS

    OPENBLAS_NUM_THREADS=1 uv run --frozen python benchmarks/bench_fits.py run \
        [--campaign paper] [--jobs 15/CAHVOR,17/CAHVORE] [--stages /tmp/camval_bench_fits.pkl] \
        [--records-out /tmp/fits-after.json] [--profile 30]
    uv run --frozen python benchmarks/bench_fits.py diff BEFORE AFTER   # run dirs or --records-out

run: each job of --campaign (every one by default; twins grouped as the campaign
groups them) runs as harness.runner.run_job runs it, except that the render +
detect stage's output is kept in the --stages pickle and read back on later runs:
the calibrate + compare part of the campaign (the image fits, compare_stage, the
verdict with its exact fits) is timed alone, in process CPU seconds
(time.process_time, the records' seconds.cpu.calibrate_compare), per job, and its
records are written to --records-out for `diff`. --profile N prints the top N
functions of a cProfile over every job (cumulative and own time). Records:
fits/<job> (cpu_s, and each calibrator's CPU seconds in calibrate, compare,
exact_fit and verdict) and fits/total.

diff: for every record ok in both, each quantity that has a sigma in BEFORE's
verdict.renderer.sigma (the scatter of the image fit under the measured
detection noise): |AFTER - BEFORE| / sigma of the record's total parameter error
(params), of its renderer part (verdict.renderer) and of its floor
(verdict.floor); projection_rms for the projection RMS (rotation mode). Prints the
largest per record kind and overall, the largest over the records judged in both
(verdict.floor_far false), the records whose status or verdict flags (floor_far,
fits_disagree) changed and the largest changes of records without a sigma
(absolute). Records: diff/<calibrator>/<part> (max_z, where), diff/<calibrator>/judged,
diff/flags_changed and diff/max.
'''

import json
import math
import os
import pickle
import sys
import time
from pathlib import Path

import common

SCRIPT = "bench_fits"


def _jobs(campaign, specs):
    from harness.jobs import group_twins
    jobs = common.campaign_jobs(campaign)
    if specs:
        want = {tuple(s.split("/", 1)) for s in specs}
        jobs = [j for j in jobs if (j.camera_key, j.family) in want]
    return group_twins(jobs)


def _cached_stage(cache, stored):
    r'''harness.runner.render_detect_stage, its outputs kept in stored[job.key]'''
    import harness.runner
    inner = harness.runner.render_detect_stage

    def stage(job, *a, **kw):
        if job.key not in stored:
            stored[job.key] = inner(job, *a, **kw)
            with open(cache, "wb") as f:
                pickle.dump(stored, f)
        return stored[job.key]
    return stage


PARTS_TIMED = ("calibrate", "compare", "exact_fit", "verdict")


def _cpu_wrappers(cpu):
    r"""calibrator_records' stages wrapped: CPU seconds per (calibrator, part) into cpu"""
    import harness.job_records
    import harness.verdict

    def wrap(module, name, part, calibrator):
        inner = getattr(module, name)

        def timed(*a, **kw):
            c0 = time.process_time()
            try:
                return inner(*a, **kw)
            finally:
                key = (calibrator(a), part)
                cpu[key] = cpu.get(key, 0.0) + time.process_time() - c0
        setattr(module, name, timed)

    wrap(harness.job_records, "calibrate_stage", "calibrate", lambda a: a[0])
    wrap(harness.job_records, "compare_stage", "compare", lambda a: a[1].calibrator)
    wrap(harness.verdict, "exact_fit", "exact_fit", lambda a: a[0])
    wrap(harness.verdict, "assess", "verdict", lambda a: a[1].calibrator)


def part_run(args, out):
    r"""CPU seconds of the calibrate + compare stages of a campaign's jobs (see the module doc)"""
    import cProfile
    import io
    import pstats

    import harness.compare
    import harness.runner
    import harness.verdict
    from harness.warmup import warm_up

    stored = {}
    if args.stages.exists():
        with open(args.stages, "rb") as f:
            stored = pickle.load(f)
    jobs = _jobs(args.campaign, args.jobs)
    harness.runner.render_detect_stage = _cached_stage(args.stages, stored)
    warm_up(jobs)
    # the first fit of each calibrator pays imports and compilation: not the campaign's
    # repeated cost, so one untimed job first (its memoised exact fits and truth points
    # forgotten: the timed run of that job must compute them again)
    harness.runner.run_job(jobs[0])
    harness.verdict._EXACT_FITS.clear()
    harness.compare._TRUTH_POINTS.clear()
    cpu = {}
    _cpu_wrappers(cpu)
    prof = cProfile.Profile(time.process_time) if args.profile else None
    records, total, per_cal = {}, 0.0, {}
    print(f"{'job':<16} {'cpu s':>6}  " + "  ".join(f"{c:>22}" for c in ("jpl", "mrcal",
                                                                           "opencv"))
          + "   (CPU s: calibrate compare exact_fit verdict)")
    for job in jobs:
        fresh = job.key not in stored
        cpu.clear()
        if prof:
            prof.enable()
        result = harness.runner.run_job(job)
        if prof:
            prof.disable()
        recs = result["records"]
        job_cpu = next(((r.get("seconds") or {}).get("cpu") or {} for r in recs
                        if "cpu" in (r.get("seconds") or {})), {})
        cc = float(job_cpu.get("calibrate_compare", 0.0))   # 0: the job failed earlier
        by_part = {}
        for (c, part), x in cpu.items():
            by_part.setdefault(c, [0.0] * 4)[PARTS_TIMED.index(part)] += x
        for r in recs:
            records[r["fullname"]] = r
        total += cc
        for c, w in by_part.items():
            per_cal[c] = [a + b for a, b in zip(per_cal.get(c, [0.0] * 4), w, strict=True)]
        out.add(f"fits/{job.key}", cpu_s=cc, rendered_now=fresh,
                cpu_s_by_part={c: dict(zip(PARTS_TIMED, w, strict=True))
                               for c, w in by_part.items()})
        print(f"{job.key.split('/dots')[0]:<16} {cc:>6.2f}  " + "  ".join(
            "{:>5.2f} {:>5.2f} {:>5.2f} {:>4.2f}".format(*by_part.get(c, [0.0] * 4))
            for c in ("jpl", "mrcal", "opencv")), flush=True)
    out.add("fits/total", cpu_s=total, cpu_s_by_part={
        c: dict(zip(PARTS_TIMED, w, strict=True)) for c, w in per_cal.items()},
        load_average_end=list(os.getloadavg()))
    print(f"total calibrate + compare CPU s: {total:.2f} over {len(jobs)} jobs "
          f"(CPU s per calibrator: calibrate compare exact_fit verdict)")
    for c, w in sorted(per_cal.items()):
        print(f"  {c:<8} " + " ".join(f"{x:7.2f}" for x in w))
    if args.records_out:
        args.records_out.write_text(json.dumps(records, allow_nan=True))
        print(f"records -> {args.records_out}")
    if prof:
        for key in ("cumulative", "tottime"):
            s = io.StringIO()
            pstats.Stats(prof, stream=s).sort_stats(key).print_stats(args.profile)
            print(s.getvalue())


def _load_records(path):
    path = Path(path)
    if path.is_dir():
        from harness.records import load_run
        return load_run(path)["records"]
    return json.loads(path.read_text())


def _get(d, *keys):
    for k in keys:
        if not isinstance(d, dict):
            return None
        d = d.get(k)
    return d


def _num(x):
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _quantities(r):
    r'''{(part, quantity): value} of a record: total, renderer and floor parameters and
projection RMS'''
    out = {}
    v = r.get("verdict") if isinstance(r.get("verdict"), dict) else {}
    parts = {"total": (r.get("params"), _get(r, "projection", "rotation", "rms")),
             "renderer": (_get(v, "renderer", "params"), _get(v, "renderer", "projection",
                                                               "rms")),
             "floor": (_get(v, "floor", "params"), _get(v, "floor", "projection", "rms"))}
    for part, (params, proj) in parts.items():
        for k, x in (params or {}).items():
            if _num(x):
                out[(part, k)] = float(x)
        if _num(proj):
            out[(part, "projection_rms")] = float(proj)
    return out


# the verdict's flags a change must keep (diff lists each record whose flag changed)
FLAGS = ("floor_far", "fits_disagree")


def part_diff(args, out):
    r'''How far AFTER's records lie from BEFORE's, in units of BEFORE's sigma (module doc)'''
    a, b = _load_records(args.before), _load_records(args.after)
    status = [(k, a[k].get("status"), b[k].get("status")) for k in sorted(set(a) & set(b))
              if a[k].get("status") != b[k].get("status")]
    missing = sorted(set(a) ^ set(b))
    worst = {}        # (calibrator, part) -> (z, fullname, quantity, before, after)
    nosigma = {}      # calibrator -> (|change|, fullname, quantity, before, after)
    per_record = []   # (z, fullname, part, quantity, before, after, projection z)
    judged = {}       # calibrator -> (z, fullname, part, quantity): records judged in both
    flags = []        # (fullname, flag, before, after): a verdict flag that changed
    n = 0
    for k in sorted(set(a) & set(b)):
        ra, rb = a[k], b[k]
        if ra.get("status") != "ok" or rb.get("status") != "ok":
            continue
        n += 1
        sigma = _get(ra, "verdict", "renderer", "sigma") or {}
        qa, qb = _quantities(ra), _quantities(rb)
        cal = ra.get("calibrator")
        mine = (0.0, None, None, None, None)
        proj_z = 0.0
        for key in sorted(set(qa) | set(qb)):
            part, q = key
            if key not in qa or key not in qb:
                worst_key = (cal, part)
                w = worst.get(worst_key)
                if w is None or w[0] < math.inf:
                    worst[worst_key] = (math.inf, k, q, qa.get(key), qb.get(key))
                continue
            d = abs(qb[key] - qa[key])
            s = sigma.get(q)
            if _num(s) and s > 0:
                z = d / s
                w = worst.get((cal, part))
                if w is None or z > w[0]:
                    worst[(cal, part)] = (z, k, q, qa[key], qb[key])
                if z > mine[0]:
                    mine = (z, part, q, qa[key], qb[key])
                if q == "projection_rms":
                    proj_z = max(proj_z, z)
            elif d > 0:
                w = nosigma.get(cal)
                if w is None or d > w[0]:
                    nosigma[cal] = (d, k, q, qa[key], qb[key])
        if mine[0] > 0:
            per_record.append((mine[0], k, *mine[1:], proj_z))
        for flag in FLAGS:
            fa, fb = _get(ra, "verdict", flag), _get(rb, "verdict", flag)
            if fa != fb:
                flags.append((k, flag, fa, fb))
        if _get(ra, "verdict", "floor_far") is False and _get(rb, "verdict", "floor_far") is False:
            w = judged.get(cal)
            if w is None or mine[0] > w[0]:
                judged[cal] = (mine[0], k, mine[1], mine[2])
    print(f"{n} records ok in both; {len(missing)} in one run only; "
          f"{len(status)} changed status")
    for k, sa, sb in status:
        print(f"  status {k}: {sa} -> {sb}")
    overall = (0.0, None)
    for (cal, part), (z, k, q, x, y) in sorted(worst.items()):
        print(f"{cal:<7} {part:<9} max |change|/sigma {z:9.3g}  {k} {q}: {x!r} -> {y!r}")
        out.add(f"diff/{cal}/{part}", max_z=z if math.isfinite(z) else None, worst_record=k,
                quantity=q, before=x, after=y)
        if z > overall[0]:
            overall = (z, k)
    for cal, (z, k, part, q) in sorted(judged.items()):
        print(f"{cal:<7} judged    max |change|/sigma {z:9.3g}  {k} {part} {q} (records "
              f"whose verdict has floor_far false in both)")
        out.add(f"diff/{cal}/judged", max_z=z if math.isfinite(z) else None, worst_record=k,
                part=part, quantity=q)
    print(f"{len(flags)} verdict flags changed ({', '.join(FLAGS)})")
    for k, flag, fa, fb in flags:
        print(f"  {flag} {k}: {fa!r} -> {fb!r}")
    out.add("diff/flags_changed", n=len(flags), changes=[list(f) for f in flags])
    for cal, (d, k, q, x, y) in sorted(nosigma.items()):
        print(f"{cal:<7} without sigma: max |change| {d:.3g}  {k} {q}: {x!r} -> {y!r}")
    if per_record and args.top:
        print(f"the {args.top} records that moved most (their largest |change|/sigma; "
              f"proj z: the largest of their projection RMS figures)")
        for z, k, part, q, x, y, pz in sorted(per_record, reverse=True)[:args.top]:
            print(f"  {z:9.3g}  proj z {pz:9.3g}  {k} {part} {q}: {x!r} -> {y!r}")
    print(f"largest change over every record: {overall[0]:.3g} sigma ({overall[1]})")
    out.add("diff/max", max_z=overall[0] if math.isfinite(overall[0]) else None,
            worst_record=overall[1], records=n, status_changed=len(status), missing=len(missing))


def _run_arguments(ap):
    ap.add_argument("--campaign", default="paper", help="a campaign name or TOML path")
    ap.add_argument("--jobs", type=common.ids, default=None,
                    help="camera/family of the jobs (default every job)")
    ap.add_argument("--stages", type=Path, default=Path("/tmp/camval_bench_fits.pkl"),
                    help="where the render + detect outputs are kept between runs")
    ap.add_argument("--records-out", type=Path, default=None, help="the records (JSON)")
    ap.add_argument("--profile", type=int, default=0, help="print the top N of a cProfile")


def _diff_arguments(ap):
    ap.add_argument("before", type=Path, help="run directory or --records-out JSON")
    ap.add_argument("after", type=Path, help="run directory or --records-out JSON")
    ap.add_argument("--top", type=int, default=10, help="list the N records that moved most")


PARTS = {"run": (part_run, _run_arguments), "diff": (part_diff, _diff_arguments)}

if __name__ == "__main__":
    sys.exit(common.main(SCRIPT, common.parser(__doc__, PARTS, repeats=1, warmup=0)))
