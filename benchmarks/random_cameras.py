r'''Random plausible cameras as JPL model files, seeded: issue 16's bars on cameras nobody chose

SYNOPSIS

    uv run --frozen python benchmarks/random_cameras.py --seed S --n N --out DIR [--force]

Draws N cameras from the seed S and writes each as DIR/rnd<S>-<i>-<W>x<H>.<cahv|cahvor|cahvore>,
its draw in the file's note ('#' lines at the top: seed, index, size, field of view, family and
every distortion parameter). The same seed gives the same files, bit for bit. Prints one line per
camera and the comma-separated list of paths (for bench_corner_campaign.py --cameras).

THE DISTRIBUTION (what real cameras do, not what camval passes)

  size          width log-uniform over 320..5120 px; aspect from 4:3, 3:2, 16:9, 5:4, 1:1 (weighted
                to the common 4:3 and 3:2) and, one draw in eight, portrait (H > W); the height is
                clipped to 240..3840 and both are made even.
  field of view the horizontal field of view (field_of_view_deg: edge to edge through the middle
                row) from a mixture: 25% telephoto 15-40 deg, 45% normal 40-90 deg, 20% wide
                90-130 deg, 10% fisheye 130-180 deg (uniform in each). The focal length is solved
                (bisection) so that the written model has that field of view exactly.
  family        by field of view, as lenses are: below 90 deg CAHV 30%, CAHVOR 40%, CAHVORE 30%;
                90-130 deg CAHVOR 30%, CAHVORE 70%; above 130 deg CAHVORE only (no rectilinear lens
                covers that).
  CAHV          pixel skew theta (the angle between the image axes) uniform 89-91 deg, pixel
                aspect vs/hs 1 +- 0.5%.
  CAHVOR        theta 89.8-90.2 deg (a calibrated camera's axes are square to a few tenths);
                R0 +-0.005, R1 uniform -0.3..+0.2 (barrel..pincushion), R2 +-0.05; O tilted from A
                by up to 2 deg in a random direction.
  CAHVORE       type 2 (fisheye, linearity 0) one draw in three, else type 3 with linearity
                uniform 0..1 (type 3 draws whose field needs L * theta past 80 deg at the image
                corner are drawn again: no lens maps a ray at 90 deg to a finite point); R1
                -0.2..+0.1, R2 +-0.02 (chi^2 of a fisheye reaches 2.5); E small: E0 +-2 mm,
                E1 +-2 mm, E2 +-0.5 mm (the MER hazcams' pupils move by about a millimetre).
  all           principal point offset uniform up to 10% of the width and of the height; the
                camera's frame rotated at random (the catalogue's cameras point anywhere in
                their rovers' frames) and C within 1 m of the origin.

A draw whose mapping folds inside the image (the image radius not increasing with the ray's
angle out to the image corner, or a pixel that does not unproject and project back to itself
within 1e-6 px) is drawn again, its reason counted: no real lens folds. The count is printed.
Not a test, not a benchmark: the cameras' generator (tests/test_random_cameras.py).
'''

import argparse
import math
import sys
from pathlib import Path

import numpy as np

# (width:height, weight)
ASPECTS = ((4 / 3, 0.35), (3 / 2, 0.2), (16 / 9, 0.15), (5 / 4, 0.15), (1.0, 0.15))
PORTRAIT_P = 1 / 8
FOV_MIXTURE = (((15.0, 40.0), 0.25), ((40.0, 90.0), 0.45), ((90.0, 130.0), 0.20),
               ((130.0, 180.0), 0.10))
MAX_L_THETA_DEG = 80.0
FIT_TOL_DEG = 1e-9


def _pick(rng, items):
    w = np.array([x[1] for x in items], float)
    return items[int(rng.choice(len(items), p=w / w.sum()))][0]


