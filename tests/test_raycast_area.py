r'''The ray caster's area coverage (its default; RenderSettings(options={"coverage": "area"}))

Every edge pixel's value is the albedo integrated over the pixel's preimage on
the board (renderers._raycast_kernels, "Area coverage"), to within
area_tolerance (1e-4 of the pixel's area) of the exact value. The references
here are independent of that machinery: the exact area of a disc and a
polygon (1-D quadrature), and pixels integrated line by line with exact rays,
the material transitions along each line found by bisection.
'''
import math

import numpy as np
import pytest
from numba import njit

from reference_models import kernels
from reference_models.cahvore import CAHV, CAHVOR, CAHVORE
from reference_models.errors import CamvalError
from renderers import _raycast_kernels as kern
from renderers.base import RenderSettings
from renderers.raycast import AREA_TOLERANCE, RaycastRenderer, Rt_board_ref, compile_pattern
from targets.boards import load_target
from targets.centroids import board_to_ref, polygon_centroid
from targets.pattern import Pattern

AREA = RenderSettings(spp=16, options={"coverage": "area"})


def _parts(width, height, f, cx, cy):
    A = np.array([0.0, 0.0, 1.0])
    return dict(C=np.array([0.1, -0.2, 0.3]), A=A, H=np.array([f, 0.0, 0.0]) + cx * A,
                V=np.array([0.0, f, 0.0]) + cy * A, width=width, height=height)


def _tilted(deg):
    t = math.radians(deg)
    return np.array([math.sin(t), 0.2 * math.sin(t), math.cos(t)])


def cameras():
    r'''A pinhole, a strongly distorted CAHVOR (about 10% radial at the corners) and a
noncentral CAHVORE (moving entrance pupil), small enough to integrate exactly'''
    return {
        "cahv": CAHV(**_parts(160, 120, 250.0, 81.3, 57.9)),
        "cahvor-strong": CAHVOR(O=_tilted(2.0), R=[0.0, -0.45, 0.1],
                                **_parts(160, 120, 220.0, 78.6, 61.2)),
        "cahvore-noncentral": CAHVORE(O=_tilted(2.0), R=[0.0, 0.02, -0.01],
                                      E=[0.01, 0.02, -0.005], model_type=3, linearity=0.37,
                                      **_parts(160, 120, 130.0, 79.5, 59.5)),
    }


def dots(n=5, spacing=0.1, r=0.032):
    g = np.arange(n) * spacing
    X, Y = np.meshgrid(g, g)
    circles = np.stack((X.ravel(), Y.ravel(), np.full(n * n, r)), axis=1)
    m = spacing
    return Pattern(extent=(-m, (n - 1) * spacing + m, -m, (n - 1) * spacing + m),
                   board_value=0.9, background_value=0.25, circles=circles, circle_value=0.05)


def board_pose(distance, euler_deg, centre=(0.2, 0.2)):
    from scipy.spatial.transform import Rotation
    R = Rotation.from_euler("xyz", euler_deg, degrees=True).as_matrix()
    t = np.array([0.0, 0.0, distance]) - R @ np.array([centre[0], centre[1], 0.0])
    return np.vstack((R, t))


# --- the integrals -----------------------------------------------------------------------------
def _disc_square_area(cx, cy, r, x0, x1, y0, y1):
    r'''Area of the disc (cx, cy, r) inside the box: adaptive quadrature over x of the
clipped chord, split where the chord's ends meet the box or the circle (~1e-12)'''
    from scipy.integrate import quad
    a, b = max(x0, cx - r), min(x1, cx + r)
    if b <= a:
        return 0.0

    def chord(x):
        h = math.sqrt(max(r * r - (x - cx) ** 2, 0.0))
        return max(min(cy + h, y1) - max(cy - h, y0), 0.0)

    breaks = [a, b]
    for yb in (y0, y1):
        if abs(yb - cy) < r:
            d = math.sqrt(r * r - (yb - cy) ** 2)
            breaks += [x for x in (cx - d, cx + d) if a < x < b]
    breaks = sorted(breaks)
    return sum(quad(chord, u, v, epsabs=1e-14, epsrel=1e-13, limit=200)[0]
               for u, v in zip(breaks[:-1], breaks[1:], strict=True))


@pytest.mark.parametrize("box", [(-0.3, 0.4, -0.2, 0.5), (0.5, 1.4, -0.2, 0.3),
                                 (-2.0, 2.0, -2.0, 2.0), (0.9, 1.1, 0.95, 1.3),
                                 (1.5, 2.0, 1.5, 2.0)])
