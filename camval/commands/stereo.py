r'''Stereo range check: render terrain through a stereo pair, match, and compare ranges

camval stereo SLOT_L SLOT_R [-o DIR] [--scale S] [--spp K] [--variants clean,psf,...] [--stages]
              [--renderer NAME [--command 'PROGRAM ARGS' --setup KEY=VALUE ...]]

Renders a generated terrain through both cameras of a catalogue stereo pair
(same frame), rectifies with mrcal (theta = 90, E = 0 versions of the models,
LENSMODEL_LATLON, 1.5 rectified px per raw px at the centre), matches with
OpenCV StereoSGBM, refines the disparities to subpixel precision
(harness.studies.stereo.refine_disparity), triangulates with mrcal.stereo_range and
compares with the exact range along the same rectified rays. Writes
DIR/stereo_<L>_<R>.json (statistics per response variant: valid-pixel
fraction, median and 95th-percentile range errors, over all pixels and in a
+-10% band around --look-range; also SGBM's own), DIR/stereo_<L>_<R>.md (the
same as a table, one row per variant, with the change against "clean") and
DIR/stereo_<L>_<R>.png (rectified image, range- and elevation-coloured stereo
views, true range, error map, error histogram).

Variants are camera-response settings (renderers/response.py) applied to both
images; --stages runs "clean", then every stage alone, then "all":

  clean         no response stage
  vignetting    cos^4
  psf           Gaussian lens PSF, sigma 1.0 px
  motion_blur   2 px along the rows (the epipolar direction)
  global_gain   exposure x0.6
  shot_noise    Poisson, 20000 e- full well
  dark_current  200 e-/s for 0.5 s
  hot_pixels    0.1% of pixels + 10000 e-
  dead_pixels   0.1% of pixels at 0
  saturation    exposure x2 with blooming at the full well
  read_noise    15 e- rms
  encoding      the sRGB transfer function (values not proportional to the light)
  quantise      8 bits
  noise         shot noise + 15 e- read noise, 8 bits
  all           vignetting + PSF + shot noise + dark current + read noise, 12 bits

Examples: camval stereo 21 22 --scale 0.25 -o out/   (Mars 2020 navcam pair)
          camval stereo 12 11 --stages -o out/       (MER B front hazcams)
          camval stereo 12 11 --scale 0.25 --renderer command \
              --command 'python examples/external_renderer.py' --setup persistent=true
                                                     (an external renderer: the protocol's
                                                      terrain requests, docs/README-renderers.md)
'''

from . import command_renderer

# each response stage alone at a realistic setting (renderers/response.py), in the
# physical order the chain runs them; then two combinations
VARIANTS = {
    "clean": {},
    "vignetting": {"vignetting": {"model": "cos4"}},
    "psf": {"psf": {"kind": "gaussian", "sigma_px": 1.0}},
    "motion_blur": {"motion_blur": {"velocity_px": [2.0, 0.0]}},
    "global_gain": {"global_gain": {"gain": 0.6}},
    "shot_noise": {"full_well_e": 20000, "shot_noise": {}},
    "dark_current": {"dark_current": {"rate_e_per_s": 200.0, "exposure_s": 0.5}},
    "hot_pixels": {"hot_pixels": {"fraction": 0.001, "charge_e": 10000.0}},
    "dead_pixels": {"dead_pixels": {"fraction": 0.001}},
    "saturation": {"global_gain": {"gain": 2.0}, "saturation": {"blooming": True}},
    "read_noise": {"read_noise": {"sigma_e": 15.0}},
    # an sRGB-encoded image: its values are not proportional to the light
    "encoding": {"encoding": {"kind": "srgb"}},
    "quantise": {"quantise": {"bits": 8}},
    "noise": {"full_well_e": 20000, "shot_noise": {}, "read_noise": {"sigma_e": 15.0},
              "quantise": {"bits": 8}},
    "all": {"full_well_e": 20000, "vignetting": {"model": "cos4"},
            "psf": {"kind": "gaussian", "sigma_px": 1.0}, "shot_noise": {},
            "dark_current": {"rate_e_per_s": 200.0, "exposure_s": 0.5},
            "read_noise": {"sigma_e": 15.0}, "quantise": {"bits": 12}},
}
STAGE_VARIANTS = [n for n in VARIANTS if n not in ("noise", "all")] + ["all"]


