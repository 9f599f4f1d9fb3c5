r'''The report's tables: one summary per calibrator (and target) beside the paper's numbers,
failures

SYNOPSIS

    from reports.tables import summary_tables, target_tables, failure_rows

    for t in target_tables(records):  # a calibrator's targets side by side (several targets)
        t.title, t.header, t.rows
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

from reference_models.cahvore import FAMILIES

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
    # harness.verdict: floor (exact-observation fit vs truth) + renderer (image fit vs
    # exact-observation fit) side by side with total (the two rows above)
    ("floor: exact-observation fit vs truth, projection RMS, worst",
     ("verdict", "floor", "projection", "rms"), "max", "px", "—"),
    ("renderer: image fit vs exact fit, projection RMS, median",
     ("verdict", "renderer", "projection", "rms"), "median", "px", "—"),
    ("renderer: image fit vs exact fit, projection RMS, worst",
     ("verdict", "renderer", "projection", "rms"), "max", "px", "—"),
    ("renderer: |Hc| difference, worst", ("verdict", "renderer", "params", "Hc"), "absmax",
     "px", "—"),
    ("renderer: |Vc| difference, worst", ("verdict", "renderer", "params", "Vc"), "absmax",
     "px", "—"),
    ("renderer: projection RMS / its sigma, worst",
     ("verdict", "renderer", "z", "projection_rms"), "max", "", "—"),
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
        v = r
        for k in key:
            v = v.get(k) if isinstance(v, dict) else None
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


def render_variant(r):
    r'''The renderer and its settings of a record, as its fullname writes them
(e.g. "raycast[spp=16,adaptive,coverage=area,response=realistic]")'''
    from harness.records import renderer_key
    return renderer_key(r["renderer"], r.get("settings") or {})


def render_variants(records):
    r'''The distinct render variants of a run's records, sorted'''
    return sorted({render_variant(r) for r in records.values()})


def record_variant(records):
    r'''-> a function record -> its variant: what a table or panel never pools

The target (when the run has several: dots and an AprilTag grid have their own
accuracy) then the render variant (when the run has several), joined by ", ";
"" for a run of one target and one render variant.

SYNOPSIS

    variant = record_variant(records)
    variant(r)      # "apriltag, raycast[spp=16,adaptive]", "apriltag", ""
'''
    targets = len({r.get("target") for r in records.values()}) > 1
    renders = len(render_variants(records)) > 1

    def variant(r):
        parts = ([str(r.get("target"))] if targets else []) + (
            [render_variant(r)] if renders else [])
        return ", ".join(parts)
    return variant


def summary_tables(records):
    r'''One Table per calibrator (and named model): paper | CAHV | CAHVOR | CAHVORE

A run with several targets (dots, AprilTag grid, chessboard) or several render variants
(renderers, K, response profiles) gets one table per calibrator and variant
(record_variant: "Calibrator jpl on apriltag"): their statistics are not pooled.'''
    variant = record_variant(records)
    by_cal = {}
    for r in records.values():
        v = variant(r)
        label = _cal_label(r) + (f" on {v}" if v else "")
        by_cal.setdefault(label, []).append(r)
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
        far = sum(1 for r in recs if r["status"] == "ok"
                  and ((r.get("verdict") or {}).get("floor_far")))
        if far:
            note += (f"; {far} ok with a floor far from the truth (the calibrator's own "
                     f"error: see verdict_rows)")
        tables.append(Table(f"Calibrator {cal}", header, tuple(rows), note))
    return tables


# the targets' side-by-side table (target_tables): the renderer's verdict first, then
# what the fits reach against the truth
TARGET_ROWS = (
    ("renderer: image fit vs exact fit, projection RMS, median",
     ("verdict", "renderer", "projection", "rms"), "median", "px"),
    ("renderer: image fit vs exact fit, projection RMS, worst",
     ("verdict", "renderer", "projection", "rms"), "max", "px"),
    ("renderer: its expected scatter (sigma), projection RMS, median",
     ("verdict", "renderer", "sigma", "projection_rms"), "median", "px"),
    ("renderer: projection RMS / its sigma, worst",
     ("verdict", "renderer", "z", "projection_rms"), "max", ""),
    ("detected minus exact positions, RMS, worst", ("verdict", "detection_noise", "rms"),
     "max", "px"),
    ("floor: exact-observation fit vs truth, projection RMS, worst",
     ("verdict", "floor", "projection", "rms"), "max", "px"),
    ("total: projection difference RMS, median", ("projection", "rms"), "median", "px"),
    ("total: projection difference RMS, worst", ("projection", "rms"), "max", "px"),
    ("RMS residual, median", ("residuals", "rms"), "median", "px"),
    ("|Hc| error, worst", ("params", "Hc"), "absmax", "px"),
    ("|Vc| error, worst", ("params", "Vc"), "absmax", "px"),
    ("|theta| error, worst", ("params", "theta_deg"), "absmax", "deg"),
    ("points found per record, median", ("detections", "n_found"), "median", ""),
)


