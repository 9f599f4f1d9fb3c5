r'''The report's figures (matplotlib, Agg): the paper's Figs. 3-11, maps, speed vs accuracy

SYNOPSIS

    from reports.figures import make_figures

    figs = make_figures(records, run_dir, out_dir)
    # [Figure(key, title, caption, path), ...]; path is a PNG in out_dir

Every figure plots per-camera values, one panel per calibrator (model),
coloured by the model family the images were rendered with, like the paper's
plots (camera number on the x axis). Records that are not ok are left out of
the plots (the report lists them). A figure with nothing to plot is not made.
'''

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from harness.studies.sweep import level_text

from .tables import record_variant

FAMILY_COLOURS = {"CAHV": "tab:blue", "CAHVOR": "tab:orange", "CAHVORE": "tab:green"}
FAMILY_OFFSET = {"CAHV": -0.22, "CAHVOR": 0.0, "CAHVORE": 0.22}


@dataclass(frozen=True)
class Figure:
    key: str
    title: str
    caption: str
    path: str


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def camera_order(records):
    r'''Camera keys in paper order: slot numbers ascending, then the others by name'''
    keys = {r["camera"] for r in records.values()}

    def k(c):
        return (0, int(c), "") if c.isdigit() else (1, 0, c)
    return sorted(keys, key=k)


def calibrator_panels(records):
    r'''[(calibrator, calibrator_model label, variant), ...] that have ok records,
in a stable order; the variant (tables.record_variant: the target and the render variant,
each when the run has several) is "" when the run has only one, so that records of
different targets, renderers, K or response profiles never share a panel'''
    variant = record_variant(records)
    out = sorted({(r["calibrator"], _calmodel(r), variant(r))
                  for r in records.values() if r["status"] == "ok"})
    return out


def _panel_title(cal, cm, variant):
    return cal + ("" if cm == "family" else f" [{cm}]") + (f" on {variant}" if variant else "")


def _calmodel(r):
    m = r["calibrator_model"]
    return "family" if m == r["model"] else m


def _panel_records(records, cal, calmodel, variant=""):
    of = record_variant(records)
    return [r for r in records.values()
            if r["status"] == "ok" and r["calibrator"] == cal and _calmodel(r) == calmodel
            and (not variant or of(r) == variant)]


def _param(r, name):
    v = (r.get("params") or {}).get(name)
    return None if v is None else float(v)


# A linear panel's y range ends at OFFSCALE x the upper quartile of its |values| (and the
# paper's lines): a point beyond is drawn at the edge as a red arrow and listed in the caption,
# so diverged fits (mrcal's 1.55e4 px Hc) cannot flatten every other point onto zero. The
# quartile holds while fewer than a quarter of the points are outliers.
OFFSCALE = 10.0
OFFSCALE_LISTED = 12
# decades of the maps' shared logarithmic colour scale
MAP_DECADES = 3
# the map figures' fixed geometry (inches): a cell per map (its two-line title above the
# image), the margin round the grid, the suptitle's band, the colour bar (width, longest
# length) and the band right of the grid that holds it with its labels
MAP_CELL = (2.1, 2.0)
MAP_PAD = 0.08
MAP_TITLE_SPACE = 0.32
MAP_MARGIN = 0.05
MAP_SUPTITLE_SPACE = 0.3
MAP_COLORBAR = (0.2, 4.5)
MAP_COLORBAR_SPACE = 0.9


# The report's signal colour (off-scale arrows, the paper's lines, saturated map titles) and
# its blends with the white page (antialiased text edges), at these opacities: palette
# entries of their own in every palette PNG (save_png)
SIGNAL_COLOUR = (214, 39, 40)     # matplotlib's tab:red
SIGNAL_BLENDS = (1.0, 0.8, 0.6, 0.4)


def save_png(fig, path, dpi):
    r'''Save a figure as a palette PNG (256 colours): a third of the RGB file's size for the
report's plots and maps (the paper campaign's report: 2.83 -> 1.57 MB), no visible change

The palette: a median cut of the figure's colours (smooth gradients stay smooth; maximum
coverage bands the maps into false contours) plus SIGNAL_COLOUR and its blends, which
take the pixels nearer to them than to their median-cut colour: a few red pixels among
the maps' million (a "(saturated)" title) stay red, where median cut alone spent every
entry on the gradients and turned them grey (the paper run's mrcal maps).'''
    from PIL import Image
    # the canvas's pixels as they are: fig.savefig would encode a PNG only to decode it here
    fig.set_dpi(dpi)
    fig.canvas.draw()
    rgb = np.asarray(fig.canvas.buffer_rgba())[..., :3]
    reserved = np.array([[255 * (1 - a) + a * c for c in SIGNAL_COLOUR]
                         for a in SIGNAL_BLENDS]).round()
    ncut = 256 - len(reserved)
    cut = Image.fromarray(rgb).quantize(colors=ncut, method=Image.Quantize.MEDIANCUT)
    palette = np.array(cut.getpalette()[:3 * ncut], dtype=np.float64).reshape(-1, 3)
    palette = np.vstack([palette, np.zeros((ncut - len(palette), 3)), reserved])
    index = np.array(cut, dtype=np.uint8)
    # only reddish pixels can be nearer a blend of red and white (each has R - G, R - B
    # >= 0.4 x 174 there): the few to look at
    r, g, b = (rgb[..., k].astype(np.int16) for k in range(3))
    iy, ix = np.nonzero((r - g > 30) & (r - b > 30))
    x = rgb[iy, ix].astype(np.float64)                                  # (n, 3)
    d_cut = ((x - palette[index[iy, ix]]) ** 2).sum(axis=-1)
    d_res = ((x[:, None, :] - reserved) ** 2).sum(axis=-1)              # (n, len(reserved))
    nearer = d_res.min(axis=-1) < d_cut
    index[iy[nearer], ix[nearer]] = ncut + d_res.argmin(axis=-1)[nearer]
    out = Image.fromarray(index, mode="P")
    out.putpalette(palette.astype(np.uint8).ravel().tolist())
    out.save(path, optimize=True)


def robust_limit(values, keep=()):
    r'''The half-range of a linear axis no outlier can swamp (see OFFSCALE); None: no clip'''
    a = np.abs(np.asarray([v for v in values if math.isfinite(v)], dtype=np.float64))
    if a.size < 4:
        return None
    lim = OFFSCALE * float(np.percentile(a, 75))
    lim = max([lim] + [1.1 * abs(k) for k in keep])
    if lim <= 0 or a.max() <= lim:
        return None
    return lim