def add_arguments(p):
    p.add_argument("left", help="left camera: slot id, extra's name or model file")
    p.add_argument("right", help="right camera (same frame as the left)")
    p.add_argument("-o", "--out", default=".", help="output directory (default: .)")
    p.add_argument("--scale", type=float, default=1.0,
                   help="scale the camera models (H, V, image size) by this for speed")
    p.add_argument("--spp", type=int, default=2, help="K: K x K rays per pixel (default 2)")
    p.add_argument("--variants", default="clean",
                   help=f"comma-separated response variants; known: {', '.join(VARIANTS)}")
    p.add_argument("--stages", action="store_true",
                   help="run clean, each response stage alone and 'all' (overrides --variants)")
    p.add_argument("--render-model", choices=("true", "rectifiable"), default="true",
                   help="render with the true models (default) or the theta=90, E=0 "
                        "models the rectification uses")
    p.add_argument("--camera-height", type=float, default=None,
                   help="camera height above the ground, m (default by role: hazcam "
                        "0.52, mast 1.9)")
    p.add_argument("--look-range", type=float, default=5.0,
                   help="range of the statistics band, m; a mast frame is pitched so "
                        "the axis meets the ground there (default 5)")
    p.add_argument("--block-size", type=int, default=5, help="StereoSGBM block size")
    p.add_argument("--oversample", type=float, default=1.5,
                   help="rectified pixels per raw pixel at the image centre (default 1.5)")
    p.add_argument("--no-refine", action="store_true",
                   help="keep StereoSGBM's 1/16 px disparities (no subpixel refinement)")
    p.add_argument("--refine-radius", type=int, default=4,
                   help="half-size of the refinement window, rectified px (default 4)")
    p.add_argument("--photometric", choices=("auto", "on", "off"), default="auto",
                   help="refinement: fit a gain and offset between the images only where "
                        "the geometric fit fails (auto), everywhere (on: robust to "
                        "vignetting, 0.1%% worse on clean hazcam images) or nowhere")
    p.add_argument("--flat-field", action="store_true",
                   help="divide the images by the vignetting stage's falloff before "
                        "rectification (radiometric correction)")
    p.add_argument("--prefilter", type=float, default=0.8,
                   help="Gaussian low-pass before the refinement, std in raw px (default 0.8)")
    p.add_argument("--seed", type=int, default=0, help="terrain and noise seed")
    p.add_argument("--renderer", default="raycast_terrain",
                   help="terrain renderer, a registry name (camval renderers list; default "
                        "raycast_terrain)")
    command_renderer.add_arguments(p)
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")


def stage_table(doc):
    r'''Rows of the per-variant table: band and all-pixel range errors, change against clean

SYNOPSIS

    rows = stage_table(result.as_dict())
    # [{"variant", "stages", "band_valid", "band_median", "band_median_abs",
    #   "band_p95_abs", "all_valid", "all_median_abs", "sgbm_band_median_abs",
    #   "delta_band_median_abs"}, ...]; errors are relative (0.01 = 1%)
'''
    variants = doc["variants"]
    nan = float("nan")

    def g(d, *keys):
        for k in keys:
            if not isinstance(d, dict) or k not in d:
                return nan
            d = d[k]
        return float(d)

    clean = g(variants.get("clean", {}), "stats", "band", "median_abs_rel_error")
    rows = []
    for name, v in variants.items():
        s, b = v["stats"], v["stats"]["band"]
        stages = [k for k in v["response"] if k not in ("seed", "full_well_e")]
        rows.append({
            "variant": name, "stages": stages or ["none"],
            "band_n": int(b.get("n", 0)),
            "band_valid": float(b["valid_fraction"]),
            "band_median": g(b, "median_rel_error"),
            "band_median_abs": g(b, "median_abs_rel_error"),
            "band_p95_abs": g(b, "p95_abs_rel_error"),
            "all_valid": float(s["valid_fraction"]),
            "all_median_abs": g(s, "all", "median_abs_rel_error"),
            "all_p95_abs": g(s, "all", "p95_abs_rel_error"),
            "sgbm_band_median_abs": g(v.get("stats_sgbm", {}), "band", "median_abs_rel_error"),
            "delta_band_median_abs": g(b, "median_abs_rel_error") - clean})
    return rows