def target_tables(records):
    r'''One Table per calibrator (and render variant) that ran on several targets: its
targets side by side under each model family, the renderer verdict's rows first

SYNOPSIS

    for t in target_tables(records):   # [] for a run of one target
        t.title        # "jpl: dots and apriltag side by side"
        t.header       # ("quantity", "unit", "CAHV dots (20 ok)", "CAHV apriltag (20 ok)", ...)

The same statistics as summary_tables() (TARGET_ROWS: worst values, or medians), over the
ok records of one target and family each.'''
    if len({r.get("target") for r in records.values()}) < 2:
        return []
    renders = len(render_variants(records)) > 1
    groups = {}
    for r in records.values():
        label = _cal_label(r) + (f" on {render_variant(r)}" if renders else "")
        groups.setdefault(label, []).append(r)
    tables = []
    for label in sorted(groups):
        recs = groups[label]
        targets = sorted({r["target"] for r in recs}, key=lambda x: (x != "dots", x))
        if len(targets) < 2:
            continue
        fams = [f for f in FAMILIES if any(r["model"] == f for r in recs)]
        fams += sorted({r["model"] for r in recs} - set(fams))
        # a family a target was not run under ([target_models]) has no column
        cols = [(f, tg) for f in fams for tg in targets
                if any((r["model"], r["target"]) == (f, tg) for r in recs)]
        ok = {c: [r for r in recs if (r["model"], r["target"]) == c and r["status"] == "ok"]
              for c in cols}
        header = ("quantity", "unit") + tuple(f"{f} {tg} ({len(ok[(f, tg)])} ok)"
                                              for f, tg in cols)
        rows = []
        for name, key, how, unit in TARGET_ROWS:
            cells = [_stat(_values(ok[c], key), how) for c in cols]
            if all(c is None for c in cells):
                continue
            rows.append((name, unit) + tuple(_fmt(c) for c in cells))
        counts = []
        for tg in targets:
            n = {}
            for r in recs:
                if r["target"] == tg:
                    n[r["status"]] = n.get(r["status"], 0) + 1
            counts.append(f"{tg}: " + ", ".join(f"{k} {s}" for s, k in sorted(n.items())))
        tables.append(Table(f"{label}: {' and '.join(targets)} side by side", header,
                            tuple(rows), "; ".join(counts)))
    return tables


VERDICT_HEADER = ("record", "floor RMS px", "renderer RMS px", "renderer sigma px",
                  "total RMS px", "floor")


def verdict_rows(records, only_far=False):
    r'''[(fullname, floor, renderer, renderer sigma, total, floor flag)] of the ok records
with a verdict (harness.verdict): the projection-difference RMS of each comparison,
side by side; the flag is the floor's reason in words, or "" (only_far: only those)'''
    rows = []
    for r in records.values():
        v = r.get("verdict") or {}
        if r["status"] != "ok" or not v or (only_far and not v.get("floor_far")):
            continue

        def rms(part, v=v):
            return ((v.get(part) or {}).get("projection") or {}).get("rms")
        sigma = ((v.get("renderer") or {}).get("sigma") or {}).get("projection_rms")
        rows.append((r["fullname"], _fmt(rms("floor")), _fmt(rms("renderer")), _fmt(sigma),
                     _fmt(rms("total")), v.get("floor_reason") or v.get("error") or ""))
    return rows


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
    twins = _twin_cameras(ex.get("twins") or {})
    if twins:
        facts.append(("cameras rendered once for others (identical in their camera frames)",
                      "; ".join(f"{lead} for {', '.join(others)}"
                                for lead, others in twins.items())))
    for kind in ("renderers", "calibrators"):
        if ad.get(kind):
            facts.append((kind, "; ".join(f"{k}: {v}" for k, v in sorted(ad[kind].items()))))
    return facts


def _twin_cameras(twins):
    r'''{leader camera: [twin cameras]} from the run's execution.twins {job key: [keys]}'''
    out = {}
    for key, others in sorted(twins.items()):
        lead = key.split("/", 1)[0]
        for k in others:
            if k not in out.setdefault(lead, []):
                out[lead].append(k)
    return out


