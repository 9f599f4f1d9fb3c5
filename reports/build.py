r'''Write a run's report: one self-contained HTML page, Markdown, PNG figures

SYNOPSIS

    from reports.build import build_report

    paths = build_report("runs/20261122T150000Z")
    paths["html"], paths["markdown"], paths["figures"]   # in RUN_DIR/report/

The HTML page embeds every figure as a base64 data URI, so the one file can be
mailed or archived; the Markdown links the PNGs in figures/ (relative paths).
Both hold the run's facts (campaign, commit, machine, adapters), one summary
table per calibrator beside the paper's numbers, the figures, and every
failed record with its stage and reason. Existing report files of the run are
replaced (they are derived data; the run document is never touched).

Two sections appear when the run has their data:

- Legacy signature (paper Figs. 4-5): when records were rendered in legacy
  mode (renderer option legacy = true, e.g. campaigns/legacy.toml), the
  recovered (Hc, Vc) error against the truth and against the truth rounded to
  the half pixel, per camera, with the clean records of the same cameras as
  the control, and the numbers in a table. The truths come from the
  catalogue (the campaign's overlay if it named one).
- Stability sweeps: sweep documents of `camval sweep` (sweep_*.json) found in
  the run directory or its sweeps/ folder: one stability chart per sweep with
  each method's breakdown marked, and the breakdown table.

    paths = build_sweep_report("out/")   # camval sweep's own page: the sweeps alone
'''

import base64
import html
import json
from pathlib import Path

from harness.records import load_run, write_atomic
from reference_models.errors import CamvalError

from .figures import fig_legacy_signature, fig_sweeps, make_figures
from .tables import (
    DETECTABLE_HEADER,
    VERDICT_HEADER,
    detectable_fault_rows,
    failure_rows,
    legacy_signature_rows,
    legacy_signature_table,
    run_facts,
    summary_tables,
    sweep_level_rows,
    sweep_rows,
    target_tables,
)
from .tables import verdict_rows as tables_verdict_rows


class ReportError(CamvalError):
    '''A report that cannot be written from what was given (no run, no sweeps).'''


SWEEP_HEADER = ("method", "breaks at", "why", "best projection RMS (px)", "at level",
                "lowest detection rate (%)")
SWEEP_LEVEL_HEADER = ("level", "method", "status", "detection (%)", "projection RMS (px)",
                      "residual RMS (px)", "scene (mean range m, mean tilt deg, median dot px) "
                      "or why not run")

CSS = """
body { font-family: system-ui, sans-serif; max-width: 1200px; margin: 1em auto; padding: 0 1em;
       color: #222; }
table { border-collapse: collapse; margin: 0.5em 0 1.2em; font-size: 0.85em; }
th, td { border: 1px solid #ccc; padding: 0.2em 0.5em; text-align: left; vertical-align: top; }
th { background: #f0f0f0; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
figure { margin: 1em 0 2em; }
figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: 0.85em; color: #444; }
.status-failed { color: #a00; }
.verdict { font-size: 1.2em; padding: 0.4em 0.6em; border-radius: 4px; }
.verdict-pass { background: #e4f4e4; } .verdict-fail { background: #fbe3e3; }
.verdict-none { background: #eee; }
"""
# gate failures listed under the verdict (all of them are in `camval gate`'s output)
VERDICT_ROWS = 20

# Marks the page once every image has decoded (a headless browser test reads it).
IMAGE_CHECK = """
window.addEventListener("load", function () {
  var imgs = Array.prototype.slice.call(document.images);
  var ok = imgs.filter(function (i) { return i.complete && i.naturalWidth > 0; }).length;
  document.body.setAttribute("data-images-total", String(imgs.length));
  document.body.setAttribute("data-images-loaded", String(ok));
});
"""


def _e(s):
    return html.escape(str(s), quote=True)


def _is_num(s):
    try:
        float(s)
        return True
    except ValueError:
        return False