def _per_camera_figure(records, out, key, title, ylabel, series, caption, logy=False,
                       absolute=False, paper=()):
    r'''series: [(label, marker, getter(record) -> float or None), ...];
paper: [(value, label)] the paper's figures, drawn as dashed lines'''
    panels = calibrator_panels(records)
    cams = camera_order(records)
    xpos = {c: i for i, c in enumerate(cams)}
    rows = []
    for cal, cm, variant in panels:
        recs = _panel_records(records, cal, cm, variant)
        pts = []
        for r in recs:
            for label, marker, get in series:
                v = get(r)
                if v is None or not math.isfinite(v):
                    continue
                if absolute or logy:
                    v = abs(v)
                if logy and v <= 0:
                    v = 1e-12
                pts.append((xpos[r["camera"]] + FAMILY_OFFSET.get(r["model"], 0), v,
                            r["model"], label, marker, r["camera"]))
        if pts:
            rows.append((_panel_title(cal, cm, variant), pts))
    if not rows:
        return None
    plt = _plt()
    fig, axes = plt.subplots(len(rows), 1, figsize=(max(7.0, 0.38 * len(cams) + 3), 2.6 *
                                                    len(rows) + 0.6), squeeze=False,
                             dpi=90)   # the dpi of save_png: one renderer lays out and draws
    offscale = []
    for ax, (panel_title, pts) in zip(axes[:, 0], rows, strict=True):
        lim = None if logy else robust_limit([p[1] for p in pts],
                                             keep=[v for v, _ in paper])
        if lim is not None:
            out_pts = [p for p in pts if abs(p[1]) > lim]
            pts = [p for p in pts if abs(p[1]) <= lim]
            for x, v, fam, label, _, cam in out_pts:
                offscale.append(f"{panel_title}: {cam} {fam} {label} {v:.3g}")
                ax.plot([x], [math.copysign(0.97 * lim, v)], "^" if v > 0 else "v",
                        color="tab:red", ms=7)
            ax.set_ylim(-lim if not absolute else -0.03 * lim, lim)
            ax.text(0.995, 0.97, f"{len(out_pts)} off scale (red arrows)", fontsize=6,
                    color="tab:red", ha="right", va="top", transform=ax.transAxes)
        groups = {}
        for x, v, fam, label, marker, _ in pts:
            groups.setdefault((fam, label, marker), []).append((x, v))
        for (fam, label, marker), xv in groups.items():
            xv = np.array(xv)
            ax.plot(xv[:, 0], xv[:, 1], marker, color=FAMILY_COLOURS.get(fam, "k"), ms=5,
                    ls="none", mfc="none" if marker in ("^", "v") else None,
                    label=f"{fam} {label}".strip())
        for value, label in paper:
            ax.axhline(value, color="tab:red", ls="--", lw=0.8, label=f"paper: {label}")
        ax.set_title(panel_title, fontsize=9)
        ax.set_ylabel(ylabel, fontsize=8)
        ax.set_xticks(range(len(cams)))
        ax.set_xticklabels(cams, fontsize=7, rotation=90 if len(cams) > 30 else 0)
        ax.set_xlim(-0.6, len(cams) - 0.4)
        if logy:
            ax.set_yscale("log")
        else:
            ax.axhline(0, color="0.6", lw=0.6)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=6, ncol=3, loc="best")
    axes[-1, 0].set_xlabel("camera (catalogue slot)", fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    path = Path(out) / f"{key}.png"
    save_png(fig, path, dpi=90)
    plt.close(fig)
    if offscale:
        listed = "; ".join(offscale[:OFFSCALE_LISTED])
        more = f"; and {len(offscale) - OFFSCALE_LISTED} more" if len(offscale) > \
            OFFSCALE_LISTED else ""
        caption += (f" Off scale (beyond {OFFSCALE:g}x the upper quartile of the panel's "
                    f"values, red arrows at the edge): {listed}{more}.")
    return Figure(key, title, caption, str(path))


def _res(name):
    def get(r):
        v = (r.get("residuals") or {}).get(name)
        return None if v is None else float(v)
    return get


def _p(name, scale=1.0):
    def get(r):
        v = _param(r, name)
        return None if v is None else v * scale
    return get


def fig_residuals(records, out):
    return _per_camera_figure(
        records, out, "fig03_residuals", "Calibration residuals per camera (paper Fig. 3)",
        "residual (px)",
        [("min", "v", _res("min")), ("RMS", "o", _res("rms")), ("max", "^", _res("max"))],
        "Minimum, RMS and maximum per-point residual of each calibration. The paper: RMS "
        "about 1/30 px, worst 0.14 px (dashed).", logy=True,
        paper=((1 / 30, "RMS 1/30 px"), (0.14, "worst 0.14 px")))


def fig_center(records, out):
    return _per_camera_figure(
        records, out, "fig04_center", "Error in (Hc, Vc) (paper Figs. 4-5)", "error (px)",
        [("Hc", "o", _p("Hc")), ("Vc", "x", _p("Vc"))],
        "Recovered minus true image centre. The paper: within +-0.5 px (ROAMS rounded the "
        "centre to half pixels).")


def fig_focal(records, out):
    return _per_camera_figure(
        records, out, "fig06_focal", "Fractional error in (Hs, Vs) (paper Fig. 6)",
        "fractional error",
        [("Hs", "o", _p("Hs")), ("Vs", "x", _p("Vs")),
         ("Hs(1+R0)", "s", _p("Hs*(1+R0)")), ("Vs(1+R0)", "+", _p("Vs*(1+R0)"))],
        "Focal lengths as fractions of the truth; Hs(1+R0) is nearly free of the R0 gauge. "
        "The paper: Vs underestimated by 0.04% or less under CAHVOR.")


def fig_theta(records, out):
    return _per_camera_figure(
        records, out, "fig_theta", "Error in theta", "error (deg)",
        [("theta", "o", _p("theta_deg"))],
        "Recovered minus true angle between H' and V' (only the jpl calibrator estimates it). "
        "The paper: up to 0.17 deg under CAHV, 0.002 deg under CAHVOR.")


def fig_C(records, out):
    return _per_camera_figure(
        records, out, "fig07_C", "Error in C (paper Fig. 7)", "|C error| (mm)",
        [("C", "o", _p("C_mm"))],
        "Distance between the recovered and true camera centres. The paper: below 0.06 mm "
        "under CAHV.", logy=True, paper=((0.06, "CAHV < 0.06 mm"),))


def fig_A(records, out):
    return _per_camera_figure(
        records, out, "fig08_A", "Angular error in A (paper Fig. 8)", "angle (deg)",
        [("A", "o", _p("A_deg"))],
        "Angle between the recovered and true axis A. The paper: at most 0.005 deg under "
        "CAHV.", logy=True, paper=((0.005, "CAHV 0.005 deg"),))


def fig_O(records, out):
    return _per_camera_figure(
        records, out, "fig09_O", "Angular error in O (paper Fig. 9)", "angle (deg)",
        [("O", "o", _p("O_deg"))],
        "Angle between the recovered and true optical axis O (each in its camera frame). "
        "The paper: within 0.1 deg except the MER mast cameras (13-16).", logy=True,
        paper=((0.1, "0.1 deg"),))


def fig_R_abs(records, out):
    return _per_camera_figure(
        records, out, "fig10_R_abs", "Absolute error in R (paper Fig. 10)", "|error|",
        [("R0", "o", _p("R0")), ("R1", "x", _p("R1")), ("R2", "s", _p("R2"))],
        "Absolute error of the radial terms (R0 in the fit's gauge).", logy=True)


def fig_R_frac(records, out):
    return _per_camera_figure(
        records, out, "fig11_R_frac", "Fractional error in R (paper Fig. 11)",
        "|fractional error|",
        [("R0", "o", _p("R0_frac")), ("R1", "x", _p("R1_frac")), ("R2", "s", _p("R2_frac"))],
        "Fractional error of the radial terms. The paper: R1, R2 well below 1% except the "
        "mast cameras.", logy=True)


def fig_projection(records, out):
    return _per_camera_figure(
        records, out, "fig_projection", "Projection difference, truth vs recovered model",
        "px",
        [("RMS", "o", lambda r: (r.get("projection") or {}).get("rms")),
         ("max", "^", lambda r: (r.get("projection") or {}).get("max"))],
        "RMS and maximum over the whole image of |fit - truth| in projection (rotation "
        "between the camera frames fitted).", logy=True)


TARGET_MARKERS = {"dots": "o", "apriltag": "s", "chessboard": "D"}


def _gate_z():
    r'''The default gate's z (harness.gate.DEFAULT_SPEC's [[scatter]]), or None'''
    try:
        from harness.gate import DEFAULT_SPEC, load_gate_spec
        zs = {s.z for s in load_gate_spec(DEFAULT_SPEC).scatter}
    except Exception:   # no spec in this tree: the figure without the line
        return None
    return max(zs) if zs else None


def _worst_z(r):
    z = ((r.get("verdict") or {}).get("renderer") or {}).get("z") or {}
    vals = [abs(v) for v in z.values() if isinstance(v, (int, float)) and math.isfinite(v)]
    return max(vals) if vals else None


def fig_targets(records, out):
    r'''The targets side by side: per camera, the renderer verdict (the largest |z| of a
record's judged quantities) and the total projection difference RMS, one row of panels per
calibrator (and render variant) that ran on several targets, a marker per target; None
for a run of one target'''
    from .tables import render_variant, render_variants
    if len({r.get("target") for r in records.values()}) < 2:
        return None
    renders = len(render_variants(records)) > 1
    groups = {}
    for r in records.values():
        if r["status"] == "ok":
            label = r["calibrator"] + ("" if _calmodel(r) == "family" else f" [{_calmodel(r)}]")
            label += f" on {render_variant(r)}" if renders else ""
            groups.setdefault(label, []).append(r)
    groups = {k: v for k, v in groups.items() if len({r["target"] for r in v}) > 1}
    if not groups:
        return None
    cams = camera_order(records)
    xpos = {c: i for i, c in enumerate(cams)}
    gate_z = _gate_z()
    plt = _plt()
    fig, axes = plt.subplots(len(groups), 2, figsize=(max(12.0, 0.6 * len(cams) + 4),
                                                      2.8 * len(groups) + 0.6), squeeze=False,
                             dpi=90)   # the dpi of save_png: one renderer lays out and draws
    for (label, recs), (axz, axp) in zip(sorted(groups.items()), axes, strict=True):
        series = {}
        for r in recs:
            x = xpos[r["camera"]] + FAMILY_OFFSET.get(r["model"], 0)
            series.setdefault((r["model"], r["target"]), []).append(
                (x, _worst_z(r), (r.get("projection") or {}).get("rms")))
        for (fam, tg), pts in sorted(series.items()):
            kw = dict(color=FAMILY_COLOURS.get(fam, "k"), ls="none", ms=5,
                      marker=TARGET_MARKERS.get(tg, "x"),
                      mfc="none" if tg != "dots" else None, label=f"{fam} {tg}")
            z = [(x, v) for x, v, _ in pts if v is not None]
            p = [(x, v) for x, _, v in pts if v is not None and v > 0]
            if z:
                axz.plot(*zip(*z, strict=True), **kw)
            if p:
                axp.plot(*zip(*p, strict=True), **kw)
        if gate_z is not None:
            axz.axhline(gate_z, color="tab:red", ls="--", lw=0.8, label=f"gate z = {gate_z:g}")
        axz.set_ylim(bottom=0)
        axz.set_title(f"{label}: renderer verdict, largest |z|", fontsize=9)
        axz.set_ylabel("|renderer difference| / sigma", fontsize=8)
        axp.set_yscale("log")
        axp.set_title(f"{label}: total projection difference RMS", fontsize=9)
        axp.set_ylabel("px", fontsize=8)
        for ax in (axz, axp):
            ax.set_xticks(range(len(cams)))
            ax.set_xticklabels(cams, fontsize=7, rotation=90 if len(cams) > 30 else 0)
            ax.set_xlim(-0.6, len(cams) - 0.4)
            ax.grid(True, alpha=0.3)
            ax.legend(fontsize=6, ncol=3, loc="best")
    for ax in axes[-1]:
        ax.set_xlabel("camera (catalogue slot)", fontsize=8)
    fig.suptitle("Targets side by side", fontsize=10)
    fig.tight_layout()
    path = Path(out) / "fig_targets.png"
    save_png(fig, path, dpi=90)
    plt.close(fig)
    gate_text = "" if gate_z is None else f"; the default renderer gate fails above {gate_z:g}"
    return Figure("fig_targets", "Targets side by side: renderer verdict and total error",
                  "Per camera, for each calibrator that fitted several targets: left, the "
                  "renderer verdict (the largest |z| of the record's judged quantities: its "
                  "image fit minus its fit of the exact observations, over the expected "
                  f"scatter{gate_text}); right, the total "
                  "projection difference RMS against the truth. Filled circles: dots; open "
                  "markers: corner targets. A corner target rendered by the reference render "
                  "itself (harness.verdict.REFERENCE_RENDER) has a renderer difference of 0 by "
                  "construction: its detections are the reference corners.", str(path))


def fig_maps(records, run_dir, out, limit=72):
    r'''Small multiples of the stored projection-difference maps (keep_maps), per calibrator

All the panels of a figure are images in ONE axes (data units are inches; each
map centred in its cell at its own aspect, its title above it) placed at fixed
positions: a figure of 66 maps costs one axes' tick machinery and no layout
solve, instead of 66 axes under constrained layout (the paper campaign's four
map figures: 14 s -> 3 s of CPU).'''
    figs = []
    panels = calibrator_panels(records)
    order = {c: i for i, c in enumerate(camera_order(records))}
    for cal, cm, variant in panels:
        recs = [r for r in _panel_records(records, cal, cm, variant)
                if (r.get("artifacts") or {}).get("map")
                and (Path(run_dir) / r["artifacts"]["map"]).is_file()]
        recs.sort(key=lambda r: (order[r["camera"]], r["model"], r["fullname"]))
        if not recs:
            continue
        shown = recs[:limit]
        several = len({(r["renderer"], str(r["settings"])) for r in recs}) > 1
        plt = _plt()
        ncol = min(6, len(shown))
        nrow = math.ceil(len(shown) / ncol)
        maps = [np.load(Path(run_dir) / r["artifacts"]["map"]) for r in shown]
        maxima = [float(np.nanmax(m)) if np.isfinite(m).any() else math.nan for m in maps]
        # one colour scale for the figure; a panel beyond it saturates and says so
        vmax = robust_limit([x for x in maxima if math.isfinite(x)]) or max(
            [x for x in maxima if math.isfinite(x)] or [1.0])
        vmax = vmax if vmax > 0 else 1.0
        # logarithmic, MAP_DECADES decades: a 0.003 px map keeps its structure beside a
        # 0.8 px one on the same scale
        from matplotlib.colors import LogNorm
        norm = LogNorm(vmin=vmax * 10.0 ** -MAP_DECADES, vmax=vmax, clip=True)
        grid_w, grid_h = MAP_CELL[0] * ncol, MAP_CELL[1] * nrow
        fig_w = MAP_MARGIN + grid_w + MAP_COLORBAR_SPACE
        fig_h = grid_h + MAP_MARGIN + MAP_SUPTITLE_SPACE
        fig = plt.figure(figsize=(fig_w, fig_h))
        ax = fig.add_axes((MAP_MARGIN / fig_w, MAP_MARGIN / fig_h, grid_w / fig_w,
                           grid_h / fig_h))
        ax.set_xlim(0, grid_w)
        ax.set_ylim(0, grid_h)
        ax.axis("off")
        im = None
        box_w = MAP_CELL[0] - 2 * MAP_PAD
        box_h = MAP_CELL[1] - MAP_TITLE_SPACE - MAP_PAD
        for k, (r, m, mx) in enumerate(zip(shown, maps, maxima, strict=True)):
            x_left = (k % ncol) * MAP_CELL[0]
            y_top = grid_h - (k // ncol) * MAP_CELL[1]
            ny, nx = m.shape
            s = min(box_w / nx, box_h / ny)      # inches per map pixel: the map's own aspect
            cx, cy = x_left + MAP_CELL[0] / 2, y_top - MAP_TITLE_SPACE - box_h / 2
            im = ax.imshow(np.maximum(m, norm.vmin), cmap="viridis", norm=norm,
                           extent=(cx - s * nx / 2, cx + s * nx / 2, cy - s * ny / 2,
                                   cy + s * ny / 2))
            setting = f" {r['renderer']} K{r['settings'].get('spp')}" if several else ""
            over = " (saturated)" if mx > vmax else ""
            ax.text(cx, cy + s * ny / 2 + 0.04, f"{r['camera']} {r['model']}{setting}\n"
                    f"max {mx:.2g} px{over}", ha="center", va="bottom", fontsize=7,
                    color="tab:red" if over else "black")
        # the image axes' autoscaling and aspect are not wanted: the cells fix both
        ax.set_xlim(0, grid_w)
        ax.set_ylim(0, grid_h)
        ax.set_aspect("auto")
        if im is not None:
            bar_h = min(grid_h, MAP_COLORBAR[1])
            cax = fig.add_axes(((MAP_MARGIN + grid_w + 0.1) / fig_w,
                                (MAP_MARGIN + (grid_h - bar_h) / 2) / fig_h,
                                MAP_COLORBAR[0] / fig_w, bar_h / fig_h))
            fig.colorbar(im, cax=cax,
                         extend="both" if max(maxima, default=0) > vmax else "min",
                         label="px").ax.tick_params(labelsize=6)
        label = _panel_title(cal, cm, variant)
        more = f" (first {limit} of {len(recs)})" if len(recs) > limit else ""
        fig.suptitle(f"Projection difference |fit - truth| (px), {label}{more}", fontsize=9,
                     y=1 - 0.08 / fig_h, va="top")
        key = f"maps_{cal}" + ("" if cm == "family" else f"_{cm}") + (
            "_" + "".join(c if c.isalnum() else "_" for c in variant) if variant else "")
        path = Path(out) / f"{key}.png"
        # 68 dpi: ~140 px panels for the stored maps' 96 px (harness.stages.MAP_SIZE); the
        # paper campaign's report: 1.40 MB (80 dpi: 1.57 MB)
        save_png(fig, path, dpi=68)
        plt.close(fig)
        figs.append(Figure(key, f"Projection-difference maps, {label}",
                           "Per-pixel |fit - truth| in projection over the whole image "
                           "(downsampled, maximum per block); one logarithmic colour "
                           f"scale for all panels, {vmax * 10.0 ** -MAP_DECADES:.2g} to "
                           f"{vmax:.3g} px; a panel whose maximum (printed above it) is "
                           "beyond it is marked saturated.",
                           str(path)))
    return figs


def speed_accuracy_points(records):
    r'''[(renderer label, calibrator label, time per image s, median projection RMS px, n)]

One point per renderer setting and calibrator: the median over its ok
records of the projection-difference RMS, against the mean render time per
image of its jobs.
'''
    groups = {}
    for r in records.values():
        if r["status"] != "ok":
            continue
        s = r.get("seconds") or {}
        t = s.get("render_per_image")
        rms = (r.get("projection") or {}).get("rms")
        if t is None or rms is None:
            continue
        rlab = _renderer_text(r["renderer"], r["settings"])
        clab = r["calibrator"] + ("" if _calmodel(r) == "family" else f"[{_calmodel(r)}]")
        g = groups.setdefault((rlab, clab), {"t": {}, "rms": []})
        g["t"][r["fullname"].rsplit("/", 1)[0]] = t
        g["rms"].append(rms)
    return [(rl, cl, float(np.mean(list(g["t"].values()))), float(np.median(g["rms"])),
             len(g["rms"])) for (rl, cl), g in sorted(groups.items())]


def _renderer_text(renderer, s):
    r'''"raycast[spp=16,adaptive,coverage=area]": the renderer's name and its settings as
in a fullname (with the options it applies by default)'''
    from harness.records import renderer_key
    return renderer_key(renderer, {k: v for k, v in s.items() if k != "label"})


def pareto_front(points):
    r'''Indices of the points (t, e) not dominated (no other point is faster and as accurate)'''
    idx = sorted(range(len(points)), key=lambda i: (points[i][0], points[i][1]))
    front, best = [], math.inf
    for i in idx:
        if points[i][1] < best:
            front.append(i)
            best = points[i][1]
    return front


def speed_series(records):
    r'''{renderer label: (series label, K)}: a series is one renderer path (renderer name,
full or adaptive sampling, its options such as povray's camera=perspective / camera=mesh);
its points differ in supersampling K'''
    out = {}
    for r in records.values():
        s = r.get("settings") or {}
        rlab = _renderer_text(r["renderer"], s)
        from renderers.base import DEFAULT_OPTIONS
        options = {**DEFAULT_OPTIONS.get(r["renderer"], {}), **(s.get("options") or {})}
        opts = ", ".join(f"{k}={_opt_text(v)}" for k, v in sorted(options.items()))
        series = r["renderer"] + ("" if s.get("adaptive", False) else " (full)")
        if opts:
            series += f" {opts}"
        out[rlab] = (series, int(s.get("spp", 1)))
    return out


def _opt_text(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    return str(v)


SPEED_MARKERS = "osD^vP*Xh<>p"


def _log_axes(ax, xs, ys):
    r'''Log axes with plain 1-2-5 tick labels, at least a factor 4 wide (a narrow log axis
otherwise prints overlapping minor labels)'''
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter
    for axis, vals, setlim in ((ax.xaxis, xs, ax.set_xlim), (ax.yaxis, ys, ax.set_ylim)):
        v = [x for x in vals if x is not None and math.isfinite(x) and x > 0]
        (ax.set_xscale if axis is ax.xaxis else ax.set_yscale)("log")
        if v:
            lo, hi = min(v), max(v)
            pad = max(1.6, math.sqrt(4.0 * lo / hi))
            setlim(lo / pad, hi * pad)
        axis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
        axis.set_major_formatter(FuncFormatter(lambda x, _: f"{x:g}"))
        axis.set_minor_formatter(NullFormatter())


def fig_speed(records, out):
    pts = speed_accuracy_points(records)
    if not pts:
        return None
    series_of = speed_series(records)
    names = sorted({series_of[p[0]][0] for p in pts})
    palette = ("C0", "C1", "C2", "C4", "C5", "C6", "C8", "C9", "C7")   # red marks the front
    colour = {n: palette[i % len(palette)] for i, n in enumerate(names)}
    marker = {n: SPEED_MARKERS[i % len(SPEED_MARKERS)] for i, n in enumerate(names)}
    plt = _plt()
    cals = sorted({p[1] for p in pts})
    fig, axes = plt.subplots(1, len(cals), figsize=(6.4 * len(cals), 4.6 + 0.2 * len(names)),
                             squeeze=False)
    for ax, cal in zip(axes[0], cals, strict=True):
        mine = [p for p in pts if p[1] == cal]
        xy = [(p[2], p[3]) for p in mine]
        front = pareto_front(xy)
        for name in names:
            ser = sorted((series_of[p[0]][1], p[2], p[3]) for p in mine
                         if series_of[p[0]][0] == name)
            if not ser:
                continue
            ks = [k for k, _, _ in ser]
            ax.plot([t for _, t, _ in ser], [e for _, _, e in ser], "-", marker=marker[name],
                    color=colour[name], ms=6, lw=1,
                    label=f"{name} (K = {', '.join(str(k) for k in ks)})")
            for k, t, e in ser:
                ax.annotate(f"K{k}", (t, e), fontsize=7, color=colour[name], xytext=(4, 3),
                            textcoords="offset points")
        f = sorted(front, key=lambda i: xy[i][0])
        ax.plot([xy[i][0] for i in f], [xy[i][1] for i in f], "o", ms=12, mfc="none",
                mec="tab:red", mew=1.5, ls="--", color="tab:red", lw=0.8,
                label="Pareto front")
        _log_axes(ax, [p[2] for p in mine], [p[3] for p in mine])
        ax.set_xlabel("render time per image (s)", fontsize=8)
        ax.set_ylabel("median projection-difference RMS (px)", fontsize=8)
        ax.set_title(f"calibrated with {cal}", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2,
                  frameon=False)
    fig.suptitle("Speed versus accuracy of every renderer setting", fontsize=10)
    fig.tight_layout()
    path = Path(out) / "speed_accuracy.png"
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return Figure("speed_accuracy", "Speed versus accuracy",
                  "Mean render time per image against the median projection-difference RMS "
                  "of the recovered models. One line (colour and marker) per renderer path: "
                  "renderer, sampling and options (e.g. povray camera=perspective or "
                  "camera=mesh); its points are the supersampling K, labelled. Ringed in "
                  "red: the Pareto front (no other setting is both faster and more accurate).",
                  str(path))


def fig_legacy_signature(rows, out):
    r'''The paper's Figs. 4-5: recovered (Hc, Vc) error against the truth (left) and
against the truth rounded to the half pixel (right), per camera; rows from
reports.tables.legacy_signature_rows'''
    if not any(r["mode"] == "legacy" for r in rows):
        return None
    cals = sorted({r["calibrator"] for r in rows})
    cams = sorted({r["camera"] for r in rows},
                  key=lambda c: (0, int(c), "") if c.isdigit() else (1, 0, c))
    xpos = {c: i for i, c in enumerate(cams)}
    plt = _plt()
    fig, axes = plt.subplots(len(cals), 2, figsize=(max(10.0, 0.9 * len(cams) + 6),
                                                    3.4 * len(cals) + 1.6), squeeze=False)
    for row_axes, cal in zip(axes, cals, strict=True):
        mine = [r for r in rows if r["calibrator"] == cal]
        for ax, suffix, title in ((row_axes[0], "error", "Fig. 4: recovered - truth"),
                                  (row_axes[1], "error_vs_rounded",
                                   "Fig. 5: recovered - truth rounded to 1/2 px")):
            for mode in ("clean", "legacy"):
                for name, mk, dx in (("Hc", "o", -0.08), ("Vc", "x", 0.08)):
                    for fam in sorted({r["model"] for r in mine}):
                        pts = [(xpos[r["camera"]] + FAMILY_OFFSET.get(fam, 0) + dx,
                                r[f"{name}_{suffix}"]) for r in mine
                               if r["mode"] == mode and r["model"] == fam]
                        if not pts:
                            continue
                        pts = np.array(pts)
                        legacy = mode == "legacy"
                        ax.plot(pts[:, 0], pts[:, 1], mk, ls="none",
                                color=FAMILY_COLOURS.get(fam, "k") if legacy else "0.55",
                                ms=7 if legacy else 4, mfc="none" if mk == "o" else None,
                                label=f"{mode} {fam} {name}" if legacy
                                else f"clean renderer {name} (control)")
            if suffix == "error":
                # where the rounding put each centre: the legacy errors land on these ticks
                for name, dx in (("Hc", -0.08), ("Vc", 0.08)):
                    seen = {}
                    for r in mine:
                        x = xpos[r["camera"]] + FAMILY_OFFSET.get(r["model"], 0) + dx
                        seen[(x, r["model"])] = r[f"{name}_rounding"]
                    xs = np.array([x for x, _ in seen])
                    ax.plot(xs, list(seen.values()), "_", color="k", ms=16, mew=1.5,
                            label="truth rounded to 1/2 px - truth" if name == "Hc" else None)
                for v in (-0.25, 0.25):
                    ax.axhline(v, color="0.6", ls=":", lw=0.8)
            ax.axhline(0, color="0.6", lw=0.6)
            ax.set_title(f"{title} (Hc, Vc), {cal}", fontsize=9)
            ax.set_ylabel("px", fontsize=8)
            ax.set_xticks(range(len(cams)))
            ax.set_xticklabels(cams, fontsize=8)
            ax.set_xlim(-0.6, len(cams) - 0.4)
            ax.grid(True, alpha=0.3)
    handles = {}
    for ax in axes.ravel():
        h, lab = ax.get_legend_handles_labels()
        handles.update(zip(lab, h, strict=True))
    fig.legend(handles.values(), handles.keys(), loc="lower center", fontsize=7,
               ncol=min(4, len(handles)), frameon=False)
    for ax in axes[-1]:
        ax.set_xlabel("camera (catalogue slot); CAHV left, CAHVOR middle, CAHVORE right",
                      fontsize=8)
    fig.suptitle("Legacy (ROAMS) signature: the recovered image centre sits on the half "
                 "pixel", fontsize=10)
    nleg = math.ceil(len(handles) / min(4, max(len(handles), 1)))
    fig.tight_layout(rect=(0, 0.045 * nleg + 0.02, 1, 1))
    path = Path(out) / "fig04_05_legacy_signature.png"
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return Figure("fig04_05_legacy_signature",
                  "Legacy signature: (Hc, Vc) error against the truth and the rounded truth "
                  "(paper Figs. 4-5)",
                  "Left: recovered minus true image centre, spread over +-0.25 px for the "
                  "legacy renderer (coloured by model family; circles Hc, crosses Vc), each "
                  "landing on the black tick that marks how far rounding the true centre to "
                  "the nearest half pixel moved it; the clean renderer (grey, the control) "
                  "sits at 0. Right: the same errors against the true centre rounded to the "
                  "half pixel: the legacy errors collapse to 0 and the clean ones move to "
                  "minus the rounding. ROAMS rounded (Hc, Vc) to the half pixel and never "
                  "corrected it.", str(path))


def sweep_tick_labels(sweep):
    r'''The x tick label of every level: the level, with the camera's field of view (fov)
or the mean board range in metres (range)'''
    levels = sweep["levels"]
    labels = list(sweep.get("level_labels") or [level_text(v) for v in levels])
    if sweep["difficulty"] == "range":
        for i, lv in enumerate(levels):
            sc = next((r.get("scene") for r in sweep["records"]
                       if r["level"] == lv and r.get("scene")), None)
            if sc and sc.get("range_m") is not None:
                labels[i] = f"{lv:g}\n{sc['range_m']:.2g} m"
    return labels


def stability_chart(sweep, path):
    r'''One stability chart: projection difference per method against the level,
breakdown points marked (X and a dotted line), detection rate on a second axis,
levels that could not be set up shaded (a harness.studies.sweep.run_sweep document)'''
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 5.6))
    ax2 = ax.twinx()
    levels = sweep["levels"]
    xs = np.arange(len(levels))
    keys = sorted({f"{r['calibrator']}/{r['model']}" for r in sweep["records"]})
    floor = None
    for k, key in enumerate(keys):
        ys = []
        for lv in levels:
            r = next((r for r in sweep["records"] if r["level"] == lv
                      and f"{r['calibrator']}/{r['model']}" == key), None)
            v = r.get("projection_rms_px") if r else None
            ys.append(np.nan if v is None else max(v, 1e-6))
        finite = [y for y in ys if np.isfinite(y)]
        if finite:
            floor = min(finite) if floor is None else min(floor, min(finite))
        b = sweep["breakdown"].get(key, {}).get("level")
        label = key + (f" (breaks at {level_text(b)})" if b is not None else " (never broke)")
        ax.plot(xs, ys, "o-", color=f"C{k}", label=label)
        if b is not None:
            ib = levels.index(b)
            ax.axvline(ib, color=f"C{k}", ls=":", alpha=0.7)
            ax.plot([ib], [ys[ib] if np.isfinite(ys[ib]) else sweep["bar_px"]], "X",
                    color=f"C{k}", ms=14, mec="k")
    for i, lv in enumerate(levels):
        recs = [r for r in sweep["records"] if r["level"] == lv]
        if recs and all(r.get("status") == "not-applicable" for r in recs):
            ax.axvspan(i - 0.5, i + 0.5, color="0.85", zorder=0)
            ax.text(i, sweep["bar_px"], "n/a", ha="center", va="bottom", fontsize=7,
                    color="0.4")
    rates = []
    for lv in levels:
        rs = [r["detection_rate"] for r in sweep["records"]
              if r["level"] == lv and r.get("detection_rate") is not None]
        rates.append(max(rs) if rs else np.nan)
    ax2.plot(xs, 100 * np.asarray(rates, float), "s--", color="0.5", label="detection rate")
    ax2.set_ylabel("detection rate, %")
    ax2.set_ylim(0, 105)
    ax.axhline(sweep["bar_px"], color="k", lw=0.8, ls="--", label=f"bar {sweep['bar_px']:g} px")
    ax.set_yscale("log")
    top = max([sweep["bar_px"]] + [r["projection_rms_px"] for r in sweep["records"]
                                   if r.get("projection_rms_px") is not None])
    ax.set_ylim(min(floor or sweep["bar_px"], sweep["bar_px"]) / 2, top * 3)
    ax.set_xticks(xs, sweep_tick_labels(sweep), fontsize=8)
    ax.set_xlim(-0.5, len(levels) - 0.5)
    ax.set_xlabel(sweep["unit"])
    ax.set_ylabel("projection difference, px RMS (rotation mode)")
    where = ("cameras of the catalogue" if sweep["difficulty"] == "fov" else
             f"camera {sweep['camera']} ({sweep['camera_label']})")
    ax.set_title(f"stability: {sweep['difficulty']} - {where}, {sweep['family']}, "
                 f"{sweep['target']}, {sweep['renderer']} K={sweep['spp']}; X = breakdown",
                 fontsize=9)
    h1, l1 = ax.get_legend_handles_labels()
    h2, l2 = ax2.get_legend_handles_labels()
    ax.legend(h1 + h2, l1 + l2, loc="upper center", bbox_to_anchor=(0.5, -0.15), ncol=3,
              fontsize=7, frameon=False)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def fig_sweeps(sweeps, out):
    r'''One stability chart per sweep document (stability_chart) -> [Figure]'''
    figs = []
    used = set()
    for sw in sweeps:
        key = f"sweep_{sw['difficulty']}"
        if sw.get("camera") not in (None, "catalogue"):
            key += f"_{sw['camera']}"
        key = "".join(ch if ch.isalnum() or ch in "_-." else "_" for ch in key)
        base, i = key, 2
        while key in used:
            key, i = f"{base}_{i}", i + 1
        used.add(key)
        path = Path(out) / f"{key}.png"
        stability_chart(sw, path)
        where = ("one camera per level" if sw["difficulty"] == "fov"
                 else f"camera {sw['camera']} ({sw['camera_label']})")
        broke = "; ".join(f"{k} breaks at {level_text(b['level'])}" if b["level"] is not None
                          else f"{k} never broke" for k, b in sorted(sw["breakdown"].items()))
        figs.append(Figure(
            key, f"Stability: {sw['difficulty']} ({where})",
            f"Projection difference (px RMS, log scale) of every method against "
            f"{sw['unit']}; X and a dotted line mark where each method breaks (detection "
            f"below 100%, a failed calibration, or above the {sw['bar_px']:g} px bar, dashed); "
            f"grey squares: detection rate; shaded: levels that could not be set up. "
            f"{sw['family']}, {sw['target']}, {sw['renderer']} K={sw['spp']}, "
            f"{sw['n_poses']} poses. {broke}.", str(path)))
    return figs


def _figure_makers():
    r'''The run's figures in the report's order: functions (records, run_dir, out) -> a
Figure, None (nothing to plot) or [Figure]'''
    per_run = (fig_targets, fig_residuals, fig_center, fig_focal, fig_theta, fig_C, fig_A,
               fig_O, fig_R_abs, fig_R_frac, fig_projection)
    return ([lambda records, run_dir, out, f=f: f(records, out) for f in per_run] +
            [fig_maps, lambda records, run_dir, out: fig_speed(records, out)])


def _make_figure(i, records, run_dir, out):
    r'''The i-th of _figure_makers() -> [Figure] (what a worker process runs)'''
    fig = _figure_makers()[i](records, run_dir, out)
    return fig if isinstance(fig, list) else [] if fig is None else [fig]


def figure_workers():
    r'''Processes that draw the figures by default: 1. A second process sharing them
(make_figures(workers=2)) was not faster on the 2-core machine the paper campaign is timed
on: 11.8 s wall against 10.2 s near idle (load 0.8-2.2), neutral to slower under load
(2026-11-28, `uv run --frozen python benchmarks/bench_report.py RUN --workers 1,2`); where
more cores are free, pass workers='''
    return 1


def make_figures(records, run_dir, out, workers=None):
    r'''Every figure that has data -> [Figure], in the report's order

workers: processes drawing them (default figure_workers()). With N >= 2, this process
and N - 1 workers (harness.executors.local_pool) share the figures: the workers take
them from the front of the list, this process from the back, each taking the next one
no other has started, so none waits while figures are left, whatever each costs.'''
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    n = len(_figure_makers())
    workers = min(n, figure_workers() if workers is None else workers)
    if workers < 2:
        return [f for i in range(n) for f in _make_figure(i, records, run_dir, out)]
    from concurrent.futures.process import BrokenProcessPool

    from harness.executors import local_pool
    done = {}
    with local_pool(workers - 1) as pool:
        futs = [pool.submit(_make_figure, i, records, run_dir, out) for i in range(n)]
        for i in reversed(range(n)):
            if not futs[i].cancel():
                break       # a worker has it, and the workers every figure before it
            done[i] = _make_figure(i, records, run_dir, out)
        for i in range(n):
            if i not in done:
                try:
                    done[i] = futs[i].result()
                except BrokenProcessPool:
                    # a worker could not start or died (a script without the
                    # `if __name__ == "__main__":` guard forkserver needs): draw it here
                    done[i] = _make_figure(i, records, run_dir, out)
    return [f for i in range(n) for f in done[i]]


def stereo_figure(result, path, variant="clean"):
    r'''The paper's Fig. 12 made quantitative: range- and elevation-coloured stereo
views, the true range, and the range-error map (harness.studies.stereo.run_stereo_check's result)'''
    plt = _plt()
    v = result.variants[variant]
    rng, truth = v.range, result.true_range
    # elevation of the stereo points: the rectified ray scaled by the stereo range
    import mrcal
    mr = result.models_rectified[0]
    W, Hh = mr.imagersize()
    q = np.stack(np.meshgrid(np.arange(W, dtype=float), np.arange(Hh, dtype=float)), axis=-1)
    vc = mrcal.unproject(np.ascontiguousarray(q), *mr.intrinsics(), normalize=True)
    Rt = mr.Rt_ref_cam()
    p_ref = Rt[3] + (vc @ Rt[:3].T) * rng[..., None]
    R, T = result.setup.Rt_ref_terrain[:3], result.setup.Rt_ref_terrain[3]
    elev = ((p_ref - T) @ R)[..., 2]
    rel = (rng - truth) / truth
    # the sky has no truth; SGBM still "matches" its flat black: hide it in the views
    sky = ~np.isfinite(truth)
    rng = np.where(sky, np.nan, rng)
    elev = np.where(sky, np.nan, elev)

    finite = np.isfinite(truth)
    rmax = float(np.nanpercentile(truth[finite], 98)) if finite.any() else 10.0
    fig, ax = plt.subplots(2, 3, figsize=(16, 9.5))
    ax[0, 0].imshow(result.rectified[0], cmap="gray", vmin=0, vmax=1)
    ax[0, 0].set_title(f"rectified left ({result.setup.names[0]})")
    im = ax[0, 1].imshow(rng, cmap="turbo", vmin=0, vmax=rmax)
    ax[0, 1].set_title(f"stereo range, coloured by distance ({variant}; sky masked)")
    fig.colorbar(im, ax=ax[0, 1], label="m")
    et = result.elevation_true
    e_lo, e_hi = (np.nanpercentile(et, [1, 99]) if np.isfinite(et).any() else (0, 1))
    im = ax[0, 2].imshow(elev, cmap="terrain", vmin=e_lo, vmax=e_hi)
    ax[0, 2].set_title("stereo points, coloured by elevation")
    fig.colorbar(im, ax=ax[0, 2], label="m above the datum")
    im = ax[1, 0].imshow(truth, cmap="turbo", vmin=0, vmax=rmax)
    ax[1, 0].set_title("true range (exact ray cast)")
    fig.colorbar(im, ax=ax[1, 0], label="m")
    im = ax[1, 1].imshow(100 * rel, cmap="RdBu_r", vmin=-5, vmax=5)
    ax[1, 1].set_title("range error (stereo - truth) / truth")
    fig.colorbar(im, ax=ax[1, 1], label="%")
    band = v.stats["band"]
    ok = np.isfinite(rel)
    ax[1, 2].hist(np.clip(100 * rel[ok], -10, 10), bins=200, color="0.3")
    lo, hi = band["range_m"]
    inb = ok & (truth >= lo) & (truth <= hi)
    ax[1, 2].hist(np.clip(100 * rel[inb], -10, 10), bins=200, color="C3", alpha=0.8,
                  label=f"true range {lo:g}-{hi:g} m")
    ax[1, 2].set_yscale("log")
    ax[1, 2].set_xlabel("range error, % (clipped to +-10)")
    ax[1, 2].legend()
    s = v.stats
    txt = (f"valid {100 * s['valid_fraction']:.1f}%; median |err| "
           f"{100 * s['all'].get('median_abs_rel_error', float('nan')):.2f}%; "
           f"at {lo:g}-{hi:g} m: median {100 * band.get('median_rel_error', float('nan')):+.2f}%"
           f", median |err| {100 * band.get('median_abs_rel_error', float('nan')):.2f}%, "
           f"p95 {100 * band.get('p95_abs_rel_error', float('nan')):.2f}%")
    ax[1, 2].set_title(txt, fontsize=8)
    for a in ax.ravel()[:5]:
        a.set_xticks([])
        a.set_yticks([])
    fig.suptitle(f"stereo range check: {result.setup.names[0]} / {result.setup.names[1]}"
                 f" (scale {result.setup.scale:g}, K={result.meta['spp']}, "
                 f"render model: {result.meta['render_model']})")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


LIBRARY_MARKERS = {"jpl (scipy)": ("s", "tab:blue"), "mrcal": ("o", "tab:orange"),
                   "opencv": ("^", "tab:green")}


def fig_model_floors(benchmarks, out, key="model_floors"):
    r'''Floor vs parameter count, one panel per camera (harness.model_benchmark results)

SYNOPSIS

    f = fig_model_floors({"15": bench15, "9": bench9}, out_dir)   # Figure or None

Each candidate model is a point at (parameters, max floor px), log scales; the
tolerance is a dashed line and the recommended model is circled. A model that
cannot see the whole field of view is drawn hollow at its floor over the rest.
A cross is a calibrator's own fit of the model (b["own"]: the floors its "best"
choice is made on).
'''
    items = [(cam, b) for cam, b in benchmarks.items() if b.get("rows")]
    if not items:
        return None
    plt = _plt()
    ncol = min(4, len(items))
    nrow = math.ceil(len(items) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.2 * ncol, 2.6 * nrow + 0.6),
                             squeeze=False)
    for ax in axes.ravel()[len(items):]:
        ax.axis("off")
    for ax, (cam, b) in zip(axes.ravel(), items, strict=False):
        crit = b.get("criterion", "max")
        for lib, (marker, colour) in LIBRARY_MARKERS.items():
            rows = [r for r in b["rows"] if r["library"] == lib and r.get(crit) is not None
                    and r.get("nparams")]
            full = [r for r in rows if not r.get("n_invalid")]
            part = [r for r in rows if r.get("n_invalid")]
            for sel, mfc, lab in ((full, colour, lib), (part, "none", None)):
                if sel:
                    ax.plot([r["nparams"] for r in sel],
                            [max(r[crit], 1e-13) for r in sel], marker, color=colour,
                            mfc=mfc, ls="none", ms=5, label=lab)
        # each calibrator's own fits (the floors its "best" choice is made on): crosses in
        # its library's colour
        for cal, own in (b.get("own") or {}).items():
            colour = {"jpl": "tab:blue", "mrcal": "tab:orange", "opencv": "tab:green"}.get(
                cal, "k")
            rows = [r for r in own.get("rows", []) if r.get(crit) is not None]
            if rows:
                ax.plot([r["nparams"] for r in rows], [max(r[crit], 1e-13) for r in rows],
                        "x", color=colour, ls="none", ms=6, mew=1.2,
                        label=f"{cal}'s own fit")
        ax.axhline(b["tolerance"], color="tab:red", ls="--", lw=0.8)
        rec = b.get("recommended")
        if rec:
            ax.plot([rec["nparams"]], [max(rec[crit], 1e-13)], "o", ms=12, mfc="none",
                    color="k")
        ax.set_xscale("log")
        ax.set_yscale("log")
        cam_txt = b.get("camera") or {}
        ax.set_title(f"{cam} {cam_txt.get('family', '')} -> "
                     f"{rec['name'] if rec else 'none'}", fontsize=7)
        ax.tick_params(labelsize=6)
        ax.grid(True, alpha=0.3)
    axes[0, 0].legend(fontsize=6, loc="lower left")
    fig.supxlabel("parameters", fontsize=8)
    fig.supylabel("floor (px, max over the image)", fontsize=8)
    fig.suptitle("Camera-model floors: each candidate fitted\nto the camera's exact "
                 "projections", fontsize=8)
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.4 / fig.get_figheight()))
    path = Path(out) / f"{key}.png"
    save_png(fig, path, dpi=80)
    plt.close(fig)
    return Figure(key, "Camera-model floors", "Each candidate lens model fitted to the "
                  "camera's exact projections over the whole field of view (harness."
                  "model_benchmark): its floor (max projection difference) against its "
                  "parameter count; dashed: the tolerance; circled: the simplest model "
                  "within it; hollow: the model cannot see the whole field of view (the "
                  "floor is over the rest); crosses: each calibrator's own fit of exact "
                  "observations of whole-image poses, the floors its 'best' choice is "
                  "made on.", str(path))