def _rotation(rng):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    a, b, c, d = q
    return np.array([
        [a * a + b * b - c * c - d * d, 2 * (b * c - a * d), 2 * (b * d + a * c)],
        [2 * (b * c + a * d), a * a - b * b + c * c - d * d, 2 * (c * d - a * b)],
        [2 * (b * d - a * c), 2 * (c * d + a * b), a * a - b * b - c * c + d * d]])


def _tilted(rng, max_deg):
    r'''a unit vector within max_deg of +z, in the camera frame'''
    t = math.radians(rng.uniform(0.0, max_deg))
    az = rng.uniform(0.0, 2 * math.pi)
    return np.array((math.sin(t) * math.cos(az), math.sin(t) * math.sin(az), math.cos(t)))


def draw_size(rng):
    W = float(np.exp(rng.uniform(math.log(320), math.log(5120))))
    aspect = _pick(rng, ASPECTS)
    H = W / aspect
    if rng.uniform() < PORTRAIT_P:
        W, H = H, W
    W = int(round(min(max(W, 320), 5120) / 2)) * 2
    H = int(round(min(max(H, 240), 3840) / 2)) * 2
    return W, H


def draw_family(rng, hfov):
    if hfov < 90:
        return _pick(rng, (("CAHV", 0.3), ("CAHVOR", 0.4), ("CAHVORE", 0.3)))
    if hfov < 130:
        return _pick(rng, (("CAHVOR", 0.3), ("CAHVORE", 0.7)))
    return "CAHVORE"


def _fields(draw, f):
    r'''the model's fields (camera frame, then rotated) for focal length f (px)'''
    W, H = draw["width"], draw["height"]
    hs, vs = f, f * draw["aspect"]
    th = math.radians(draw["theta_deg"])
    cx, cy = (W - 1) / 2 + draw["dx"], (H - 1) / 2 + draw["dy"]
    # camera frame: A = z, H' = x, V' at theta to H' (theta 90: y)
    Ac = np.array((0.0, 0.0, 1.0))
    Hc = hs * np.array((1.0, 0.0, 0.0)) + cx * Ac
    Vc = vs * np.array((-math.cos(th), math.sin(th), 0.0)) + cy * Ac
    Rm = draw["rotation"]
    out = dict(C=list(draw["C"]), A=(Rm @ Ac).tolist(), H=(Rm @ Hc).tolist(),
               V=(Rm @ Vc).tolist(), width=W, height=H)
    if draw["family"] != "CAHV":
        out.update(O=(Rm @ draw["O"]).tolist(), R=list(draw["R"]))
    if draw["family"] == "CAHVORE":
        out.update(E=list(draw["E"]), model_type=draw["model_type"],
                   linearity=draw["linearity"])
    return out


def _model(draw, f):
    from reference_models.catalogue import model_from_fields
    return model_from_fields(_fields(draw, f), "random camera")


def _hfov(model):
    from reference_models.catalogue import field_of_view_deg
    with np.errstate(all="ignore"):
        try:
            h, _ = field_of_view_deg(model)
        except Exception:
            return math.nan
    return h


def _solve_focal(draw, hfov):
    r'''f (px) with the model's horizontal field of view hfov (bisection; the field falls as f
grows; an f whose edge rays do not unproject counts as too wide)'''
    W = draw["width"]
    lo, hi = W * 0.02, W * 50.0
    for _ in range(200):
        mid = math.sqrt(lo * hi)
        h = _hfov(_model(draw, mid))
        if not math.isfinite(h) or h > hfov:
            lo = mid
        else:
            hi = mid
        if hi / lo - 1 < 1e-14:
            break
    f = hi
    h = _hfov(_model(draw, f))
    if not (math.isfinite(h) and abs(h - hfov) < 1e-6):
        return None
    return f


