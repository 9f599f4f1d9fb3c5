r'''The verdict's cost and its figures on captured inputs, before and after a change

SYNOPSIS

    uv run --frozen python benchmarks/verdict_capture.py campaigns/quick.toml Q.pkl
    uv run --frozen python benchmarks/bench_verdict.py Q.pkl --save before.json
    ... change harness/verdict.py ...
    uv run --frozen python benchmarks/bench_verdict.py Q.pkl --compare before.json
    uv run --frozen python benchmarks/bench_verdict.py Q.pkl --profile 25

Replays harness.verdict.assess() on the inputs verdict_capture.py kept (the same
image fit, exact fit, noise and observations each time), each right after the
record's own comparison with the truth (harness.stages.compare_stage, untimed and
unprofiled: the campaign's order, so the memos of the truth's grid and of the fits'
pixels hold what they hold in a campaign), timing each record (CPU
seconds, best of --repeats) and collecting every sigma and z-score of its
renderer comparison and the expected projection sigma, and every leaf of the
verdict (numbers, flags, reasons; not its seconds). --save writes those
figures; --steps F scales the linearisation's finite-difference steps (compared
with a run at 1, the sigmas' own numerical noise; only the derivatives still
differenced read them: model_jacobians' stepped models (mrcal's R0 column, FISHEYE's
grid), not the closed forms of harness.verdict (jpl's G, Jg and J, mrcal's and OpenCV's G
and Jg) nor the posed fits' own J, whose steps are their own); --compare prints, for every
quantity, the largest relative change against a saved file, |after - before| /
|before| over all records, with the absolute change beside it (and the
records where a sigma appeared or vanished), and how many of the verdicts' leaves
are not the same bits. --profile N prints cProfile's N
most expensive functions over one pass; --parts times the verdict's floor, renderer
comparison and scatter apart, per calibrator. Results (per-calibrator CPU seconds
and the largest changes) go to a JSON document via benchmarks/common.py.
'''

import json
import math
import pickle
import time

import common


def _figures(v):
    r'''{"sigma.<q>": x, "z.<q>": x, "<part>.<mode>_rms": px} of one verdict'''
    out = {}
    for part in ("renderer", "floor"):
        proj = (v.get(part) or {}).get("projection") or {}
        for mode in ("rotation", "intrinsics", "world"):
            for k in ("rms", "max"):
                x = (proj.get(mode) or {}).get(k)
                if x is not None:
                    out[f"{part}.{mode}_{k}"] = float(x)
    r = v.get("renderer") or {}
    for part in ("sigma", "z"):
        for k, x in (r.get(part) or {}).items():
            if x is not None:
                out[f"{part}.{k}"] = float(x)
    return out


def _flat(v, prefix=""):
    r'''Every leaf of a verdict (numbers, strings, flags, None) by its path, its seconds
left out: what --compare holds bit for bit'''
    if isinstance(v, dict):
        out = {}
        for k, x in v.items():
            if k != "seconds":
                out.update(_flat(x, f"{prefix}{k}."))
        return out
    if isinstance(v, (list, tuple)):
        out = {}
        for i, x in enumerate(v):
            out.update(_flat(x, f"{prefix}{i}."))
        return out
    return {prefix.rstrip("."): v}


def _prime(a):
    r'''The record's own comparison with the truth (harness.stages.compare_stage), as the
campaign computes it just before the verdict (harness.job_records): the memos of the
truth's grid and of the fit's pixels then hold what they hold in a campaign'''
    from harness.stages import compare_stage
    compare_stage(a[0], a[1])


def _parts(cases, out):
    r'''CPU seconds of the verdict's parts per calibrator, as assess() computes them: the
floor (skipped where the exact fit IS the image fit: the record's own comparison), the
renderer comparison and the scatter, each record after its own comparison (_prime)'''
    from harness import blas
    from harness import verdict as vd
    parts = {}
    for _name, a, kw in cases:
        truth, res, exact = a[0], a[1], a[2]
        if exact.status != "ok" or exact.model is None:
            continue
        _prime(a)
        t = [time.process_time()]
        with blas.one_thread():
            if exact is not res:
                vd.floor_comparison(truth, exact)
            t.append(time.process_time())
            vd.fit_comparison(exact.model, res.model, truth, res.theta_estimated,
                              res.world_frame and exact.world_frame)
            t.append(time.process_time())
            vd.scatter(res, exact, kw["obs"], truth)
            t.append(time.process_time())
        p = parts.setdefault(res.calibrator, [0.0, 0.0, 0.0])
        for i in range(3):
            p[i] += t[i + 1] - t[i]
    for cal, (fl, rd, sc) in sorted(parts.items()):
        print(f"{cal:8s} parts CPU: floor {fl:6.3f} s, renderer {rd:6.3f} s, scatter {sc:6.3f} s")
        out.add(f"parts/{cal}", floor_s=fl, renderer_s=rd, scatter_s=sc)


