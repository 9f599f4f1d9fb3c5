r'''The report's tables: one summary per calibrator beside the paper's numbers, failures

SYNOPSIS

    from reports.tables import summary_tables, failure_rows

    for t in summary_tables(records):
        t.title, t.header, t.rows     # rows of strings
    failure_rows(records)             # [(fullname, status, stage, reason), ...]

Each summary row is a statistic over the calibrator's ok records of one model
family (the worst value, or the median where the paper quotes a typical
value), next to what the paper reported for ROAMS (Pomerantz et al.). The
paper's numbers are for its renderer and calibrator; ours are exact ray
casting and our calibrators, so they should be far smaller.
'''

import math
from dataclasses import dataclass

import numpy as np

FAMILIES = ("CAHV", "CAHVOR", "CAHVORE")

# (label, getter key, statistic, unit, paper's figure)
SUMMARY_ROWS = (
    ("RMS residual, median", ("residuals", "rms"), "median", "px", "about 1/30 = 0.033"),
    ("worst residual", ("residuals", "max"), "max", "px", "0.14"),
    ("|Hc| error, worst", ("params", "Hc"), "absmax", "px", "up to 0.5"),
    ("|Vc| error, worst", ("params", "Vc"), "absmax", "px", "up to 0.5"),
    ("|Hs| fractional error, worst", ("params", "Hs"), "absmax", "", "—"),
    ("|Vs| fractional error, worst", ("params", "Vs"), "absmax", "",
     "0.0004 (CAHVOR, not 13-16)"),
    ("|Hs(1+R0)| fractional error, worst", ("params", "Hs*(1+R0)"), "absmax", "", "—"),
    ("|theta| error, worst", ("params", "theta_deg"), "absmax", "deg",
     "0.17 (CAHV), 0.002 (CAHVOR)"),
    ("C error, worst", ("params", "C_mm"), "absmax", "mm", "< 0.06 (CAHV)"),
    ("A error, worst", ("params", "A_deg"), "absmax", "deg", "0.005 (CAHV)"),
    ("O error, worst", ("params", "O_deg"), "absmax", "deg", "within 0.1 (not 13-16)"),
    ("|R1| fractional error, worst", ("params", "R1_frac"), "absmax", "",
     "well below 0.01 (not 13-16)"),
    ("|R2| fractional error, worst", ("params", "R2_frac"), "absmax", "",
     "well below 0.01 (not 13-16)"),
    ("projection difference RMS, median", ("projection", "rms"), "median", "px", "—"),
    ("projection difference, worst", ("projection", "max"), "max", "px", "—"),
)


@dataclass(frozen=True)
class Table:
    title: str
    header: tuple
    rows: tuple
    note: str = ""


def _fmt(v):
    if v is None:
        return "—"
    if isinstance(v, str):
        return v
    if v == 0:
        return "0"
    a = abs(v)
    if a >= 1e4 or a < 1e-3:
        return f"{v:.2e}"
    return f"{v:.4g}"


def _values(recs, key):
    out = []
    for r in recs:
        v = (r.get(key[0]) or {}).get(key[1])
        if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v):
            out.append(float(v))
    return out


def _stat(vals, how):
    if not vals:
        return None
    a = np.asarray(vals)
    if how == "median":
        return float(np.median(a))
    if how == "max":
        return float(a.max())
    return float(np.abs(a).max())


def _cal_label(r):
    m = r["calibrator_model"]
    return r["calibrator"] if m == r["model"] else f"{r['calibrator']}[{m}]"


def summary_tables(records):
    r'''One Table per calibrator (and named model): paper | CAHV | CAHVOR | CAHVORE'''
    by_cal = {}
    for r in records.values():
        by_cal.setdefault(_cal_label(r), []).append(r)
    tables = []
    for cal in sorted(by_cal):
        recs = by_cal[cal]
        fams = [f for f in FAMILIES if any(r["model"] == f for r in recs)]
        fams += sorted({r["model"] for r in recs} - set(fams))
        ok = {f: [r for r in recs if r["model"] == f and r["status"] == "ok"] for f in fams}
        header = ("quantity", "unit", "paper (ROAMS)") + tuple(
            f"{f} ({len(ok[f])} ok)" for f in fams)
        rows = []
        for label, key, how, unit, paper in SUMMARY_ROWS:
            cells = [_stat(_values(ok[f], key), how) for f in fams]
            if all(c is None for c in cells):
                continue   # not estimated by this calibrator at all
            rows.append((label, unit, paper) + tuple(_fmt(c) for c in cells))
        counts = {}
        for r in recs:
            counts[r["status"]] = counts.get(r["status"], 0) + 1
        note = ", ".join(f"{n} {s}" for s, n in sorted(counts.items()))
        tables.append(Table(f"Calibrator {cal}", header, tuple(rows), note))
    return tables


def failure_rows(records, statuses=("failed",)):
    r'''[(fullname, status, stage, reason)] of the records with these statuses'''
    return [(r["fullname"], r["status"], r.get("stage") or "", r.get("reason") or "")
            for r in records.values() if r["status"] in statuses]


def run_facts(doc):
    r'''[(label, value)] describing the run: when, what, where'''
    src = doc.get("source") or {}
    mach = doc.get("machine") or {}
    ex = doc.get("execution") or {}
    camp = doc.get("campaign") or {}
    ad = doc.get("adapters") or {}
    recs = doc["records"]
    counts = {}
    for r in recs.values():
        counts[r["status"]] = counts.get(r["status"], 0) + 1
    facts = [
        ("campaign", f"{camp.get('name', '?')} ({camp.get('source', '')})"),
        ("created (UTC)", str(doc.get("created"))),
        ("commit", f"{src.get('commit')}" + (" (modified tree)" if src.get("dirty") else "")),
        ("machine", f"{mach.get('hostname')}, {mach.get('machine')}, {mach.get('cpus')} cpus, "
                    f"Python {mach.get('python')}"),
        ("records", f"{len(recs)}: " + ", ".join(f"{n} {s}" for s, n in sorted(counts.items()))),
    ]
    if ex:
        facts.append(("execution", f"{ex.get('executor')} executor, {ex.get('jobs')} jobs "
                                   f"({ex.get('jobs_run')} in the last session), "
                                   f"{ex.get('wall_seconds', 0):.1f} s wall"))
    for kind in ("renderers", "calibrators"):
        if ad.get(kind):
            facts.append((kind, "; ".join(f"{k}: {v}" for k, v in sorted(ad[kind].items()))))
    return facts