def _html_table(header, rows):
    out = ["<table>"]
    if any(header):
        out.append("<tr>" + "".join(f"<th>{_e(h)}</th>" for h in header) + "</tr>")
    for row in rows:
        out.append("<tr>" + "".join(
            f"<td class=\"num\">{_e(c)}</td>" if _is_num(c) else f"<td>{_e(c)}</td>"
            for c in row) + "</tr>")
    out.append("</table>")
    return "\n".join(out)


def _md_cell(s):
    return str(s).replace("|", "\\|").replace("\n", " ")


def _md_table(header, rows):
    out = ["| " + " | ".join(_md_cell(h) for h in header) + " |",
           "|" + "|".join("---" for _ in header) + "|"]
    out += ["| " + " | ".join(_md_cell(c) for c in row) + " |" for row in rows]
    return "\n".join(out)


def _html_figure(f):
    data = base64.b64encode(Path(f.path).read_bytes()).decode("ascii")
    return (f"<figure id=\"{_e(f.key)}\"><h3>{_e(f.title)}</h3>"
            f"<img alt=\"{_e(f.title)}\" src=\"data:image/png;base64,{data}\">"
            f"<figcaption>{_e(f.caption)}</figcaption></figure>")


def _md_figure(f, out):
    rel = Path(f.path).relative_to(out)
    alt = f.title.replace("[", "(").replace("]", ")")   # brackets would end the alt text
    return [f"### {f.title}", "", f"![{alt}]({rel.as_posix()})", "", f.caption, ""]


def is_sweep(doc):
    r'''Whether a JSON document is a harness.studies.sweep.run_sweep result'''
    return (isinstance(doc, dict) and isinstance(doc.get("records"), list)
            and isinstance(doc.get("breakdown"), dict) and "difficulty" in doc
            and "levels" in doc)


def find_sweeps(directory):
    r'''[sweep document] from DIR/sweep_*.json and DIR/sweeps/**/sweep_*.json, in the order
of harness.studies.sweep.DIFFICULTIES'''
    d = Path(directory)
    paths = sorted(set(d.glob("sweep_*.json")) | set(d.glob("sweeps/**/sweep_*.json")))
    out = []
    for p in paths:
        try:
            doc = json.loads(p.read_text())
        except (OSError, ValueError):
            continue     # not ours or half written: the report is about the run
        if is_sweep(doc):
            doc["_path"] = str(p.relative_to(d))
            out.append(doc)
    from harness.studies.sweep import DIFFICULTIES
    order = {k: i for i, k in enumerate(DIFFICULTIES)}
    return sorted(out, key=lambda sw: (order.get(sw["difficulty"], len(order)), sw["_path"]))


def truth_resolver(doc, run_dir):
    r'''truth_of(camera, family) -> the true model of a run's camera, or None'''
    from reference_models.cahvore import truncate
    from reference_models.catalogue import load_catalogue
    from reference_models.errors import CamvalError
    overlay = (doc.get("campaign") or {}).get("catalogue")
    cache = {}

    def catalogue():
        if "cat" not in cache:
            cat = None
            if overlay:
                for base in (Path(run_dir), Path.cwd()):
                    try:
                        cat = load_catalogue(overlay=str(base / overlay))
                        break
                    except (CamvalError, OSError):
                        continue
            cache["cat"] = cat or load_catalogue()
        return cache["cat"]

    def truth_of(camera, family):
        key = (camera, family)
        if key not in cache:
            try:
                cache[key] = truncate(catalogue().get(camera).model, family)
            except (CamvalError, ValueError):
                cache[key] = None
        return cache[key]
    return truth_of