# ---------------------------------------------------------------------------------------------
# the paper's Figs. 4-5 signature of the legacy (ROAMS) renderer
def _defect_names(v):
    if not v:
        return set()
    if v is True:
        return {"all"}
    if isinstance(v, str):
        return {v}
    return {str(x) for x in v}


def render_mode(record):
    r'''"legacy" when the record's images were rendered with (Hc, Vc) rounded to the half
pixel (renderer option legacy = true, or a legacy / fault list naming round_centre),
"faulty" for any other injected defect, "clean" otherwise'''
    opts = (record.get("settings") or {}).get("options") or {}
    legacy = _defect_names(opts.get("legacy"))
    fault = _defect_names(opts.get("fault"))
    if "all" in legacy or "round_centre" in legacy or "round_centre" in fault:
        return "legacy"
    return "faulty" if legacy or fault else "clean"


def round_half(x):
    r'''x rounded to the nearest half pixel (renderers.legacy's rule)'''
    return round(2.0 * x) / 2.0


def legacy_signature_rows(records, truth_of):
    r'''The recovered (Hc, Vc) errors of the legacy records and their clean controls

SYNOPSIS

    rows = legacy_signature_rows(records, truth_of)
    # truth_of(camera, family) -> the true model (or None when it cannot be had)
    rows[0]["Hc_error"], rows[0]["Hc_rounding"], rows[0]["Hc_error_vs_rounded"]

One row per ok record that estimates Hc and Vc, for every camera/model/target
that has at least one legacy-mode record (render_mode == "legacy"): the
legacy records and the clean records of the same camera, model and target
(the control). Hc_error = recovered - true (the record's params.Hc);
Hc_rounding = round_half(true Hc) - true Hc, what the legacy renderer moved
the centre by; Hc_error_vs_rounded = recovered - round_half(true Hc) =
Hc_error - Hc_rounding (the paper's Fig. 5). Same for Vc. Returns [] when
the run has no legacy records.
'''
    modes = {k: render_mode(r) for k, r in records.items()}
    groups = {(r["camera"], r["model"], r["target"]) for k, r in records.items()
              if modes[k] == "legacy"}
    rows = []
    for k, r in records.items():
        g = (r["camera"], r["model"], r["target"])
        if g not in groups or modes[k] == "faulty" or r["status"] != "ok":
            continue
        p = r.get("params") or {}
        if p.get("Hc") is None or p.get("Vc") is None:
            continue
        truth = truth_of(r["camera"], r["model"])
        if truth is None:
            continue
        ph = truth.photogrammetric()
        row = {"fullname": r["fullname"], "camera": r["camera"], "model": r["model"],
               "target": r["target"], "mode": modes[k], "calibrator": _cal_label(r),
               "renderer": r["renderer"], "Hc_true": float(ph.Hc), "Vc_true": float(ph.Vc)}
        for name in ("Hc", "Vc"):
            t = row[f"{name}_true"]
            row[f"{name}_rounding"] = round_half(t) - t
            row[f"{name}_error"] = float(p[name])
            row[f"{name}_error_vs_rounded"] = float(p[name]) - row[f"{name}_rounding"]
        rows.append(row)

    def order(row):
        c = row["camera"]
        return ((0, int(c), "") if c.isdigit() else (1, 0, c), row["model"],
                row["calibrator"], row["mode"] != "legacy", row["fullname"])
    return sorted(rows, key=order)


def legacy_signature_table(rows):
    r'''Table of legacy_signature_rows (the figure's numbers) and a one-line verdict note'''
    header = ("camera", "model", "calibrator", "renderer", "true Hc", "true Vc",
              "rounding Hc", "rounding Vc", "error Hc", "error Vc",
              "error vs rounded Hc", "error vs rounded Vc")
    out = []
    for r in rows:
        out.append((r["camera"], r["model"], r["calibrator"],
                    f"{r['mode']} ({r['renderer']})", f"{r['Hc_true']:.4f}",
                    f"{r['Vc_true']:.4f}",
                    *(f"{r[k]:+.4f}" for k in ("Hc_rounding", "Vc_rounding", "Hc_error",
                                                "Vc_error", "Hc_error_vs_rounded",
                                                "Vc_error_vs_rounded"))))
    note = legacy_signature_note(rows)
    return Table("Recovered image centre against the truth and the truth rounded to the half "
                 "pixel (px)", header, tuple(out), note)


