r'''Speed in one run: the ray caster's render figures, the paper campaign first and repeated, memory

SYNOPSIS

    uv run --frozen python benchmarks/speed.py [--cameras 15,1] [--render-repeats 2]
        [--campaign paper] [-j 2] [--repeats 1] [--no-first] [--skip-render]
        [--skip-campaign] [--keep DIR] [--out-dir DIR]

One command for issue 18's bar "benchmarks/ prints the render figures, the
campaign time (first and repeated run) and peak RSS in one run". It measures
nothing itself; it calls the benchmarks that own each figure:

render    per camera (default 15: MER B navcam, 1024x1024 CAHVOR; 1: 5120x3840
          noncentral CAHVORE), the dot target rendered by the ray caster as the
          campaigns render it (area coverage) in a fresh process
          (bench_raycast_area.memory): the first image (cold: its memory is fresh and
          faulted in; later images reuse dropped buffers, renderers.memory.ImagePool),
          the warm seconds per image (median over 6 poses x --render-repeats; wall and
          CPU: with other processes on the cores, wall follows the load and CPU less)
          and the process's peak resident memory during the camera's renders.
campaign  the campaign (default paper, -j 2 local workers; bench_campaign.measure):
          the first run after a kernel change (an empty NUMBA_CACHE_DIR: numba
          compiles every kernel; --no-first leaves it out), then --repeats runs with
          the kernels compiled; per run the wall and CPU seconds, the seconds per
          stage summed over the workers, the numba warm-up before the workers, the
          peak resident memory and CPU seconds of the campaign's process and of each
          worker (sampled from /proc).
load      the load average (1, 5, 15 min) before and after each part: the machine
          is shared, and wall seconds follow its load.

Printed, and written as one JSON document through harness.records
(benchmarks/common.py: benchmarks/results/<UTC stamp>-speed.json). Records a gate
can judge (campaigns/gate-speed.toml): raycast_area/memory/<camera>/area
(seconds.render_per_image: the warm median), campaign/<name>/first,
campaign/<name>/repeat-<i> and campaign/<name>/repeated (seconds.campaign: wall
seconds; the minimum over the repeats), speed/summary. Bars of issue 18: paper
campaign <= 40 s first run and <= 30 s repeated (2 workers), peak RSS per worker
<= 0.8 GiB, 5120x3840 render <= 0.1 s and <= 400 MB.
'''

import os
import sys

import bench_campaign
import bench_raycast_area
import common

SCRIPT = "speed"
BARS = {"campaign_first_s": 40.0, "campaign_repeated_s": 30.0,
        "peak_rss_worker_bytes": 0.8 * 2**30}


def _load():
    return [round(x, 2) for x in os.getloadavg()]


def run(args, out):
    loads = {"start": _load()}
    renders = {}
    if not args.skip_render:
        print(f"render: ray caster, dot target, fresh process per camera; load {loads['start']}",
              flush=True)
        for cam in args.cameras:
            rec = bench_raycast_area.memory(out, cam, args.render_repeats)
            if rec["status"] == "ok":
                rec["seconds"] = {"render_per_image": rec["wall_s"]["median"],
                                  "render_first_image": rec["cold_s"]}
            renders[cam] = rec
        loads["after_render"] = _load()
    campaign = []
    if not args.skip_campaign:
        path = bench_campaign._campaign_path(args.campaign)
        print(f"\ncampaign {path.stem}: {args.jobs} workers; load {_load()}", flush=True)
        campaign = bench_campaign.measure(out, path, args.jobs, first=not args.no_first,
                                          repeats=args.repeats, keep=args.keep)
        loads["after_campaign"] = _load()
    summary(out, renders, campaign, loads)
    return 0