def _sweep_sections(sweeps, figs, out):
    r'''(html lines, markdown lines) of the stability-sweep section'''
    h = ["<h2 id=\"sweeps\">Stability sweeps</h2>",
         "<p>One difficulty varied at a time (harness/studies/sweep.py), everything else fixed. A "
         "method breaks at the first level where the target is not found in every point of "
         "every image, the calibration fails, or the projection difference exceeds the "
         "bar.</p>"]
    m = ["## Stability sweeps", "",
         "One difficulty varied at a time (harness/studies/sweep.py), everything else fixed. "
         "A method breaks at the first level where the target is not found in every point of "
         "every image, the calibration fails, or the projection difference exceeds the bar.",
         ""]
    for sw, f in zip(sweeps, figs, strict=True):
        h.append(_html_figure(f))
        h.append(_html_table(SWEEP_HEADER, sweep_rows(sw)))
        h.append(f"<details><summary>every level ({len(sw['records'])} records, "
                 f"{sw.get('seconds', 0):.0f} s)</summary>")
        h.append(_html_table(SWEEP_LEVEL_HEADER, sweep_level_rows(sw)))
        h.append("</details>")
        m += _md_figure(f, out)
        m += [_md_table(SWEEP_HEADER, sweep_rows(sw)), ""]
    return h, m


def _page_head(title):
    return ["<!DOCTYPE html>", "<html lang=\"en\"><head><meta charset=\"utf-8\">",
            f"<title>{_e(title)}</title>", f"<style>{CSS}</style>",
            f"<script>{IMAGE_CHECK}</script>", "</head><body>", f"<h1>{_e(title)}</h1>"]


# the report's verdict when none is given: the renderer gate (campaigns/gate-renderer.toml)
DEFAULT_GATE_SPEC = Path(__file__).resolve().parents[1] / "campaigns" / "gate-renderer.toml"


def verdict(doc, gate_spec=None):
    r'''The gate's result for a run in one line, and its failures

SYNOPSIS

    line, failures = verdict(doc)            # against campaigns/gate-renderer.toml
    # "PASS: ..." | "FAIL: 3 failures ..." | "no verdict: ..."; failures [(name, field,
    # value, limit)]

gate_spec: a path, a parsed harness.gate spec, or None (the default gate spec if the
source tree has it). A spec needing a baseline, or none at all: "no verdict" and why.
'''
    from harness.gate import GateUsageError, check, load_gate_spec
    if gate_spec is None:
        gate_spec = DEFAULT_GATE_SPEC if DEFAULT_GATE_SPEC.is_file() else None
    if gate_spec is None:
        return "no verdict: no gate spec", []
    about = ""
    try:
        if isinstance(gate_spec, str | Path):
            import tomllib
            about = tomllib.loads(Path(gate_spec).read_text()).get("description", "")
            spec = load_gate_spec(gate_spec)
        else:
            spec = gate_spec
        failures = check(doc, spec)
    except GateUsageError as e:
        return f"no verdict: {e}", []
    src = Path(spec.source).name if spec.source else "the gate spec"
    src += f" ({about})" if about else ""
    n = len(doc["records"])
    caused = any(f.cause for f in failures)
    # a failure whose record names its cause (images that bloom: harness.gate.record_cause)
    # carries it in a fifth column
    rows = [(f.fullname, f.field, f.value, f.limit) + ((f.cause,) if caused else ())
            for f in failures]
    if not failures:
        return f"PASS: no failure in the {n} records against {src}", rows
    names = len({f.fullname for f in failures})
    why = len({f.fullname for f in failures if f.cause})
    because = (f"; {why} of these records name the cause: their images are saturated and "
               f"bloom along the columns, which moves the detections, not the renderer's "
               f"geometry" if why else "")
    return (f"FAIL: {len(failures)} failure{'s' if len(failures) != 1 else ''} in {names} "
            f"of {n} records against {src}{because}"), rows


def failure_header(rows):
    r'''The header of verdict()'s failure rows (a "cause" column where they have one)'''
    base = ("fullname", "field", "value", "limit")
    return base + ("cause",) if rows and len(rows[0]) == 5 else base