def check_mapping(model):
    r'''None if the mapping is one-to-one over the image, else the reason in words'''
    W, H = model.width, model.height
    with np.errstate(all="ignore"):
        # pixels: the border and a grid
        u = np.linspace(-0.5, W - 0.5, 41)
        v = np.linspace(-0.5, H - 0.5, 31)
        q = np.stack(np.meshgrid(u, v), -1).reshape(-1, 2)
        try:
            origin, ray = model.unproject(q)
        except Exception as e:
            return f"unproject fails: {e}"
        if not np.all(np.isfinite(ray)):
            return "a pixel does not unproject"
        p = origin + ray * 10.0
        try:
            qb = model.project(p)
        except Exception as e:
            return f"project fails: {e}"
        qb = qb[0] if isinstance(qb, tuple) else qb
        err = np.max(np.hypot(*(np.asarray(qb) - q).T))
        if not err < 1e-6:
            return f"round trip {err:.2g} px"
        # along each of the four half-diagonals and the axes from the principal point: the
        # distance from the principal point grows with the angle to A
        A = np.asarray(model.A)
        cxy = np.array((np.asarray(model.H) @ A, np.asarray(model.V) @ A))
        for end in ((-0.5, -0.5), (W - 0.5, -0.5), (-0.5, H - 0.5), (W - 0.5, H - 0.5),
                    (-0.5, cxy[1]), (W - 0.5, cxy[1]), (cxy[0], -0.5), (cxy[0], H - 0.5)):
            t = np.linspace(0.0, 1.0, 400)[1:]
            qq = cxy + t[:, None] * (np.array(end) - cxy)
            _, rr = model.unproject(qq)
            ang = np.arccos(np.clip(rr @ A, -1, 1))
            if not (np.all(np.isfinite(ang)) and np.all(np.diff(ang) > 0)):
                return "the ray's angle does not grow outwards (the lens folds)"
    return None


def _draw_lens(rng, draw):
    family = draw["family"]
    if family == "CAHV":
        draw.update(theta_deg=float(rng.uniform(89.0, 91.0)),
                    aspect=float(rng.uniform(0.995, 1.005)))
        return
    draw.update(theta_deg=float(rng.uniform(89.8, 90.2)),
                aspect=float(rng.uniform(0.995, 1.005)), O=_tilted(rng, 2.0))
    if family == "CAHVOR":
        draw.update(R=[float(rng.uniform(-0.005, 0.005)), float(rng.uniform(-0.3, 0.2)),
                       float(rng.uniform(-0.05, 0.05))])
        return
    mtype = 2 if rng.uniform() < 1 / 3 else 3
    L = 0.0 if mtype == 2 else float(rng.uniform(0.0, 1.0))
    draw.update(model_type=mtype, linearity=L,
                R=[float(rng.uniform(-0.005, 0.005)), float(rng.uniform(-0.2, 0.1)),
                   float(rng.uniform(-0.02, 0.02))],
                E=[float(rng.uniform(-2e-3, 2e-3)), float(rng.uniform(-2e-3, 2e-3)),
                   float(rng.uniform(-5e-4, 5e-4))])


def _lens(draw):
    r"""(model, None) for a lens that gives the drawn field of view without folding, else
(None, the reason)"""
    f = _solve_focal(draw, draw["hfov"])
    if f is None:
        return None, "field of view not reachable"
    model = _model(draw, f)
    W, H = draw["width"], draw["height"]
    if draw["family"] == "CAHVORE" and draw["linearity"] > 0:
        # the ray at the image corner: L * theta within MAX_L_THETA_DEG
        with np.errstate(all="ignore"):
            _, rr = model.unproject(np.array(((-0.5, -0.5), (W - 0.5, -0.5),
                                              (-0.5, H - 0.5), (W - 0.5, H - 0.5))))
        th = np.degrees(np.arccos(np.clip(rr @ np.asarray(model.O), -1, 1)))
        if not (np.all(np.isfinite(th)) and np.max(th) * draw["linearity"] <= MAX_L_THETA_DEG):
            return None, "linearity too high for the field"
    why = check_mapping(model)
    if why is not None:
        return None, " ".join(why.split(" ")[:2])
    draw["focal"] = f
    return model, None