def markdown_table(doc, rows):
    r'''The per-variant table as Markdown, with a heading naming the pair and the setting'''
    import math
    m = doc["meta"]
    lo, hi = next(iter(doc["variants"].values()))["stats"]["band"]["range_m"]

    def pct(x, sign=False):
        if not math.isfinite(x):
            return "-"
        return f"{100 * x:+.2f}" if sign else f"{100 * x:.2f}"

    out = [f"# Stereo range check: {doc['cameras'][0]} / {doc['cameras'][1]}", "",
           f"Scale {m['scale']:g} ({m['image_size'][0]}x{m['image_size'][1]}), K={m['spp']}, "
           f"rectified {m['rectified_size'][0]}x{m['rectified_size'][1]} LATLON "
           f"({m['pixels_per_deg']:.2f} px/deg), baseline {m['baseline_m']:.3f} m; matcher: "
           f"{m['matcher']}. Range errors are (stereo - true) / true, in %; 'at {lo:g}-{hi:g} m' "
           "are the pixels whose true range is within 10% of the look range; 'valid' is the "
           "fraction of pixels with a true range that have a stereo range.", "",
           f"| variant | stages | valid at {lo:g}-{hi:g} m | median | median abs | p95 abs "
           "| change of median abs vs clean | SGBM alone: median abs | valid, all | "
           "median abs, all | p95 abs, all |",
           "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        out.append(f"| {r['variant']} | {', '.join(r['stages'])} | {pct(r['band_valid'])} | "
                   f"{pct(r['band_median'], True)} | {pct(r['band_median_abs'])} | "
                   f"{pct(r['band_p95_abs'])} | {pct(r['delta_band_median_abs'], True)} | "
                   f"{pct(r['sgbm_band_median_abs'])} | {pct(r['all_valid'])} | "
                   f"{pct(r['all_median_abs'])} | {pct(r['all_p95_abs'])} |")
    return "\n".join(out) + "\n"


def run(args):
    import json
    import math
    from pathlib import Path

    from harness.studies.stereo import StereoError, StereoSetup, run_stereo_check
    from reports.figures import stereo_figure

    if args.stages:
        names = list(STAGE_VARIANTS)
    else:
        names = [v.strip() for v in args.variants.split(",") if v.strip()]
    if not names:
        raise StereoError("no response variant given; known: " + ", ".join(VARIANTS))
    for n in names:
        if n not in VARIANTS:
            raise StereoError(f"unknown response variant {n!r}; known: {', '.join(VARIANTS)}")
    names = list(dict.fromkeys(names))
    if args.refine_radius < 1:
        raise StereoError(f"--refine-radius must be >= 1; got {args.refine_radius}")
    if not args.oversample > 0:
        raise StereoError(f"--oversample must be > 0; got {args.oversample}")
    if not args.prefilter >= 0:
        raise StereoError(f"--prefilter must be >= 0; got {args.prefilter}")
    out = Path(args.out)
    stem = f"stereo_{args.left}_{args.right}".replace("/", "_")
    paths = [out / f"{stem}.json", out / f"{stem}.md", out / f"{stem}.png"]
    for p in paths:
        if p.exists() and not args.force:
            raise StereoError(f"'{p}' exists; pass --force to overwrite it")
    out.mkdir(parents=True, exist_ok=True)
    renderer_options = command_renderer.renderer_options(args, StereoError)
    setup = StereoSetup.from_catalogue(args.left, args.right, scale=args.scale,
                                       camera_height_m=args.camera_height,
                                       look_range_m=args.look_range, seed=args.seed)
    result = run_stereo_check(setup, variants={n: VARIANTS[n] for n in names}, spp=args.spp,
                              render_model=args.render_model, block_size=args.block_size,
                              oversample=args.oversample, refine=not args.no_refine,
                              refine_radius=args.refine_radius, prefilter_px=args.prefilter,
                              photometric={"auto": "auto", "on": True,
                                           "off": False}[args.photometric],
                              flat_field=args.flat_field,
                              seed=args.seed, renderer=args.renderer,
                              renderer_options=renderer_options,
                              progress=lambda s: print(f"  {s}", flush=True))
    doc = result.as_dict()
    rows = stage_table(doc)
    doc["table"] = [{k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                     for k, v in r.items()} for r in rows]
    paths[0].write_text(json.dumps(doc, indent=1, allow_nan=False, default=_plain))
    paths[1].write_text(markdown_table(doc, rows))
    stereo_figure(result, paths[2], variant=names[0])
    lo, hi = next(iter(doc["variants"].values()))["stats"]["band"]["range_m"]
    print(f"{'variant':13s} | at {lo:g}-{hi:g} m: valid  median  med|err|  p95|err| "
          f"(SGBM alone med|err|) | all: valid  med|err|")
    for r in rows:
        print(f"{r['variant']:13s} |   {100 * r['band_valid']:5.1f}%  "
              f"{100 * r['band_median']:+6.2f}%  {100 * r['band_median_abs']:6.2f}%  "
              f"{100 * r['band_p95_abs']:6.2f}%   ({100 * r['sgbm_band_median_abs']:5.2f}%)"
              f"        |  {100 * r['all_valid']:5.1f}%  {100 * r['all_median_abs']:5.2f}%")
    print(f"wrote {paths[0]}, {paths[1]} and {paths[2]}")
    return 0


def _plain(o):
    import numpy as np
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")