def legacy_signature_note(rows):
    r'''One sentence: how close the legacy errors sit to the rounding, and the control'''
    def worst(mode, key):
        v = [abs(r[f"Hc_{key}"]) for r in rows if r["mode"] == mode]
        v += [abs(r[f"Vc_{key}"]) for r in rows if r["mode"] == mode]
        return max(v) if v else None
    n_leg = sum(r["mode"] == "legacy" for r in rows)
    n_clean = sum(r["mode"] == "clean" for r in rows)
    parts = []
    if n_leg:
        parts.append(f"legacy renderer ({n_leg} records): |error| up to "
                     f"{worst('legacy', 'error'):.3f} px against the truth, "
                     f"{worst('legacy', 'error_vs_rounded'):.4f} px against the truth rounded "
                     "to the half pixel")
    if n_clean:
        parts.append(f"clean renderer ({n_clean} records, the control): |error| up to "
                     f"{worst('clean', 'error'):.4f} px against the truth, "
                     f"{worst('clean', 'error_vs_rounded'):.3f} px against the rounded truth")
    return "; ".join(parts) + "." if parts else ""


# ---------------------------------------------------------------------------------------------
# stability sweeps (harness/studies/sweep.py documents)
def _lv(v):
    return f"{v:g}" if isinstance(v, float) else str(v)


def sweep_rows(sweep):
    r'''[(method, breaks at, why, best projection RMS px, at level, lowest detection rate %)]'''
    out = []
    keys = sorted({f"{r['calibrator']}/{r['model']}" for r in sweep["records"]})
    for key in keys:
        recs = [r for r in sweep["records"] if f"{r['calibrator']}/{r['model']}" == key]
        ok = [r for r in recs if r.get("projection_rms_px") is not None]
        best = min(ok, key=lambda r: r["projection_rms_px"]) if ok else None
        rates = [r["detection_rate"] for r in recs if r.get("detection_rate") is not None]
        b = sweep["breakdown"].get(key) or {}
        out.append((key, "never" if b.get("level") is None else _lv(b["level"]),
                    b.get("reason") or "",
                    _fmt(best["projection_rms_px"]) if best else "—",
                    _lv(best["level"]) if best else "—",
                    f"{100 * min(rates):.1f}" if rates else "—"))
    return out


def sweep_level_rows(sweep):
    r'''[(level, method, status, detection %, projection RMS px, residual RMS px, scene)]'''
    out = []
    for lv in sweep["levels"]:
        for r in sweep["records"]:
            if r["level"] != lv:
                continue
            sc = r.get("scene") or {}
            scene = ", ".join(f"{k} {v:.3g}" for k, v in sc.items() if v is not None)
            rate = r.get("detection_rate")
            out.append((_lv(lv), f"{r['calibrator']}/{r['model']}",
                        r["status"] + (" (broken)" if r.get("broken") else ""),
                        "—" if rate is None else f"{100 * rate:.1f}",
                        _fmt(r.get("projection_rms_px")), _fmt(r.get("residual_rms_px")),
                        scene if r["status"] != "not-applicable" else r.get("reason", "")))
    return out


def _detectable_faults():
    r'''(fault, unit) of each minimum detectable fault, in harness.gate.MDF_FAULTS' order (its
one home: a fault added there gets its column here)'''
    from harness.gate import MDF_FAULTS
    return tuple((fault, unit) for fault, _, unit in MDF_FAULTS)


# a fault's column: its name and unit ("Hc shift px"; a fraction has none)
_UNIT_LABEL = {"px": " px", "deg": " deg", "fractional": ""}
# ("camera", "Hc shift px", "Vc shift px", "focal scale", "theta change deg", "R1 scale",
# "roll about A deg")
DETECTABLE_HEADER = ("camera",) + tuple(f"{fault}{_UNIT_LABEL.get(unit, ' ' + unit)}"
                                        for fault, unit in _detectable_faults())


def detectable_fault_rows(doc):
    r'''[(camera, Hc, Vc, focal scale, theta, R1 scale, roll about A)]: run.json's minimum
detectable faults (harness.gate.minimum_detectable_faults under the renderer gate), one
column per fault of DETECTABLE_HEADER, "—" where not judged'''
    cams = ((doc.get("minimum_detectable_faults") or {}).get("cameras") or {})
    faults = tuple(fault for fault, _ in _detectable_faults())
    def order(cam):     # catalogue slots by number, then extras and files by name
        return (0, int(cam), "") if str(cam).isdigit() else (1, 0, str(cam))
    return [(cam,) + tuple(_fmt((cams[cam].get(k) or {}).get("value")) for k in faults)
            for cam in sorted(cams, key=order)]
