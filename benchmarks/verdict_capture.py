r'''Capture the verdict's inputs of a campaign's records, for bench_verdict.py

SYNOPSIS

    uv run --frozen python benchmarks/verdict_capture.py campaigns/quick.toml OUT.pkl \
        [--cameras 1,21]

Runs the campaign's jobs in this process (no run directory, no report) and keeps,
for every ok record, what harness.verdict.assess() was handed (truth, the image
fit, the exact fit, the noise, the record's figures, the observations), pickled
to OUT.pkl as a list of (fullname, args, kwargs). bench_verdict.py replays them:
the same inputs for the verdict before and after a change.
'''

import argparse
import pickle
import sys


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("campaign")
    ap.add_argument("out")
    ap.add_argument("--cameras", default="", help="comma-separated catalogue numbers")
    a = ap.parse_args(argv)
    from harness import verdict as vd
    from harness.campaign import load_campaign
    from harness.jobs import expand_jobs, group_twins
    from harness.runner import run_job

    campaign = load_campaign(a.campaign)
    if a.cameras:
        import dataclasses
        campaign = dataclasses.replace(campaign, cameras=tuple(a.cameras.split(",")))
    entries = campaign.validate()
    jobs = expand_jobs(campaign, entries=entries)
    if campaign.share_identical_cameras:
        jobs = group_twins(jobs)
    captured = []
    orig = vd.assess

    def capture(*args, **kw):
        captured.append((args, kw))
        return orig(*args, **kw)
    vd.assess = capture
    out = []
    for job in jobs:
        n0 = len(captured)
        recs = run_job(job)["records"]
        # a twin's record of a shared fit takes the verdict computed for the first camera
        # (harness.job_records: info.shared.stages names "verdict"): no assess() call
        ok = [r for r in recs if r["status"] == "ok" and isinstance(r.get("verdict"), dict)
              and "error" not in r["verdict"]
              and "verdict" not in ((r.get("info") or {}).get("shared") or {}).get("stages", ())]
        new = captured[n0:]
        if len(ok) != len(new):     # records and captures pair up only one to one
            print(f"{job.key}: {len(ok)} ok records, {len(new)} verdicts; skipped",
                  file=sys.stderr)
            continue
        for r, (args, kw) in zip(ok, new, strict=True):
            out.append((r["fullname"], args, kw))
        print(f"{job.key}: {len(new)} captured", file=sys.stderr)
    with open(a.out, "wb") as f:
        pickle.dump(out, f)
    print(f"{len(out)} verdict inputs -> {a.out}")


if __name__ == "__main__":
    main()