@pytest.mark.parametrize("clockwise", [False, True])
def test_disc_polygon_area_and_moments_are_exact(box, clockwise):
    r'''Disc x polygon (Green's theorem along sides and arcs) against quadrature; the
orientation only flips the sign'''
    cx, cy, r = 0.2, 0.3, 1.0
    x0, x1, y0, y1 = box
    xs = np.array([x0, x1, x1, x0])
    ys = np.array([y0, y0, y1, y1])
    if clockwise:
        xs, ys = xs[::-1].copy(), ys[::-1].copy()
    poly = np.stack((xs, ys))
    a, mx, my = kern._disc_poly_moments(poly, 0, 4, cx, cy, r)
    sign = -1.0 if clockwise else 1.0
    exact = _disc_square_area(cx, cy, r, x0, x1, y0, y1)
    assert abs(sign * a - exact) < 1e-11
    # first moments about the centre: the area of the disc x box weighted by x - cx
    xx = np.linspace(x0, x1, 1201)
    yy = np.linspace(y0, y1, 1201)
    X, Y = np.meshgrid(xx, yy)
    inside = ((X - cx) ** 2 + (Y - cy) ** 2 <= r * r).astype(float)
    cell = (xx[1] - xx[0]) * (yy[1] - yy[0])
    # the grid's own error: ~ perimeter x cell side x |moment arm|
    tol = 4 * (x1 - x0 + y1 - y0) * (xx[1] - xx[0]) * 2.0
    assert abs(sign * mx - (inside * (X - cx)).sum() * cell) < tol
    assert abs(sign * my - (inside * (Y - cy)).sum() * cell) < tol
    # a polygon's own moments
    pa, pmx, pmy = kern._poly_moments(poly, 0, 4, 0.0, 0.0)
    assert sign * pa == pytest.approx((x1 - x0) * (y1 - y0), rel=1e-14)
    assert sign * pmx == pytest.approx((x1 - x0) * (y1 - y0) * (x0 + x1) / 2, rel=1e-12)
    assert sign * pmy == pytest.approx((x1 - x0) * (y1 - y0) * (y0 + y1) / 2, rel=1e-12)


@pytest.mark.parametrize("row", [0, 4])
def test_clipping_a_quadrilateral_by_a_box(row):
    # rows 0 (the board rectangle) and 4 (a cell) are what _quad_value clips in
    poly = np.zeros((6, kern.AREA_MAX_VERTICES))
    poly[row, :4] = [0.0, 2.0, 2.5, -0.5]
    poly[row + 1, :4] = [0.0, -0.5, 2.0, 1.5]
    n = kern._clip_box(poly, row, 4, 0.0, 1.0, 0.0, 1.0)
    a, _, _ = kern._poly_moments(poly, row, n, 0.0, 0.0)
    # the unit square lies inside the quadrilateral
    assert a == pytest.approx(1.0, abs=1e-14)


