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
'''

import base64
import html
from pathlib import Path

from harness.records import load_run, write_atomic

from .figures import make_figures
from .tables import failure_rows, run_facts, summary_tables

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
"""

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


def build_report(run, out_dir=None):
    r'''Write report.html, report.md and figures/*.png for a run -> {"html", "markdown", ...}'''
    run = Path(run)
    run_dir = run if run.is_dir() else run.parent
    doc = load_run(run)
    records = doc["records"]
    out = Path(out_dir) if out_dir else run_dir / "report"
    fig_dir = out / "figures"
    figs = make_figures(records, run_dir, fig_dir)
    tables = summary_tables(records)
    failures = failure_rows(records)
    not_app = failure_rows(records, statuses=("not-applicable",))
    facts = run_facts(doc)
    name = (doc.get("campaign") or {}).get("name", "run")
    title = f"camval verification report: {name}"

    # --- HTML -------------------------------------------------------------------------
    h = ["<!DOCTYPE html>", "<html lang=\"en\"><head><meta charset=\"utf-8\">",
         f"<title>{_e(title)}</title>", f"<style>{CSS}</style>",
         f"<script>{IMAGE_CHECK}</script>", "</head><body>", f"<h1>{_e(title)}</h1>",
         _html_table(("", ""), facts)]
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
        data = base64.b64encode(Path(f.path).read_bytes()).decode("ascii")
        h.append(f"<figure id=\"{_e(f.key)}\"><h3>{_e(f.title)}</h3>"
                 f"<img alt=\"{_e(f.title)}\" src=\"data:image/png;base64,{data}\">"
                 f"<figcaption>{_e(f.caption)}</figcaption></figure>")
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
    m = [f"# {title}", "", _md_table(("run", ""), facts), "",
         "## Summary per calibrator, beside the paper", ""]
    for t in tables:
        m += [f"### {t.title}", "", t.note, "", _md_table(t.header, t.rows), ""]
    m += ["## Figures", ""]
    for f in figs:
        rel = Path(f.path).relative_to(out)
        m += [f"### {f.title}", "", f"![{f.title}]({rel.as_posix()})", "", f.caption, ""]
    m += [f"## Failures ({len(failures)})", ""]
    m += [_md_table(("fullname", "status", "stage", "reason"), failures) if failures
          else "None.", ""]
    m += [f"## Not applicable ({len(not_app)})", ""]
    m += [_md_table(("fullname", "status", "stage", "reason"), not_app) if not_app
          else "None.", ""]
    md_path = out / "report.md"
    write_atomic(md_path, "\n".join(m))
    return {"html": str(html_path), "markdown": str(md_path), "figures_dir": str(fig_dir),
            "figures": [f.path for f in figs]}