def failure_causes(rows):
    r'''[(fullname, cause)] of verdict()'s failure rows, once per record that names one'''
    out = {}
    for r in rows:
        if len(r) == 5 and r[4]:
            out.setdefault(r[0], r[4])
    return list(out.items())


VERDICT_NOTE = ("Each ok record fits the exact observations of its poses too (the positions a "
                "perfect renderer and detector give). floor = that exact fit against the "
                "truth: what the calibrator and model can do at all; renderer = the image "
                "fit against the exact fit: what the images cost, the renderer's verdict, "
                "beside its expected scatter (sigma); total = the image fit against the "
                "truth. Projection-difference RMS in px. A flag says why a floor is far "
                "from the truth.")
TARGETS_NOTE = ("Each calibrator that fitted several targets, its targets side by side under "
                "each model family: the renderer verdict first (image fit vs the fit of the "
                "exact observations: exact dot centroids; for corner targets the corners the "
                "detector finds on the reference render, so a job rendered by the reference "
                "render itself has a renderer difference of 0), then the fits against the "
                "truth. The figure 'Targets side by side' plots them per camera.")
DETECTABLE_NOTE = ("The smallest fault of each kind the renderer gate would flag on each "
                   "camera, from the expected scatter of its records (the smallest over "
                   "them): an Hc/Vc shift in px, a focal scale and an R1 scale as fractions, a "
                   "theta change in deg, and a roll of the image axes about A in deg (the "
                   "turn of H' about A; judged on jpl's world-frame fits, whose board poses "
                   "are surveyed: a calibrator that fits the poses takes a roll into them).")