def draw_camera(rng, seed, index, counts, tries=100):
    r"""one camera -> (model, note, draw): the size, field of view, family, principal point and
frame first, then the lens (theta, O, R, E, linearity) drawn again until it reaches that field
without folding (the lens is drawn again, not the field: the size and field distributions stay
as documented; after `tries` lenses the whole camera is drawn again)"""
    from reference_models.catalogue import field_of_view_deg
    while True:
        W, H = draw_size(rng)
        hfov = float(rng.uniform(*_pick(rng, FOV_MIXTURE)))
        family = draw_family(rng, hfov)
        base = dict(seed=seed, index=index, width=W, height=H, hfov=hfov, family=family,
                    dx=float(rng.uniform(-0.1, 0.1) * W), dy=float(rng.uniform(-0.1, 0.1) * H),
                    rotation=_rotation(rng), C=rng.uniform(-1.0, 1.0, 3).tolist())
        for _ in range(tries):
            draw = dict(base)
            _draw_lens(rng, draw)
            model, why = _lens(draw)
            if model is not None:
                _, vfov = field_of_view_deg(model)
                draw["vfov"] = float(vfov)
                return model, note_of(draw), draw
            counts[why] = counts.get(why, 0) + 1
        counts["camera drawn again"] = counts.get("camera drawn again", 0) + 1


def note_of(d):
    fam = d["family"] if d["family"] != "CAHVORE" else f"CAHVORE type {d['model_type']}"
    lines = [f"random camera (benchmarks/random_cameras.py --seed {d['seed']}) #{d['index']}: "
             f"{fam} {d['width']}x{d['height']}, hfov {d['hfov']:.4f} deg "
             f"(vfov {d['vfov']:.2f}), f {d['focal']:.3f} px",
             f"draw: principal point offset ({d['dx']:+.2f}, {d['dy']:+.2f}) px, "
             f"theta {d['theta_deg']:.4f} deg, vs/hs {d['aspect']:.5f}"]
    if d["family"] != "CAHV":
        tilt = math.degrees(math.acos(min(1.0, d["O"][2])))
        lines.append(f"draw: O tilt {tilt:.3f} deg, R {', '.join(f'{x:+.5f}' for x in d['R'])}")
    if d["family"] == "CAHVORE":
        lines.append(f"draw: linearity {d['linearity']:.4f}, "
                     f"E {', '.join(f'{x:+.6f}' for x in d['E'])}")
    return "\n".join(lines)


def generate(seed, n):
    r'''[(name, model, note, draw)] for cameras 0..n-1 of the seed, and the redraw counts'''
    rng = np.random.default_rng(seed)
    counts = {}
    out = []
    ext = {"CAHV": "cahv", "CAHVOR": "cahvor", "CAHVORE": "cahvore"}
    for i in range(n):
        model, note, d = draw_camera(rng, seed, i, counts)
        out.append((f"rnd{seed}-{i}-{d['width']}x{d['height']}.{ext[d['family']]}",
                    model, note, d))
    return out, counts


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--seed", type=int, required=True)
    p.add_argument("--n", type=int, required=True)
    p.add_argument("--out", required=True)
    p.add_argument("--force", action="store_true", help="overwrite existing files")
    a = p.parse_args(argv)
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
    from reference_models.jpl_files import write_model

    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    cams, counts = generate(a.seed, a.n)
    paths = []
    for name, model, note, _ in cams:
        path = out / name
        write_model(model, path, overwrite=a.force, note=note)
        paths.append(str(path))
        print(f"{path}: {note.splitlines()[0]}")
    print(f"redrawn: {counts if counts else 'none'}")
    print(",".join(paths))


if __name__ == "__main__":
    main()
