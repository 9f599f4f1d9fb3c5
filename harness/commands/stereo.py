r'''Stereo range check: render terrain through a stereo pair, match, and compare ranges

camval stereo SLOT_L SLOT_R [-o DIR] [--scale S] [--spp K] [--variants clean,noise,blur]

Renders a generated terrain through both cameras of a catalogue stereo pair
(same frame), rectifies with mrcal (theta = 90, E = 0 versions of the models),
matches with OpenCV StereoSGBM, triangulates with mrcal.stereo_range and
compares with the exact range along the same rectified rays. Writes
DIR/stereo_<L>_<R>.json (statistics per response variant: valid-pixel
fraction, median and 95th-percentile range errors, over all pixels and in a
+-10% band around --look-range) and DIR/stereo_<L>_<R>.png (rectified image,
range- and elevation-coloured stereo views, true range, error map, error
histogram). Variants are camera-response settings applied to both images:

  clean     no response stage
  noise     shot noise + 15 e- read noise (20000 e- full well), 8-bit
  blur      Gaussian lens PSF, sigma 1.0 px
  motion    motion blur of 2 px along the rows
  quantise  8-bit quantisation only
  vignette  cos^4 vignetting
  all       noise + blur + vignetting

Examples: camval stereo 21 22 --scale 0.25 -o out/   (Mars 2020 navcam pair)
          camval stereo 12 11 -o out/                (MER B front hazcams)
'''

VARIANTS = {
    "clean": {},
    "noise": {"full_well_e": 20000, "shot_noise": {}, "read_noise": {"sigma_e": 15.0},
              "quantise": {"bits": 8}},
    "blur": {"psf": {"kind": "gaussian", "sigma_px": 1.0}},
    "motion": {"motion_blur": {"velocity_px": [2.0, 0.0]}},
    "quantise": {"quantise": {"bits": 8}},
    "vignette": {"vignetting": {"model": "cos4"}},
    "all": {"full_well_e": 20000, "vignetting": {"model": "cos4"},
            "psf": {"kind": "gaussian", "sigma_px": 1.0}, "shot_noise": {},
            "read_noise": {"sigma_e": 15.0}, "quantise": {"bits": 8}},
}


def add_arguments(p):
    p.add_argument("left", help="left camera: slot id, extra's name or model file")
    p.add_argument("right", help="right camera (same frame as the left)")
    p.add_argument("-o", "--out", default=".", help="output directory (default: .)")
    p.add_argument("--scale", type=float, default=1.0,
                   help="scale the camera models (H, V, image size) by this for speed")
    p.add_argument("--spp", type=int, default=2, help="K: K x K rays per pixel (default 2)")
    p.add_argument("--variants", default="clean",
                   help=f"comma-separated response variants; known: {', '.join(VARIANTS)}")
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
    p.add_argument("--seed", type=int, default=0, help="terrain and noise seed")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")


def write_figure(result, path, variant="clean"):
    r'''The paper's Fig. 12 made quantitative: range- and elevation-coloured stereo
views, the true range, and the range-error map'''
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

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


def run(args):
    import json
    from pathlib import Path

    from harness.stereo import StereoError, StereoSetup, run_stereo_check

    names = [v.strip() for v in args.variants.split(",") if v.strip()]
    for n in names:
        if n not in VARIANTS:
            raise StereoError(f"unknown response variant {n!r}; known: {', '.join(VARIANTS)}")
    out = Path(args.out)
    stem = f"stereo_{args.left}_{args.right}".replace("/", "_")
    paths = [out / f"{stem}.json", out / f"{stem}.png"]
    for p in paths:
        if p.exists() and not args.force:
            raise StereoError(f"'{p}' exists; pass --force to overwrite it")
    out.mkdir(parents=True, exist_ok=True)
    setup = StereoSetup.from_catalogue(args.left, args.right, scale=args.scale,
                                       camera_height_m=args.camera_height,
                                       look_range_m=args.look_range, seed=args.seed)
    result = run_stereo_check(setup, variants={n: VARIANTS[n] for n in names}, spp=args.spp,
                              render_model=args.render_model, block_size=args.block_size,
                              seed=args.seed, progress=lambda s: print(f"  {s}", flush=True))
    doc = result.as_dict()
    paths[0].write_text(json.dumps(doc, indent=1, allow_nan=False, default=_plain))
    write_figure(result, paths[1], variant=names[0])
    for n, v in result.variants.items():
        s, b = v.stats, v.stats["band"]
        print(f"{n:10s} valid {100 * s['valid_fraction']:5.1f}%  all: median |err| "
              f"{100 * s['all'].get('median_abs_rel_error', float('nan')):.2f}%  "
              f"| {b['range_m'][0]:g}-{b['range_m'][1]:g} m: n={b.get('n', 0)} median "
              f"{100 * b.get('median_rel_error', float('nan')):+.2f}%, median |err| "
              f"{100 * b.get('median_abs_rel_error', float('nan')):.2f}%, p95 |err| "
              f"{100 * b.get('p95_abs_rel_error', float('nan')):.2f}%")
    print(f"wrote {paths[0]} and {paths[1]}")
    return 0


def _plain(o):
    import numpy as np
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


if __name__ == "__main__":
    # `camval stereo` once harness/cli.py lists this module; until then:
    # uv run python -m harness.commands.stereo 21 22 --scale 0.25 -o out/
    import argparse
    import sys

    from reference_models.errors import CamvalError
    ap = argparse.ArgumentParser(prog="camval stereo", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(ap)
    try:
        sys.exit(run(ap.parse_args()))
    except CamvalError as e:
        print(f"camval stereo: error: {e}", file=sys.stderr)
        sys.exit(2)