def build_report(run, out_dir=None, gate_spec=None, workers=None):
    r'''Write report.html, report.md and figures/*.png for a run -> {"html", "markdown", ...}

gate_spec: the gate whose result opens the report (see verdict()). workers: processes
drawing the figures (reports.figures.make_figures; default 1: figure_workers says why).
'''
    run = Path(run)
    run_dir = run if run.is_dir() else run.parent
    doc = load_run(run)
    records = doc["records"]
    out = Path(out_dir) if out_dir else run_dir / "report"
    fig_dir = out / "figures"
    figs = make_figures(records, run_dir, fig_dir, workers=workers)
    legacy_rows = legacy_signature_rows(records, truth_resolver(doc, run_dir))
    legacy_fig = fig_legacy_signature(legacy_rows, fig_dir) if legacy_rows else None
    sweeps = find_sweeps(run_dir)
    sweep_figs = fig_sweeps(sweeps, fig_dir) if sweeps else []
    tables = summary_tables(records)
    by_target = target_tables(records)
    failures = failure_rows(records)
    not_app = failure_rows(records, statuses=("not-applicable",))
    facts = run_facts(doc)
    name = (doc.get("campaign") or {}).get("name", "run")
    title = f"camval verification report: {name}"

    verdict_line, verdict_rows = verdict(doc, gate_spec)
    vrows = tables_verdict_rows(records)
    detectable = detectable_fault_rows(doc)
    vclass = {"P": "pass", "F": "fail"}.get(verdict_line[0], "none")

    # --- HTML -------------------------------------------------------------------------
    h = _page_head(title)
    h.append(f"<p class=\"verdict verdict-{vclass}\" id=\"verdict\"><b>Verdict</b> "
             f"{_e(verdict_line)}</p>")
    if verdict_rows:
        shown = verdict_rows[:VERDICT_ROWS]
        more = (f" (first {VERDICT_ROWS} of {len(verdict_rows)})"
                if len(verdict_rows) > VERDICT_ROWS else "")
        causes = failure_causes(verdict_rows)
        if causes:
            h.append("<ul class=\"causes\">" + "".join(
                f"<li>{_e(name)}: {_e(cause)}</li>" for name, cause in causes) + "</ul>")
        h.append(f"<details><summary>gate failures{more}</summary>" +
                 _html_table(failure_header(verdict_rows), shown) + "</details>")
    h.append(_html_table(("", ""), facts))
    sections = ([("targets", "Targets side by side")] if by_target else []) + [
                ("detectable", "Minimum detectable faults"),
                ("renderer-verdict", "Renderer verdict per record"),
                ("summary", "Summary per calibrator"), ("figures", "Figures")]
    if legacy_fig:
        sections.append(("legacy", "Legacy signature (paper Figs. 4-5)"))
    if sweep_figs:
        sections.append(("sweeps", "Stability sweeps"))
    sections += [("failures", "Failures"), ("not-applicable", "Not applicable")]
    h.append("<p>" + " | ".join(f"<a href=\"#{k}\">{_e(t)}</a>" for k, t in sections) +
             "</p>")
    if by_target:
        h.append("<h2 id=\"targets\">Targets side by side</h2>")
        h.append(f"<p>{_e(TARGETS_NOTE)}</p>")
        for t in by_target:
            h.append(f"<h3>{_e(t.title)}</h3><p>{_e(t.note)}</p>")
            h.append(_html_table(t.header, t.rows))
    h.append("<h2 id=\"detectable\">Minimum detectable faults</h2>")
    h.append(f"<p>{_e(DETECTABLE_NOTE)}</p>")
    h.append(_html_table(DETECTABLE_HEADER, detectable) if detectable else "<p>None judged.</p>")
    h.append("<h2 id=\"renderer-verdict\">Renderer verdict per record</h2>")
    h.append(f"<p>{_e(VERDICT_NOTE)}</p>")
    h.append(_html_table(VERDICT_HEADER, vrows) if vrows else "<p>No record has a verdict.</p>")
    h.append("<h2 id=\"summary\">Summary per calibrator, beside the paper</h2>")
    h.append("<p>Statistics over each calibrator's successful records, per model family the "
             "images were rendered with. The paper's column is what ROAMS achieved "
             "(Camera Response Simulation for Planetary Exploration, Figs. 3-11).</p>")
    for t in tables:
        h.append(f"<h3>{_e(t.title)}</h3><p>{_e(t.note)}</p>")
        h.append(_html_table(t.header, t.rows))
    h.append("<h2 id=\"figures\">Figures</h2>")
    if figs:
        h.append("<ul>" + "".join(f"<li><a href=\"#{_e(f.key)}\">{_e(f.title)}</a></li>"
                                  for f in figs) + "</ul>")
    for f in figs:
        h.append(_html_figure(f))
    legacy_table = legacy_signature_table(legacy_rows) if legacy_fig else None
    if legacy_fig:
        h.append("<h2 id=\"legacy\">Legacy signature (paper Figs. 4-5)</h2>")
        h.append(f"<p>{_e(legacy_table.note)}</p>")
        h.append(_html_figure(legacy_fig))
        h.append(f"<h3>{_e(legacy_table.title)}</h3>")
        h.append(_html_table(legacy_table.header, legacy_table.rows))
    sweep_m = []
    if sweep_figs:
        sweep_h, sweep_m = _sweep_sections(sweeps, sweep_figs, out)
        h += sweep_h
    h.append(f"<h2 id=\"failures\">Failures ({len(failures)})</h2>")
    h.append(_html_table(("fullname", "status", "stage", "reason"), failures)
             if failures else "<p>None.</p>")
    h.append(f"<h2 id=\"not-applicable\">Not applicable ({len(not_app)})</h2>")
    h.append(_html_table(("fullname", "status", "stage", "reason"), not_app)
             if not_app else "<p>None.</p>")
    h.append("</body></html>")
    html_path = out / "report.html"
    write_atomic(html_path, "\n".join(h) + "\n")

    # --- Markdown -----------------------------------------------------------------------
    m = [f"# {title}", "", f"**Verdict** {verdict_line}", ""]
    if verdict_rows:
        m += [f"- {name}: {cause}" for name, cause in failure_causes(verdict_rows)]
        m += ["", _md_table(failure_header(verdict_rows), verdict_rows[:VERDICT_ROWS]), ""]
    m += [_md_table(("run", ""), facts), ""]
    if by_target:
        m += ["## Targets side by side", "", TARGETS_NOTE, ""]
        for t in by_target:
            m += [f"### {t.title}", "", t.note, "", _md_table(t.header, t.rows), ""]
    m += ["## Minimum detectable faults", "", DETECTABLE_NOTE, "",
          _md_table(DETECTABLE_HEADER, detectable) if detectable else "None judged.", "",
          "## Renderer verdict per record", "", VERDICT_NOTE, "",
          _md_table(VERDICT_HEADER, vrows) if vrows else "No record has a verdict.", "",
          "## Summary per calibrator, beside the paper", ""]
    for t in tables:
        m += [f"### {t.title}", "", t.note, "", _md_table(t.header, t.rows), ""]
    m += ["## Figures", ""]
    for f in figs:
        m += _md_figure(f, out)
    if legacy_fig:
        m += ["## Legacy signature (paper Figs. 4-5)", "", legacy_table.note, ""]
        m += _md_figure(legacy_fig, out)
        m += [f"### {legacy_table.title}", "",
              _md_table(legacy_table.header, legacy_table.rows), ""]
    m += sweep_m
    m += [f"## Failures ({len(failures)})", ""]
    m += [_md_table(("fullname", "status", "stage", "reason"), failures) if failures
          else "None.", ""]
    m += [f"## Not applicable ({len(not_app)})", ""]
    m += [_md_table(("fullname", "status", "stage", "reason"), not_app) if not_app
          else "None.", ""]
    md_path = out / "report.md"
    write_atomic(md_path, "\n".join(m))
    all_figs = figs + ([legacy_fig] if legacy_fig else []) + sweep_figs
    return {"html": str(html_path), "markdown": str(md_path), "figures_dir": str(fig_dir),
            "figures": [f.path for f in all_figs], "verdict": verdict_line,
            "legacy_rows": legacy_rows, "sweeps": [sw["_path"] for sw in sweeps]}