def main(argv=None):
    ap = common.parser(__doc__, repeats=1, warmup=0)
    ap.add_argument("inputs", help="a pickle from verdict_capture.py")
    ap.add_argument("--save", help="write each record's sigma and z to this JSON file")
    ap.add_argument("--compare", help="a --save file to compare with")
    ap.add_argument("--profile", type=int, default=0, help="print the N top functions")
    ap.add_argument("--match", default="", help="only records whose fullname contains this")
    ap.add_argument("--parts", action="store_true",
                    help="also time the verdict's three parts per calibrator: the floor "
                         "(exact fit vs truth), the renderer comparison (image fit vs exact "
                         "fit) and the scatter")
    ap.add_argument("--steps", type=float, default=1.0,
                    help="scale the finite-difference steps of the linearisation by this "
                         "(with --compare against a run at 1: the sigmas' numerical noise)")
    args = ap.parse_args(argv)
    from harness import verdict as vd
    if args.steps != 1.0:
        linearisation = vd.linearisation

        def scaled(res, obs):
            lin = linearisation(res, obs)
            if lin is not None:
                lin.steps = lin.steps * args.steps
            return lin
        vd.linearisation = scaled
    with open(args.inputs, "rb") as f:
        cases = [c for c in pickle.load(f) if args.match in c[0]]
    out = common.Results("bench_verdict", args)
    figures, cpu, leaves = {}, {}, {}
    for _name, a, kw in cases:        # warm every import and cache once
        _prime(a)
        vd.assess(*a, **kw)
    if args.profile:
        import cProfile
        import pstats
        pr = cProfile.Profile()
        pr.enable()
        for _name, a, kw in cases:
            pr.disable()
            _prime(a)
            pr.enable()
            vd.assess(*a, **kw)
        pr.disable()
        pstats.Stats(pr).sort_stats("cumulative").print_stats(args.profile)
    for name, a, kw in cases:
        best = math.inf
        for _ in range(max(1, args.repeats)):
            _prime(a)
            c0 = time.process_time()
            v = vd.assess(*a, **kw)
            best = min(best, time.process_time() - c0)
        figures[name] = _figures(v)
        leaves[name] = _flat(v)
        cal = a[1].calibrator
        cpu.setdefault(cal, []).append(best)
    if args.parts:
        _parts(cases, out)
    total = sum(sum(x) for x in cpu.values())
    for cal, xs in sorted(cpu.items()):
        print(f"{cal:8s} {len(xs):3d} records  verdict CPU {sum(xs):7.3f} s "
              f"(median {sorted(xs)[len(xs) // 2] * 1e3:.1f} ms, max {max(xs) * 1e3:.1f} ms)")
        out.add(f"cpu/{cal}", n=len(xs), cpu_s=sum(xs), max_s=max(xs))
    print(f"all      {sum(len(x) for x in cpu.values()):3d} records  verdict CPU {total:7.3f} s")
    out.add("cpu/all", cpu_s=total)
    if args.save:
        with open(args.save, "w") as f:
            json.dump({"figures": figures, "leaves": leaves}, f, indent=1, sort_keys=True)
        print(f"wrote {args.save}")
    if args.compare:
        with open(args.compare) as f:
            before = json.load(f)
        before_leaves = before.get("leaves", {})
        before = before.get("figures", before)
        worst, changed = {}, []
        for name, fig in figures.items():
            b = before.get(name, {})
            if set(b) != set(fig):
                changed.append((name, sorted(set(b) ^ set(fig))))
            for k in set(b) & set(fig):
                rel = abs(fig[k] - b[k]) / abs(b[k]) if b[k] else abs(fig[k])
                q = k.split(".", 1)[0] + "." + k.split(".", 1)[1].split("[")[0]
                if rel >= worst.get(q, (-1,))[0]:
                    worst[q] = (rel, name, b[k], fig[k])
        print("largest relative change per quantity (before -> after):")
        for q, (rel, name, b, a) in sorted(worst.items(), key=lambda t: -t[1][0]):
            print(f"  {q:24s} {rel:9.2e} (abs {abs(a - b):8.1e})  {name}: {b:.6g} -> {a:.6g}")
            out.add(f"change/{q}", rel=rel, worst=name, before=b, after=a)
        for name, keys in changed[:10]:
            print(f"  {name}: present in one only: {keys[:6]}")
        print(f"  {len(changed)} records with quantities present in one only")
        out.add("change/present_in_one_only", records=[n for n, _ in changed])
        if before_leaves:
            diff = {n: [k for k in set(lv) | set(before_leaves.get(n, {}))
                        if lv.get(k, "-") != before_leaves.get(n, {}).get(k, "-")]
                    for n, lv in leaves.items()}
            diff = {n: ks for n, ks in diff.items() if ks}
            n_leaves = sum(len(lv) for lv in leaves.values())
            print(f"every figure of the verdicts ({n_leaves} in {len(leaves)} records): "
                  f"{sum(len(k) for k in diff.values())} differ (not bit for bit) in "
                  f"{len(diff)} records")
            for n, ks in list(diff.items())[:8]:
                print(f"  {n}: {sorted(ks)[:6]}")
            out.add("change/leaves", leaves=n_leaves, differ=sum(len(k) for k in diff.values()),
                    records=sorted(diff))
    out.write()


if __name__ == "__main__":
    main()