def summary(out, renders, campaign, loads):
    r'''The figures of the bars, side by side, with the load (record speed/summary)'''
    recs = {r["fullname"].rsplit("/", 1)[1]: r for r in campaign if r["status"] == "ok"}
    first, repeat = recs.get("first"), recs.get("repeat-1")
    doc = {"load_average": loads, "bars": BARS}
    print("\n== speed summary (load average 1/5/15 min: "
          + "; ".join(f"{k} {v}" for k, v in loads.items()) + ")")
    for cam, r in renders.items():
        if r["status"] != "ok":
            print(f"  render camera {cam}: {r['status']}: {r['reason']}")
            continue
        print(f"  render camera {cam:>2} {r['size'][0]}x{r['size'][1]}: warm "
              f"{r['wall_s']['median'] * 1e3:.1f} ms median (min {r['wall_s']['min'] * 1e3:.1f}),"
              f" CPU {r['cpu_s']['median'] * 1e3:.1f} ms median, first image "
              f"{r['cold_s'] * 1e3:.0f} ms, peak RSS {r['peak_rss_MB']:.0f} MB")
    def load(r):
        return (f"load {r['load_average_start'][0]:.1f} at the start, "
                f"{r['load_average'][0]:.1f} at the end")
    if first is not None:
        doc["first_s"] = first["wall_s"]
        print(f"  campaign first run     {first['wall_s']:6.1f} s wall (bar <= "
              f"{BARS['campaign_first_s']:.0f} s), {first['seconds']['campaign_cpu']:.1f} CPU s; "
              + load(first))
    for k, r in recs.items():
        if k.startswith("repeat-"):
            print(f"  campaign {k:<13} {r['wall_s']:6.1f} s wall (bar <= "
                  f"{BARS['campaign_repeated_s']:.0f} s), {r['seconds']['campaign_cpu']:.1f} "
                  f"CPU s; " + load(r))
    if repeat is not None:
        doc["repeated_s"] = min(r["wall_s"] for k, r in recs.items() if k.startswith("repeat-"))
    if first is not None and repeat is not None:
        # what the first run pays: the difference of wall and of CPU (all processes)
        cpu = {k: r["seconds"]["campaign_cpu"] for k, r in (("first", first),
                                                             ("repeat", repeat))}
        doc["first_pays_s"] = first["wall_s"] - repeat["wall_s"]
        doc["first_pays_cpu_s"] = cpu["first"] - cpu["repeat"]
        doc["cpu_s"] = cpu
        w = (first.get("warm_up") or {}).get("seconds") or 0.0
        # the campaign's process compiles the renderer's kernels before the workers start
        # (harness.warmup); what the workers pay more is the kernels compiled on first use
        doc["first_pays_cpu_campaign_process_s"] = first["cpu_s"] - repeat["cpu_s"]
        doc["first_pays_cpu_workers_s"] = (doc["first_pays_cpu_s"]
                                           - doc["first_pays_cpu_campaign_process_s"])
        print(f"  the first run pays     {doc['first_pays_s']:6.1f} s wall, "
              f"{doc['first_pays_cpu_s']:.1f} CPU s more (all processes: {cpu['first']:.1f} "
              f"against {cpu['repeat']:.1f}): the campaign's process "
              f"{doc['first_pays_cpu_campaign_process_s']:.1f} CPU s (numba warm-up before the "
              f"workers: {w:.1f} s wall), the workers "
              f"{doc['first_pays_cpu_workers_s']:.1f} CPU s")
    peaks = [p["peak_rss_bytes"] for r in recs.values() for p in r.get("processes", ())
             if p["role"] == "worker"]
    if peaks:
        doc["peak_rss_worker_bytes"] = max(peaks)
        doc["meets_worker_rss"] = bool(max(peaks) <= BARS["peak_rss_worker_bytes"])
        print(f"  peak RSS per worker    {max(peaks) / 2**30:.2f} GiB at most over "
              f"{len(peaks)} workers (bar <= 0.8 GiB: "
              f"{'met' if doc['meets_worker_rss'] else 'NOT met'}); campaign process "
              + ", ".join(f"{r['peak_rss_bytes'] / 2**30:.2f}" for r in recs.values()
                          if "peak_rss_bytes" in r) + " GiB")
    out.add("speed/summary", doc)


def make_parser():
    ap = common.parser(__doc__, repeats=1, warmup=0)
    ap.add_argument("--cameras", type=common.ids, default=["15", "1"],
                    help="catalogue slots rendered for the render figures")
    ap.add_argument("--render-repeats", type=int, default=2,
                    help="warm renders of each of the 6 poses per camera")
    ap.add_argument("--campaign", default="paper", help="campaign name or TOML path")
    ap.add_argument("-j", "--jobs", type=int, default=2, help="local workers")
    ap.add_argument("--no-first", action="store_true",
                    help="leave out the first run (empty numba cache)")
    ap.add_argument("--skip-render", action="store_true")
    ap.add_argument("--skip-campaign", action="store_true")
    ap.add_argument("--keep", metavar="DIR", help="keep the campaign's run directories")
    ap.set_defaults(run=run)
    return ap


if __name__ == "__main__":
    sys.exit(common.main(SCRIPT, make_parser()))