def build_sweep_report(sweep_dir, out_dir=None):
    r'''The stability sweeps of a directory on their own page

SYNOPSIS

    paths = build_sweep_report("out/")     # reads out/sweep_*.json (and out/sweeps/)
    paths["html"], paths["markdown"], paths["figures"]

Writes OUT/sweep_report.html (figures embedded), OUT/sweep_report.md and one
stability chart per sweep in OUT/sweep_figures/ (OUT defaults to sweep_dir).
Raises ReportError when the directory holds no sweep document.
'''
    sweep_dir = Path(sweep_dir)
    sweeps = find_sweeps(sweep_dir)
    if not sweeps:
        raise ReportError(f"'{sweep_dir}' holds no sweep document (sweep_*.json written by "
                          "camval sweep)")
    out = Path(out_dir) if out_dir else sweep_dir
    fig_dir = out / "sweep_figures"
    fig_dir.mkdir(parents=True, exist_ok=True)
    figs = fig_sweeps(sweeps, fig_dir)
    title = "camval stability sweeps"
    facts = [(sw["_path"], f"{sw['difficulty']}: {len(sw['levels'])} levels, "
                           f"{len(sw['records'])} records, {sw.get('seconds', 0):.0f} s")
             for sw in sweeps]
    sweep_h, sweep_m = _sweep_sections(sweeps, figs, out)
    h = _page_head(title) + [_html_table(("sweep", ""), facts)] + sweep_h
    h.append("</body></html>")
    html_path = out / "sweep_report.html"
    write_atomic(html_path, "\n".join(h) + "\n")
    m = [f"# {title}", "", _md_table(("sweep", ""), facts), ""] + sweep_m
    md_path = out / "sweep_report.md"
    write_atomic(md_path, "\n".join(m))
    return {"html": str(html_path), "markdown": str(md_path), "figures_dir": str(fig_dir),
            "figures": [f.path for f in figs]}