def _clip_sides(poly, row, n, x0, x1, y0, y1):
    # the four sides clipped one after the other, each by _clip (what _clip_box did before
    # it skipped the sides that keep every vertex)
    for side in range(4):
        first = side % 2 == 0
        value = (x0, x1, y0, y1)[side]
        n = kern._clip(poly, row if first else 2, n, side // 2, value, first, 2 if first else row)
    return n


@pytest.mark.parametrize("row", [0, 4])
def test_clip_box_skips_only_what_clipping_would_not_change(row):
    # quadrilaterals inside the box, across one, two or four of its sides, outside it, and
    # with vertices on its sides: _clip_box gives _clip's polygons, vertex for vertex (the
    # same floating-point operations, so the area coverage of a pixel is unchanged)
    rng = np.random.default_rng(1)
    quads = [np.array([[0.2, 0.8, 0.7, 0.1], [0.1, 0.2, 0.9, 0.6]]),
             np.array([[0.0, 1.0, 1.0, 0.0], [0.0, 0.0, 1.0, 1.0]]),
             np.array([[1.5, 2.0, 2.0, 1.5], [0.1, 0.1, 0.5, 0.5]])]
    quads += [c + rng.uniform(-0.6, 0.6, (2, 1)) + rng.uniform(-0.2, 0.2, (2, 4))
              for c in [np.array([[0.0, 1.0, 1.0, 0.0], [0.0, 0.0, 1.0, 1.0]])] * 200]
    kept = 0
    for q in quads:
        a = np.full((6, kern.AREA_MAX_VERTICES), np.nan)
        a[row:row + 2, :4] = q
        b = a.copy()
        na = kern._clip_box(a, row, 4, 0.0, 1.0, 0.0, 1.0)
        nb = _clip_sides(b, row, 4, 0.0, 1.0, 0.0, 1.0)
        assert na == nb
        np.testing.assert_array_equal(a[row:row + 2, :na], b[row:row + 2, :nb])
        kept += nb >= 3
    assert kept > 100


# --- pixels against an exact line-by-line integral ---------------------------------------------
@njit(cache=False)
def _exact_pixels(cam, xf, pix, lines, values, pat):
    r'''The albedo integrated over each pixel (ix, iy) of pix: midpoint rule over `lines`
rows, each row integrated exactly (material transitions by bisection of exact rays)'''
    out = np.empty(pix.shape[0])
    S = 64
    for p in range(pix.shape[0]):
        ix = pix[p, 0]
        iy = pix[p, 1]
        warm = kernels.warm_start(cam, ix, iy)
        acc = 0.0
        for m in range(lines):
            y = iy - 0.5 + (m + 0.5) / lines
            xa = ix - 0.5
            s, vx, vy, vz = kernels.ray_warm(cam, xa, y, warm)
            ok, bx, by = kern._hit(xf, s, vx, vy, vz)
            ma = kern._material(bx, by, pat) if ok else pat[1][0]
            row = 0.0
            for k in range(1, S + 1):
                xb = ix - 0.5 + k / S
                s, vx, vy, vz = kernels.ray_warm(cam, xb, y, warm)
                ok, bx, by = kern._hit(xf, s, vx, vy, vz)
                mb = kern._material(bx, by, pat) if ok else pat[1][0]
                lo = xb - 1.0 / S
                if mb != ma:
                    hi = xb
                    for _ in range(60):
                        mid = 0.5 * (lo + hi)
                        s, vx, vy, vz = kernels.ray_warm(cam, mid, y, warm)
                        ok, bx, by = kern._hit(xf, s, vx, vy, vz)
                        mm = kern._material(bx, by, pat) if ok else pat[1][0]
                        if mm == ma:
                            lo = mid
                        else:
                            hi = mid
                    row += values[ma] * (lo - xa) + values[mb] * (xb - lo)
                else:
                    row += values[ma] * (xb - xa)
                xa = xb
                ma = mb
            acc += row
        out[p] = acc / lines
    return out


def _kernel_inputs(model, pattern, Rt_cam_board):
    cam = kernels.pack_model(model)
    Rt = Rt_board_ref(model, Rt_cam_board)
    R, t = Rt[:3], Rt[3]
    xf = np.concatenate((R.ravel(), R @ model.C + t, R @ cam[12:15]))
    cp = compile_pattern(pattern)
    return cam, xf, cp


@pytest.mark.parametrize("name", ["cahv", "cahvor-strong", "cahvore-noncentral"])
@pytest.mark.parametrize("target", ["dots", "chessboard", "apriltag", "apriltag-far"])
def test_edge_pixels_are_the_exact_integral_within_the_bound(name, target):
    r'''Edge pixels (between the albedos) against the exact integral over the pixel: within
area_tolerance plus the reference's own error; the K = 16 point samples of the same
pixels are ~100x farther off'''
    model = cameras()[name]
    # the AprilTag board's margin corners lie beyond its cell grid on both axes
    pattern = dots() if target == "dots" else load_target(target.split("-")[0]).pattern()
    # (the AprilTag board near, whole bits over several pixels: its margin corners in view,
    # point sampled by the area path before a fix: 0.06-0.09% of the pixels; far, bits of
    # 0.6-1.3 px: a pixel over 16-100 of its cells, a fifth of a bit, was point sampled
    # while AREA_MAX_CELLS was 16)
    Rt = (board_pose(0.8, (20, 10, 0)) if target == "apriltag"
          else board_pose(3.1, (20, 10, 0), centre=(0.45, 0.45)) if target == "apriltag-far"
          else board_pose(0.9 if target == "dots" else 1.6, (35, -25, 10)))
    r = RaycastRenderer()
    area = r.render(model, pattern, Rt, AREA)
    point = r.render(model, pattern, Rt, RenderSettings(spp=16, options={"coverage": "point"}))
    md = area.metadata
    assert md["coverage"] == "area"
    # a mean of albedos: never past [0, 1], rounding included (an external renderer's check)
    assert area.image.min() >= 0.0 and area.image.max() <= 1.0
    assert md["area_fraction"] > 0.02
    assert md["area_point_sampled_fraction"] == 0.0
    img = area.image.astype(np.float64)
    # the mixed pixels: none of the pattern's albedos
    cand = np.argwhere(~np.isin(area.image, compile_pattern(pattern).values.astype(np.float32)))
    assert len(cand) > 100
    pix = cand[np.random.default_rng(0).choice(len(cand), 60, replace=False)][:, ::-1].copy()
    cam, xf, cp = _kernel_inputs(model, pattern, Rt)
    # the midpoint rule over rows errs where a boundary is tangent to a row or passes
    # a corner of the pixel; two resolutions bound it
    e1 = _exact_pixels(cam, xf, pix, 512, cp.values, cp.kernel_args())
    e2 = _exact_pixels(cam, xf, pix, 1024, cp.values, cp.kernel_args())
    ref_err = np.abs(e2 - e1)
    got = img[pix[:, 1], pix[:, 0]]
    # a float32 image of values <= 1 carries 6e-8; the bound is in units of the pixel's area
    # times the albedo span of its materials (<= 1)
    diff = np.abs(got - e2)
    assert np.all(diff <= AREA_TOLERANCE + ref_err + 1e-7), \
        (diff.max(), ref_err[np.argmax(diff)])
    pt = np.abs(point.image.astype(np.float64)[pix[:, 1], pix[:, 0]] - e2)
    assert np.sqrt(np.mean(diff ** 2)) < 0.05 * np.sqrt(np.mean(pt ** 2))


# --- centroids ---------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["cahv", "cahvor-strong", "cahvore-noncentral"])
def test_dot_centroids_are_the_exact_centroids(name):
    r'''Each dot's darkness-weighted centroid in the area-coverage image against the area
centroid of its projected outline: RMS <= 1e-3 px'''
    model = cameras()[name]
    # 2 x 2 dots of ~16 px radius: the darkness-weighted centroid of exact pixel values
    # (pixel centres standing for the pixels) is then itself within a few 1e-4 px of the
    # true one (8 px: ~1e-3); their windows (the outline's bounding box + 2 px) hold no
    # other dot
    r, s = 0.045, 0.15
    circles = np.array([[0.0, 0.0, r], [s, 0.0, r], [0.0, s, r], [s, s, r]])
    pattern = Pattern(extent=(-3 * r, s + 3 * r, -3 * r, s + 3 * r),
                      board_value=0.9, background_value=0.25, circles=circles,
                      circle_value=0.05)
    distance = r * model.photogrammetric().Hs / 16.0
    Rt = board_pose(distance, (30, -20, 15), centre=(s / 2, s / 2))
    img = RaycastRenderer().render(model, pattern, Rt, AREA).image.astype(np.float64)
    t = np.linspace(0, 2 * math.pi, 2880, endpoint=False)
    errors = []
    for cx, cy, rc in pattern.circles:
        outline = np.stack((cx + rc * np.cos(t), cy + rc * np.sin(t), 0 * t), axis=-1)
        q = model.project(board_to_ref(model, Rt, outline))
        lo = np.floor(q.min(axis=0)).astype(int) - 2
        hi = np.ceil(q.max(axis=0)).astype(int) + 3
        if lo.min() < 0 or hi[0] > model.width or hi[1] > model.height:
            continue
        w = pattern.board_value - img[lo[1]:hi[1], lo[0]:hi[0]]
        iy, ix = np.mgrid[lo[1]:hi[1], lo[0]:hi[0]]
        got = np.array([(w * ix).sum() / w.sum(), (w * iy).sum() / w.sum()])
        errors.append(np.linalg.norm(got - polygon_centroid(q)))
    errors = np.array(errors)
    assert len(errors) == 4
    assert np.sqrt(np.mean(errors ** 2)) <= 1e-3
    assert errors.max() <= 3e-3


# --- settings ----------------------------------------------------------------------------------
def test_area_coverage_is_the_default_and_point_sampling_an_option():
    model = cameras()["cahvor-strong"]
    pattern = dots()
    Rt = board_pose(0.9, (30, -20, 15))
    r = RaycastRenderer()
    default = r.render(model, pattern, Rt, RenderSettings(spp=8))
    point = r.render(model, pattern, Rt, RenderSettings(spp=8, options={"coverage": "point"}))
    assert default.metadata["coverage"] == "area"
    assert point.metadata["coverage"] == "point"
    assert "area_fraction" not in point.metadata
    area = r.render(model, pattern, Rt, RenderSettings(spp=8, options={"coverage": "area"}))
    assert np.array_equal(default.image, area.image)
    assert not np.array_equal(area.image, point.image)
    # away from the edges the two are the same pixels
    same = (area.image == point.image).mean()
    assert same > 0.9
    with pytest.raises(CamvalError, match="coverage"):
        r.render(model, pattern, Rt, RenderSettings(options={"coverage": "exact"}))
    with pytest.raises(CamvalError, match="area_tolerance"):
        r.render(model, pattern, Rt, RenderSettings(options={"coverage": "area",
                                                             "area_tolerance": 0.0}))
