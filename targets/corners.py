r'''Sub-pixel corners: fit the area-sampled image of the edges meeting at each corner

SYNOPSIS

    from targets.corners import refine_corners, wedge_area

    fit = refine_corners(img, q0, directions, wedges, steps, half_box)
    # img (H,W) float; q0 (N,2) coarse corners; directions (N,R,2) the image directions
    # of the R edges leaving each corner; wedges (W,2) ray indices (i, j): the dark
    # region is the union of the wedges from ray i to ray j; steps (N,2,2) the image
    # displacement of one board unit along the two board axes at the corner;
    # half_box: the window, |board offset| <= half_box along both axes
    fit.q          # (N,2) refined corners, NaN where dropped
    fit.reasons    # (N,) "" or why the corner was dropped
    fit.info       # the blur used: psf_sigma_px, psf_kind, psf_source (estimated / given)

What a renderer draws around a corner of a chessboard or of an AprilTag's black
border is a few straight board edges meeting at one point, seen through the
camera: within a window much smaller than the distance to the next feature,
the edges are rays from the corner (a homography keeps lines straight; lens
distortion bends them by (curvature x window^2), see below), the dark region
is a union of wedges between those rays (a chessboard: two opposite wedges;
an AprilTag's outer corner: one), and each pixel records the area average of
the albedo over its square [x-0.5, x+0.5] x [y-0.5, y+0.5]
(reference_models.conventions). So the model of pixel k is

    v_k = a + b * D_k(c, theta),   D_k = area of (pixel k) inside the dark wedges

with the corner c (2), the ray angles theta (R), the light level a and the
contrast b. D_k is exact: the area of a square inside a wedge of apex c is,
by Green's theorem with coordinates relative to c (the wedge's own rays add
nothing since they pass through c), half the sum over the square's edges of
cross(P - c, Q - c) times the fraction of the edge inside the wedge
(wedge_area). Its derivatives are exact too: moving the apex by dc changes
the area by the length of each ray inside the square times the ray's outward
normal, turning a ray by dtheta by (s1^2 - s0^2)/2 over the ray's stretch
[s0, s1] inside the square. refine_corners fits all corners at once by
Gauss-Newton (Levenberg-Marquardt damping) over (c, theta, a, b), in a window
of the pixels whose whole square lies within half_box board units of the
coarse corner along both board axes (the local affine map `steps`), and at
most MAX_WINDOW_PX pixels from it. An AprilTag's outer corner is dark only along its
1-bit border, light outside as far as the gap to the next tag: its window (tag_window)
is L-shaped, the box out to that gap with the tag's inside past the border cut out
(the box inside the border alone, 0.8 bit, left fewer than the 30 pixels then required on bits of
3 px and dropped half of the tag corners of a 640x480 hazcam, catalogue slot 17).

The model has no lens distortion: an edge of curvature kappa (1/px) crossing
a window of half-width w px is fitted by a straight ray, which moves the
corner by about kappa w^2 / 10: 0.004-0.007 px RMS on a MER hazcam fisheye
(catalogue slot 8), 2e-5 px on a navcam (15). curvature_bias predicts it from
a camera model and pose (first order in kappa), and the calibrators' bias
loop removes it (harness.calibrators.bias.corner_bias): 0.0005-0.0012 px RMS
left on K=64 ray-cast renders of slot 8 (benchmarks/bench_corners.py).

A renderer that samples each pixel at K x K points sees an edge parallel to
the pixel grid only to 1/(2K) px; the corners of a board posed without roll
(edges within 0.1 deg of the grid) inherit that: 0.006-0.013 px RMS, 0.03-0.05
px max at K = 16, 0.0003-0.002 at K = 64 (the same poses and cameras). The
ray caster's exact covered-area mode (RenderSettings options coverage = "area")
draws what this model assumes: corner error RMS before the bias correction
0.000014 px on navcam 15, 0.002-0.006 on hazcams 17 and 8 (edge curvature), and
after jpl's fit with corner_bias residual and projection difference RMS of
0.0007 px at most (campaigns/corners.toml, benchmarks/bench_corners.py
--coverage area).

The pixel-area model runs compiled (targets._corner_kernels, numba); kernel="numpy"
runs wedge_area instead (the reference, equal within 1e-12 px, tested). Detection
with refinement, CPU seconds per image (median; benchmarks/bench_corners.py timing
table, a machine at load 13-17 where the wall time is several times that): AprilTag
0.054 s on 1024x1024, 0.023 s on 640x480, 0.38-0.48 s on 5120x3840 (pupil_apriltags'
own search 0.26 s of it) before the L-shaped tag window, 0.086 s on 1024x1024 and 0.071 s
on 640x480 with it (load 11-17; docs/corners.md); with the window's pixel mask compiled
(targets._corner_kernels.window_mask) 0.064 s on 640x480, 0.081 s on 1024x1024, 0.21 s on
5120x3840 against 0.080, 0.099 and 0.33 s before it on the same images and load (14-16);
with working_image's one compiled pass, the light levels compiled and the normal
equations skipping the pixels no ray crosses (corners unchanged bit for bit) 0.045 s on
640x480, 0.059-0.070 s on 1024x1024, 0.14 s on 5120x3840 against 0.057, 0.067-0.077 and
0.16 s before (the least CPU of 12 detections of one image each, load 2.5);
with the compiled model skipping the clipping of pixels no ray comes near, each iteration's
end compiled (lm_accept), the AprilTag library reading the image in place and
working_image's min/max taken on integers (corners, drops and blur estimates unchanged bit
for bit) 0.040 s on 640x480, 0.054 s on 1024x1024, 0.094 s on 5120x3840 against 0.048,
0.076 and 0.133 s before (CPU, median over 6 images, benchmarks/bench_corners.py
--coverage area --cameras 9,17,21, load 3.8; the least of 3 per image: 0.036, 0.045-0.049,
0.094-0.10 against 0.050, 0.058-0.063, 0.135-0.145 s, load 5-8);
chessboard 0.045 s on 1024x1024 (this
fit 0.037 s of it), 0.043 s on 640x480, 0.19 s on 5120x3840.

Blur. A camera's optics blur the image (the `realistic` response profile of
campaigns/response.toml: a Gaussian PSF of sigma 0.7 px), and a sharp-edged model fitted
to a blurred corner is biased: a chessboard's X junction, its four rays free, fits a
kinked X whose apex slides along it (0.07-0.25 px RMS on navcam 15), an AprilTag's
L-shaped corner moves into its dark wedge. The model therefore includes the blur: each
pixel's value is the kernel's average of the exact pixel area over the PSF's offsets,
sum_q W_q A(d + Z_q) (blur_kernel: "gaussian", a Gaussian acting on the scene before
the pixel integrates it, or "sampled", a pixel-integrated Gaussian applied to the pixel
image as renderers.response's psf stage does), with a chessboard's opposite rays tied
into one line. The blur is estimated from the image (estimate_blur: sigma and the kind
fitted on up to BLUR_SAMPLE corners, the median kept, after a look at BLUR_QUICK_SAMPLE
corners with one kind finds any blur; a given psf_sigma_px skips it; the AprilTag grid
stops at the look, refine_corners(stop_if_blurred), and fits the blur on the tags' whole
edges, targets.tag_edges), and
each window keeps 3 sigma of blur (px, over the board unit's smallest image step) away
from the nearest feature it does not model (blurred_half_box). Noise-free, the blurred
chessboard and tag corners come out within 2e-4 px of the truth on navcam 15's renders
(sampled kernel, sigma estimated to 0.7005 px); with the profile's noise, 0.004 px
(chessboard) and 0.014-0.024 px (AprilTag: two edges of a few px in a window of ~0.5
bit) RMS (benchmarks/bench_corners.py --response realistic).

A corner is dropped, never kept at its coarse position, with its reason:
its window leaves the image or holds fewer than WINDOW_PIXELS_PER_UNKNOWN pixels
per unknown of its fit, the corner's predicted error (its misfit through the window's
normal equations) is above MAX_CORNER_SIGMA_PX (or NOISE_SIGMA_FACTOR x the image's
median on a noisy image), the fit did not converge in MAX_ITERATIONS, the corner moved out of its
window, the contrast is below MIN_CONTRAST of the image's range, or the
model misses the pixels by more than MAX_MISFIT of the contrast (RMS: a
blurred, occluded or misplaced corner).
'''

import math
from dataclasses import dataclass, field

import numpy as np

# the window's half-width cap (px): the fit's cost grows as its square, and the bias of
# edge curvature (kappa w^2 / 10) with it; 8 px is 200+ edge pixels per corner
MAX_WINDOW_PX = 8
# A window's size is judged by what its fit determines, not by a count of pixels: a window
# of n pixels holding K unknowns (light level, contrast, the corner's 2 coordinates, the
# rays' angles, the blur when fitted) needs n > K to be determined at all and to leave a
# misfit to judge it by (_fit); past that, a corner is kept when its predicted standard
# error is within what the records need (MAX_CORNER_SIGMA_PX). The predicted error is the
# fit's own: its misfit per pixel (RMS over the n - K degrees of freedom; whatever the
# model does not have: the render's sampling error, a neighbouring feature, sensor noise)
# through the window's normal equations (the larger axis of the corner's 2x2 covariance).
# A window of few pixels has few edge pixels per unknown and follows the image's errors
# rather than averaging them: its covariance is large, and so is its predicted error.
# (The fixed floor before, 30 pixels, dropped every chessboard corner of a 160x120 camera
# whose corners came out within 0.001 px elsewhere, and kept AprilTag corners of bits of
# 1.5-2 px off by up to 0.4 px: campaigns/cameras/tiny-320x240, mini-160x120.)
# the largest predicted standard error (px) of a kept corner: issue 16's bar on a record's
# residual and projection difference RMS (0.005 px): a corner predicted to err by more on
# its own cannot belong to a record held to it
MAX_CORNER_SIGMA_PX = 0.005
# pixels a window needs per unknown of its fit: one to determine it, one more to judge it
# (the misfit's degrees of freedom as many as the unknowns)
WINDOW_PIXELS_PER_UNKNOWN = 2
# a noisy image's corners all carry its noise (predicted errors of 0.004 px and more under
# campaigns/response.toml's `realistic` noise): there the limit is this many times the
# median predicted error of the image's corners, so that only the windows far less
# determined than the image's own (small or cut short) are dropped, not the noise
NOISE_SIGMA_FACTOR = 3.0
MAX_ITERATIONS = 50
# the first pass only places the second's window: it stops at this step (px)
FIRST_PASS_CONVERGED_PX = 1e-3
# px by which the first pass widens each pixel for the derivatives (refine_corners)
JACOBIAN_WIDEN = 0.1
# converged when a step moves the corner by less than this (px) and turns the rays by less
# than this over the window (rad x window px): a tenth of the accuracy sought (1e-3 px);
# the misfit is piecewise smooth (pixel areas), and near a kink the steps shrink slowly
CONVERGED_PX = 1e-4
# the model misfit (RMS / contrast) above which a window is not a sharp corner: a sharp
# exact render fits to its sampling error (1/K^2 of the contrast, K x K subsamples), sensor
# noise adds sigma/contrast (under 0.05 for any usable image); a blurred edge over a few px,
# an occluding object or a corner on the wrong feature misfits by 0.1 or more
MAX_MISFIT = 0.1
# contrast below this fraction of the image's range is no corner
MIN_CONTRAST = 0.2
# the blurred model: a product Gauss-Hermite rule of BLUR_ORDER nodes per axis for the
# expectation of the exact pixel area over the PSF's offsets (see _blur_rule)
BLUR_ORDER = 5
# the PSF's reach beyond which a pixel no longer sees an edge: 3 sigma (0.13% of the step)
BLUR_REACH_SIGMAS = 3.0
# corners the per-image blur estimate fits (spread over the image's corners): the median of
# 32 independent estimates has a scatter of ~1/4.5 of one corner's
BLUR_SAMPLE = 32
# corners of the first, one-kind look (estimate_blur's sample) that decides whether the
# image is blurred at all: the median of 8 sharp corners' sigmas sits ~1e-5 px from 0,
# a blur of BLUR_NEGLIGIBLE_PX or more reads as one on any of them
BLUR_QUICK_SAMPLE = 8
# the blur (px) assumed while the estimate places its windows: the windows shrink for it,
# so a neighbouring feature blurred by up to this much stays out of them
BLUR_PROBE_PX = 1.0
# the first guess of the blur estimate (px); the model is even in sigma, so not 0
BLUR_START_PX = 0.5
# the widest blur a fit may reach (px): 3 sigma of it fill the widest window, beyond which
# a window's edges no longer tell blur from light level and contrast (and the sampled
# kernel's taps, ~6 sigma across, would grow without bound on a window with no edge)
BLUR_MAX_PX = MAX_WINDOW_PX / BLUR_REACH_SIGMAS
# a blur below this (px) is fitted with the sharp model (9x cheaper): on top of the pixel's
# own area (variance 1/12 px^2) it moves a corner by O(sigma^2): < 1e-4 px (measured below)
BLUR_NEGLIGIBLE_PX = 0.02
# the quick look (BLUR_QUICK_SAMPLE corners) ends a corner's sigma fit once sigma is below
# this (px), a tenth of the BLUR_NEGLIGIBLE_PX its median is compared with. On a sharp image
# the model is flat in sigma there and Levenberg-Marquardt crawled on towards ~1e-5 px for
# 25-35 iterations (a few corners at a time, each iteration a round of Python calls). The
# fit comes down to a blur from BLUR_START_PX (the model is even in sigma: Gauss-Newton's
# next sigma is ~(sigma + s*^2 / sigma) / 2 >= s*), so a corner ended here would have ended
# in [0, this) too: the look's median within this of the full fits'. refine_corners looks
# again without the stop when a corner was ended and that could reach BLUR_NEGLIGIBLE_PX:
# the look's decisions are the full fits', its estimates of a sharp image in [0, this)
LOOK_SHARP_SIGMA_PX = BLUR_NEGLIGIBLE_PX / 10.0
# the quick look's corners come from the straightest quarter of the board's corners (the
# straight-edge model reads a line's bend within its window as blur: a sharp view of a
# random 646x364 fisheye, lines bent 0.0024 /px, read 0.152 px where its neighbours read 0);
# a quarter keeps them spread over the board
LOOK_STRAIGHT_FRACTION = 0.25


@dataclass(frozen=True, eq=False)
class CornerFit:
    r'''Refined corners

q:        (N,2) float64 refined corners, NaN where dropped
reasons:  (N,) str: "" for a refined corner, else why it was dropped
misfit:   (N,) RMS model misfit / contrast (NaN if not fitted)
npixels:  (N,) pixels in each window
iterations: Gauss-Newton iterations run (the most of any corner, summed over the passes)
directions: (N,R,2) the fitted unit directions of the rays (NaN where not fitted)
'''

    q: np.ndarray
    reasons: np.ndarray
    misfit: np.ndarray
    npixels: np.ndarray
    iterations: int = 0
    directions: np.ndarray = None
    info: dict = field(default_factory=dict)
    predicted_sigma: np.ndarray = None

    def dropped(self):
        r'''{reason: count} of the dropped corners'''
        out = {}
        for r in self.reasons:
            if r:
                key = r.split(":")[0]
                out[key] = out.get(key, 0) + 1
        return out


def _cross(a, b):
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


# the pixel square's corners relative to its centre, counter-clockwise in (x, y)
_SQUARE = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]])


def _ray_stretch(d, u, half=0.5):
    r'''[s0, s1]: the stretch of the ray s u (s >= 0, from the apex) inside a pixel square

d (...,2): pixel centre - apex; u (...,2) unit ray. s1 >= s0 >= 0, equal when the ray misses
the square (Liang-Barsky clipping).'''
    lo = np.zeros(d.shape[:-1])
    hi = np.full(d.shape[:-1], np.inf)
    for k in range(2):
        uk = u[..., k]
        a = d[..., k] - half
        b = d[..., k] + half
        with np.errstate(divide="ignore", invalid="ignore"):
            t0 = np.where(uk > 0, a / uk, b / uk)
            t1 = np.where(uk > 0, b / uk, a / uk)
        par = uk == 0
        inside = (a <= 0) & (b >= 0)
        t0 = np.where(par, np.where(inside, -np.inf, np.inf), t0)
        t1 = np.where(par, np.where(inside, np.inf, -np.inf), t1)
        lo = np.maximum(lo, t0)
        hi = np.minimum(hi, t1)
    miss = ~(hi > lo) | ~np.isfinite(hi)
    return np.where(miss, 0.0, lo), np.where(miss, 0.0, hi)


def wedge_area(d, u1, u2, derivatives=False, widen=0.0):
    r'''Area of a unit pixel square inside the wedge from ray u1 counter-clockwise to u2

SYNOPSIS

    A = wedge_area(d, u1, u2)                  # d (...,2) pixel centre - apex; A (...)
    A, dA_dc, dA_dt1, dA_dt2 = wedge_area(d, u1, u2, derivatives=True)
    # dA_dc (...,2) per apex move, dA_dt1, dA_dt2 (...) per ray turn (rad, counter-clockwise)

The wedge is {p : cross(u1, p) >= 0 and cross(p, u2) >= 0} (apex at the origin), an
angle below pi; u1, u2 unit vectors. Exact (Green's theorem, module docstring).

widen > 0 computes the derivatives on the square widened by that much on each side: the
area of a pixel that a ray is about to enter then already depends on the ray (see
refine_corners: a ray parallel to a pixel edge otherwise creeps up to it and stops).
'''
    d = np.asarray(d, dtype=np.float64)
    P = d[..., None, :] + _SQUARE                  # (...,4,2) square corners - apex
    Q = np.roll(P, -1, axis=-2)
    e = Q - P
    t0 = np.zeros(P.shape[:-1])
    t1 = np.ones(P.shape[:-1])
    # clip each edge P + t e to cross(u1, p) >= 0 and to cross(p, u2) = cross(-u2, p) >= 0
    for u in (u1[..., None, :], -u2[..., None, :]):
        f0 = _cross(u, P)
        g = _cross(u, e)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -f0 / g
        t0 = np.where(g > 0, np.maximum(t0, t), t0)
        t1 = np.where(g < 0, np.minimum(t1, t), t1)
        out = (g == 0) & (f0 < 0)
        t1 = np.where(out, t0, t1)
    frac = np.maximum(t1 - t0, 0.0)
    A = 0.5 * (frac * _cross(P, Q)).sum(axis=-1)
    if not derivatives:
        return A
    # the apex moves by dc: the square moves by -dc relative to it
    s0a, s1a = _ray_stretch(d, u1, 0.5 + widen)
    s0b, s1b = _ray_stretch(d, u2, 0.5 + widen)
    perp1 = np.stack((-u1[..., 1], u1[..., 0]), axis=-1)
    perp2 = np.stack((-u2[..., 1], u2[..., 0]), axis=-1)
    dA_dc = -(s1a - s0a)[..., None] * perp1 + (s1b - s0b)[..., None] * perp2
    dA_dt1 = -0.5 * (s1a ** 2 - s0a ** 2)
    dA_dt2 = 0.5 * (s1b ** 2 - s0b ** 2)
    return A, dA_dc, dA_dt1, dA_dt2


def _blur_rule(order=BLUR_ORDER):
    r'''(M,2) nodes and (M,) weights: E[f(z)] ~ sum w f(node), z a unit 2-D Gaussian'''
    x, w = np.polynomial.hermite_e.hermegauss(order)
    w = w / w.sum()
    nodes = np.stack(np.meshgrid(x, x, indexing="ij"), axis=-1).reshape(-1, 2)
    return np.ascontiguousarray(nodes), np.ascontiguousarray(np.outer(w, w).ravel())


BLUR_NODES, BLUR_WEIGHTS = _blur_rule()
# the kinds of blur kernel the model knows (blur_kernel)
PSF_KINDS = ("gaussian", "sampled")
# the sampled kernel's half-width: taps to 3 sigma beyond the pixel's half (the weight left
# out is below 0.05% per side)
SAMPLED_REACH_SIGMAS = 3.0


def blur_kernel(sigma, kind="gaussian"):
    r'''Offsets and weights of the blur kernel of each corner, and their sigma derivatives

SYNOPSIS

    Z, W, dZ, dW = blur_kernel(sigma, kind)
    # sigma (m,) px; Z (m,M,2) offsets (px), W (m,M) weights; dZ, dW per px of sigma

The blurred model of a pixel is sum_q W_q A(d + Z_q), A the exact area of the pixel
inside the dark wedges. Two kinds:

- "gaussian": optics: a Gaussian PSF acting on the scene before the pixel integrates it
  (kernel: the pixel's square convolved with the Gaussian). Z = sigma * BLUR_NODES,
  W = BLUR_WEIGHTS (product Gauss-Hermite, BLUR_ORDER per axis: the expectation of the
  pixel area over the PSF's offsets, 0.26% of the contrast RMS off the exact blur at
  sigma 0.7 px against 1.0% for order 3, tests/test_corners_blur.py).
- "sampled": a pixel-integrated Gaussian applied to the pixel image (what
  renderers.response's psf stage does, _pixel_gaussian_1d): integer offsets within
  SAMPLED_REACH_SIGMAS sigma, weights outer(k, k), k_j = Phi((j + 1/2) / sigma) -
  Phi((j - 1/2) / sigma) normalised. On an area-sampled image that is the pixel's square
  convolved twice (variance sigma^2 + 1/6 per axis, not sigma^2 + 1/12).
'''
    sigma = np.atleast_1d(np.asarray(sigma, dtype=np.float64))
    m = len(sigma)
    if kind == "gaussian":
        Z = sigma[:, None, None] * BLUR_NODES[None]
        W = np.broadcast_to(BLUR_WEIGHTS, (m, len(BLUR_WEIGHTS)))
        dZ = np.broadcast_to(BLUR_NODES, (m,) + BLUR_NODES.shape)
        dW = np.zeros(W.shape)
    elif kind == "sampled":
        from scipy.special import ndtr
        sg = np.maximum(sigma, 1e-3)
        nj = np.maximum(1, np.ceil(SAMPLED_REACH_SIGMAS * sg - 0.5)).astype(np.int64)
        n = int(nj.max())
        j = np.arange(-n, n + 1, dtype=np.float64)
        hi = (j + 0.5)[None] / sg[:, None]
        lo = (j - 0.5)[None] / sg[:, None]
        # each corner's own taps: zero weights beyond them (the compiled model skips them)
        own = np.abs(j)[None] <= nj[:, None]
        k = np.where(own, ndtr(hi) - ndtr(lo), 0.0)
        phi = lambda x: np.exp(-0.5 * x * x) / np.sqrt(2 * np.pi)  # noqa: E731
        dk = np.where(own, -(hi * phi(hi) - lo * phi(lo)) / sg[:, None], 0.0)
        S = k.sum(-1, keepdims=True)
        dS = dk.sum(-1, keepdims=True)
        dk = dk / S - k * dS / S ** 2
        k = k / S
        W = (k[:, :, None] * k[:, None, :]).reshape(m, -1)
        dW = (dk[:, :, None] * k[:, None, :] + k[:, :, None] * dk[:, None, :]).reshape(m, -1)
        jj = np.stack(np.meshgrid(j, j, indexing="ij"), axis=-1).reshape(-1, 2)
        Z = np.broadcast_to(jj, (m,) + jj.shape)
        dZ = np.zeros(Z.shape)
    else:
        raise ValueError(f"psf kind must be one of {PSF_KINDS}, not {kind!r}")
    return tuple(np.ascontiguousarray(x, dtype=np.float64) for x in (Z, W, dZ, dW))


def blurred_half_box(steps, half_box, clearance, sigma):
    r'''(N,) window half-widths (board units) that keep a blurred neighbour out

The window's pixels must not see the nearest other feature, clearance board units from
the corner along the box's axes (a number or (N,)): the PSF spreads it by
BLUR_REACH_SIGMAS sigma px, which is (that / the smallest image step of one board unit)
board units. Never above half_box (the sharp image's window, a number or (N,)).
'''
    steps = np.asarray(steps, dtype=np.float64).reshape(-1, 2, 2)
    smin = np.full(len(steps), np.nan)
    fin = np.all(np.isfinite(steps), axis=(-1, -2))
    if fin.any():
        smin[fin] = np.linalg.svd(steps[fin], compute_uv=False)[:, -1]
    half_box = np.broadcast_to(np.asarray(half_box, dtype=np.float64), (len(steps),))
    with np.errstate(divide="ignore", invalid="ignore"):
        hb = clearance - BLUR_REACH_SIGMAS * float(sigma) / smin
    return np.minimum(half_box, np.where(np.isfinite(hb), hb, half_box))


def line_strips(steps, clearance, sigma, curvature):
    r'''The strips a blurred chessboard corner's window adds along its two lines:
(lines_box (N,), strip_px, lines_px (N,)); lines_box NaN where there are none; see
refine_corners

Each line through an X junction is a straight edge as far as the next corner, a square
away, whose perpendicular line the blur spreads BLUR_REACH_SIGMAS sigma px towards it:
the strips keep to clearance (board units, a number or (N,)) less that reach less
LINES_SLACK (the local affine map's error there) along both board axes. Across a line a
pixel's value moves with the line's offset as the edge profile's slope, a Gaussian of
sigma_e = sqrt(added blur^2 + 1/12) px (the pixel's own square), so its information as
the slope squared, a Gaussian of sigma_e / sqrt(2): the pixels whose centres lie within
STRIP_SIGMAS sigma_e of the line hold 99.5% of it (strip_px; the window's box has the
light levels). Along it the noise of the line's offset at the corner falls as
1 / sqrt(length), and the edge information per px of line as 1 / sigma_e: lines_px =
MAX_WINDOW_PX x sigma_e / sqrt(1/12), the length whose information is the sharp
window's (MAX_WINDOW_PX of a sharp edge, sigma_e = sqrt(1/12)): 22 px at the
`realistic` profile's 0.7 px (its sampled kernel adds 0.755 px), where the box alone
(MAX_WINDOW_PX) left the corner noise 1.7x the sharp window's per unit of image noise.

A bent line (curvature (N,), 1/px: the larger of the corner's two lines') leaves its
tangent by kappa s^2 / 2 at s px, and the straight line fitted over +-L moves by about its
mean, kappa L^2 / 6 (0.016 px on camera 1's CAHVORE lines, kappa 2e-4 / px, at 22 px).
curvature_bias predicts that shift to first order in kappa, from the model's curvature and
the same strips: where the curvature is too small to shorten them (below the cap's), their
length does not depend on it, so the detector (curvature from its first pass's grid) and
the bias step (from the model) fit the same window. What the bias step cannot predict is
the next order, ~kappa^2 L^3 px (the edge's departure from its tangent against the blurred
profile's width; noise-free blurred renders: 1e-4 px RMS, 5e-4 max at kappa 2e-4 and L 22
px, 0.004 / 0.03 px at kappa 1e-3, where it is 0.011; with the cap at 1e-3 px, 0.0009 /
0.013 px on camera 17 against the box's 0.0004 / 0.003). So the strips end where that
reaches LINES_BIAS_PX (a fifth of the realistic dots' projection difference, ~1e-3 px: the
term is smooth over the board, so a fit does not average it away): L = (LINES_BIAS_PX /
kappa^2)^(1/3), all 22 px below kappa 1.3e-4, 16-22 px on camera 1, 5.8 px at kappa 1e-3
(a MER hazcam's fisheye: the box alone). Where that leaves no more than the box, no strips
(NaN; NaN curvature: none either). Under the cap the length depends on the curvature, as
kappa^(-2/3): 1% between the grid's curvature (the detector's length) and the model's (the
bias step's) moves the first-order bias kappa L^2 / 6 by 4/3% (_grid_curvature: 0.05%
inside the grid, 0.2% at its ends on camera 1).
'''
    steps = np.asarray(steps, dtype=np.float64).reshape(-1, 2, 2)
    sigma = float(sigma)
    se = math.sqrt(added_blur_px(sigma, "sampled") ** 2 + 1.0 / 12.0)
    box = blurred_half_box(steps, np.inf, clearance, sigma) - LINES_SLACK
    k = np.abs(np.broadcast_to(np.asarray(curvature, dtype=np.float64), (len(steps),)))
    with np.errstate(divide="ignore", invalid="ignore"):
        bent = np.cbrt(LINES_BIAS_PX / (k * k))
    reach = np.minimum(MAX_WINDOW_PX * se * math.sqrt(12.0), bent)
    none = ~(reach > MAX_WINDOW_PX)
    box = np.where(none, np.nan, box)
    reach = np.where(none, 0.0, reach)
    return box, STRIP_SIGMAS * se, reach


def _window(q0, steps, half_box, shape, max_px, notch=None, strips=None):
    r'''(N,P) pixel indices ix, iy and mask of each corner's window (half_box: a number
or (N,) per corner; notch: None, or a number or (N,): the pixels reaching past notch board
units along both axes at once are left out, an L-shaped window; strips: None, or
line_strips' (lines_box, strip_px, lines_px): the pixels along the board axes' lines
added)'''
    half_box = np.broadcast_to(np.asarray(half_box, dtype=np.float64), (len(q0),))
    lines_box, strip_px, lines_px = (np.full(len(q0), np.nan), 0.0, np.zeros(len(q0))) \
        if strips is None else strips
    r = int(max(max_px, np.max(lines_px, initial=0.0)))
    off = np.arange(-r, r + 1)
    oy, ox = np.meshgrid(off, off, indexing="ij")
    ox, oy = ox.ravel(), oy.ravel()
    c0 = np.round(q0).astype(np.int64)
    ix = c0[:, 0:1] + ox
    iy = c0[:, 1:2] + oy
    # board offsets of the pixel squares' corners (local affine map), compiled: the numpy
    # arrays of every square corner's offset were a fifth of a sharp image's detection
    from ._corner_kernels import window_mask
    notch = np.full(len(q0), np.nan) if notch is None else \
        np.broadcast_to(np.asarray(notch, dtype=np.float64), (len(q0),))
    lines_box = np.broadcast_to(np.asarray(lines_box, dtype=np.float64), (len(q0),))
    # writable C arrays always (broadcast_to's are read-only): one compiled signature, the
    # one harness.warmup compiles
    q0, Ainv, half_box, notch, lines_box, lines_px = (
        np.require(a, np.float64, ("C", "W"))
        for a in (q0, np.linalg.inv(steps), half_box, notch, lines_box, lines_px))
    inside, on_image = window_mask(ix, iy, q0, Ainv, half_box, notch, float(max_px),
                                   lines_box, float(strip_px), lines_px,
                                   int(shape[0]), int(shape[1]))
    return ix, iy, inside, on_image


def window_steps(directions, steps):
    r'''(N,2,2) the last pass's window axes (columns): rays 0 and 1 of directions (N,R,2),
unit, each as long as that column of steps (N,2,2), the image step of one board unit

refine_corners lays its second pass's box along the first pass's fitted rays (the helpers
below put the board axes there), the lengths the caller's steps (refine_chessboard_corners:
grid_steps; refine_tag_corners: tag_steps); the bias model lays its window so too
(harness.calibrators.bias.corner_bias: the model's tangents, corner_steps' lengths).'''
    d = np.asarray(directions, dtype=np.float64)
    steps = np.asarray(steps, dtype=np.float64)
    return np.stack((d[:, 0] * np.linalg.norm(steps[:, :, 0], axis=-1)[:, None],
                     d[:, 1] * np.linalg.norm(steps[:, :, 1], axis=-1)[:, None]), axis=-1)


def refine_corners(image, q0, directions, wedges, steps, half_box, *, psf_sigma_px=None,
                   psf_kind=None, clearance=None, lines=(), notch=None, notch_clearance=None,
                   stop_if_blurred=False, line_curvature=None, **options):
    r'''Refine corners by fitting the area-sampled wedge model; see the module docstring

SYNOPSIS

    fit = refine_corners(img, q0, directions, wedges, steps, half_box)

ARGUMENTS

- image: (H,W) float image (linear in albedo, any scale)
- q0: (N,2) coarse corners (NaN: not detected, reason "not detected")
- directions: (N,R,2) image directions of the R edges leaving each corner
- wedges: sequence of (i, j): the dark region is the union of the wedges between rays i and
  j (whichever way round is below pi; it must stay so for every corner)
- steps: (N,2,2) columns: image displacement of one board unit along the two board axes
- half_box: the window is the pixels whose square lies within half_box board units of the
  coarse corner along both axes (and within max_window_px px)
- psf_sigma_px: the image's blur, a Gaussian PSF's sigma (px) on top of the pixel's
  area: a number when the caller knows it (e.g. from a campaign's response stage), None
  (default) to estimate it from the image (estimate_blur), 0 for a sharp image
- psf_kind: the blur kernel's kind (blur_kernel: "gaussian" optics, "sampled" a blur of
  the pixel image); None (default): estimate_blur picks the one that fits the image
  better ("gaussian" when psf_sigma_px is given)
- clearance: board units from the corner to the nearest other feature along the box's
  axes, a number or (N,) one per corner (default half_box: no room to spare): the window
  shrinks so that the blurred feature stays out of it (blurred_half_box)
- lines: pairs of rays (i, j) that are one straight line through the corner (a
  chessboard's); fitted as one angle when the image is blurred, the blurred fit's window
  then adding strips along them (line_strips) as far as line_curvature allows: a
  function of the first pass's corners (N,2) (NaN where dropped) giving the lines'
  curvature at each corner (N,), 1/px; default None: no strips
- notch: None (the window is the box), or board units: the pixels reaching past notch
  along both axes at once (the quadrant the steps' columns point into) are left out, an
  L-shaped window about a corner whose model holds only in a strip along its edges there
  (an AprilTag's border: its data bits start one bit in); notch_clearance: board units
  from the corner to that feature (default notch), the notch shrinks for the blur as the
  box does for clearance
- stop_if_blurred: look at the blur first (one kind, on the first pass of
  BLUR_QUICK_SAMPLE corners) and return when it finds one (fit.q: those corners' first
  pass, NaN elsewhere; info["stopped"]): for a caller with its own blurred model, which
  fits the blur on it (targets.tag_edges)
- options: max_window_px, max_misfit, min_contrast (module constants by default);
  value_range: the image's max - min when the caller has it (the contrast test's scale;
  default: computed here, a pass over the image); kernel:
  "numba" (default: targets._corner_kernels, compiled) or "numpy" (wedge_area: the
  reference the compiled model is tested against, within 1e-12 px)

RETURNED VALUE

A CornerFit. Two passes: the second centres each window on the first pass's corner and
aligns it with the fitted rays (a coarse corner half a pixel off, or edge directions a few
degrees off under distortion, put the first window's box partly over the next feature).
The area of a pixel is piecewise smooth in the corner: a ray nearly parallel to a pixel
edge (a board seen without roll) moves the model of one pixel column only until it
crosses into the next, and Gauss-Newton with the exact derivatives creeps towards the
column's edge in ever smaller steps and stops there (0.25 px off, measured). The first
pass takes the derivatives over pixels widened by JACOBIAN_WIDEN px (an approximate
Jacobian: Levenberg-Marquardt still only accepts steps that lower the exact misfit); the
second polishes with the exact ones.

Blur: with sigma > 0 both passes fit the blurred model (the exact pixel area averaged over
the PSF's offsets, targets._corner_kernels.wedge_model); a sharp-edged model fitted to a
blurred L-shaped corner (an AprilTag's) would put it ~0.35 sigma inside the dark wedge.
With psf_sigma_px=None, the first pass fits sharp edges (its misfit not judged: it only
places the windows), then estimate_blur fits sigma per corner on up to BLUR_SAMPLE of them
and takes the median; fit.info has "psf_sigma_px", "psf_source" (given / estimated) and
the estimate's spread.
'''
    if notch is not None:
        notch_clearance = float(notch) if notch_clearance is None else float(notch_clearance)

    def notched(steps, sigma):
        return None if notch is None else blurred_half_box(steps, notch, notch_clearance, sigma)
    q0 = np.asarray(q0, dtype=np.float64).reshape(-1, 2)
    steps = np.asarray(steps, dtype=np.float64).reshape(len(q0), 2, 2)
    # a number, or one per corner
    half_box = np.broadcast_to(np.asarray(half_box, dtype=np.float64), (len(q0),))
    clearance = np.broadcast_to(half_box if clearance is None else
                                np.asarray(clearance, dtype=np.float64), (len(q0),))
    info = {}
    options = dict(options, lines=lines)
    # the last pass's corners are judged by their predicted error (_fit)
    max_sigma_px = options.pop("max_sigma_px", MAX_CORNER_SIGMA_PX)
    if psf_sigma_px is None:
        opts1 = dict(options, max_misfit=np.inf)
        sigma1 = 0.0
    else:
        sigma1 = float(psf_sigma_px)
        kind = psf_kind or "gaussian"
        options["psf_kind"] = kind
        opts1 = options
        info = {"psf_sigma_px": sigma1, "psf_source": "given", "psf_kind": kind}
    hb1 = blurred_half_box(steps, half_box, clearance, sigma1)
    nb1 = notched(steps, sigma1)
    notches = {} if notch is None else {"notch": notch, "notch_clearance": notch_clearance}
    kinds = PSF_KINDS if psf_kind is None else (psf_kind,)

    def first_pass(idx):
        # the sharp (or given-blur) pass about the coarse corners idx: the fit, the corners
        # it kept, their rays and the steps along them. The widened Jacobian is the sharp
        # model's (a blurred ray does not stop at a pixel column's edge): with a given blur
        # it took 17-21 iterations where the exact one takes 3-6 (realistic chessboards)
        f = _fit(image, q0[idx], np.asarray(directions)[idx], wedges, steps[idx], hb1[idx],
                 notch=None if nb1 is None else nb1[idx],
                 widen=JACOBIAN_WIDEN if sigma1 == 0.0 else 0.0,
                 converged_px=FIRST_PASS_CONVERGED_PX, sigma=sigma1, **opts1)
        good = np.all(np.isfinite(f.q), axis=-1)
        if not good.any():
            return f, good, None, None
        d = f.directions[good]
        return f, good, d, window_steps(d, steps[idx][good])

    def quick_look(f, good, d, s2, idx):
        # a sharp image (every clean render) is told by a few corners and one kind
        args = (image, f.q[good], d, wedges, s2, half_box[idx][good], clearance[idx][good])
        look = estimate_blur(*args, kinds=kinds[:1], sample=BLUR_QUICK_SAMPLE,
                             sharp_sigma_px=LOOK_SHARP_SIGMA_PX, **notches, **options)
        if look.get("psf_sharp_stops") and added_blur_px(
                look["psf_sigma_px"] + LOOK_SHARP_SIGMA_PX, look["psf_kind"]) >= BLUR_NEGLIGIBLE_PX:
            # the corners ended below LOOK_SHARP_SIGMA_PX could take the median to the blur
            # it is compared with: their fits to the end
            look = estimate_blur(*args, kinds=kinds[:1], sample=BLUR_QUICK_SAMPLE, **notches,
                                 **options)
        return look
    look = None
    if psf_sigma_px is None and stop_if_blurred:
        # the quick look first, on its own corners' first pass: a blurred image's corners
        # come from the caller's model (targets.tag_edges, started from the coarse corners:
        # the same corners to 2e-5 px RMS on the quick cameras' realistic renders), and
        # need no first pass of every corner (~0.04 s CPU per 1024x1024 image)
        live = np.flatnonzero(np.all(np.isfinite(q0), axis=-1))
        if line_curvature is not None and len(live) > BLUR_QUICK_SAMPLE:
            kap = np.asarray(line_curvature(q0), dtype=np.float64)[live]
            n = max(BLUR_QUICK_SAMPLE, int(LOOK_STRAIGHT_FRACTION * len(live)))
            live = np.sort(live[np.argsort(np.where(np.isfinite(kap), kap, np.inf),
                                           kind="stable")[:n]])
        pick = live[np.unique(np.linspace(0, len(live) - 1, min(len(live), BLUR_QUICK_SAMPLE))
                              .round().astype(np.int64))] if len(live) else live
        f, good, d, s2 = first_pass(pick)
        if good.any():
            look = quick_look(f, good, d, s2, pick)
            if _clearly_blurred(look):
                q = np.full(q0.shape, np.nan)
                q[pick] = f.q
                reasons = np.full(len(q0), "blurred: not fitted here", dtype=object)
                reasons[pick] = f.reasons
                return CornerFit(q=q, reasons=reasons, misfit=np.full(len(q0), np.nan),
                                 npixels=np.zeros(len(q0), np.int64), iterations=f.iterations,
                                 info=dict(look, stopped="blurred: the quick look's corners "
                                           "only"))
    fit, ok, dirs, steps2 = first_pass(np.arange(len(q0)))
    if not ok.any():
        return CornerFit(q=fit.q, reasons=fit.reasons, misfit=fit.misfit, npixels=fit.npixels,
                         iterations=fit.iterations, directions=fit.directions, info=info)
    if psf_sigma_px is None:
        # the full estimate (both kinds, BLUR_SAMPLE corners) only when the quick look sees
        # a blur
        info = look if look is not None else quick_look(fit, ok, dirs, steps2,
                                                        np.arange(len(q0)))
        if added_blur_px(info["psf_sigma_px"], info["psf_kind"]) >= BLUR_NEGLIGIBLE_PX:
            info = estimate_blur(image, fit.q[ok], dirs, wedges, steps2, half_box[ok],
                                 clearance[ok], kinds=kinds, **notches, **options)
        options["psf_kind"] = info["psf_kind"]
    sigma = info["psf_sigma_px"]
    if added_blur_px(sigma, options.get("psf_kind", "gaussian")) < BLUR_NEGLIGIBLE_PX:
        info = dict(info, psf_sigma_px=0.0, psf_sigma_estimated_px=sigma)
        sigma = 0.0
    elif stop_if_blurred:
        # (a given blur, or one the quick look's own corners did not show)
        return CornerFit(q=fit.q, reasons=fit.reasons, misfit=fit.misfit, npixels=fit.npixels,
                         iterations=fit.iterations, directions=fit.directions,
                         info=dict(info, stopped="blurred: first pass only"))
    hb2 = blurred_half_box(steps2, half_box[ok], clearance[ok], sigma)
    nb2 = notched(steps2, sigma)
    # a blurred X junction's lines are straight edges a square long: the window adds
    # strips along them (line_strips)
    # (the first pass's corners give the curvature: the coarse ones, ~0.1 px off, read
    # ~7e-5 / px on a navcam's straight 45 px squares, which would end its strips at 8 px)
    strips = line_strips(steps2, clearance[ok], sigma, line_curvature(fit.q)[ok]) \
        if sigma > 0.0 and len(lines) and line_curvature is not None else None
    fit2 = _fit(image, fit.q[ok], dirs, wedges, steps2, hb2, notch=nb2, sigma=sigma,
                strips=strips, max_sigma_px=max_sigma_px, **options)
    q, reasons = fit.q.copy(), fit.reasons.copy()
    misfit, npix, directions = fit.misfit.copy(), fit.npixels.copy(), fit.directions.copy()
    if nb2 is not None:
        # the strip along the edges inside the notch must hold pixels that neither blurred
        # edge reaches (its own, the feature's past it: nb2 keeps that one out), else the
        # model sees no dark level there and trades contrast for corner position (0.3-0.7
        # px off on 2.8 px tag bits at sigma 0.7 px, hazcam 17)
        # Sharp or blurred, a whole pixel must fit in each edge's strip (its width across the
        # edge: the notch along the other axis; a pixel's extent across an edge of direction
        # u is |u_x| + |u_y|, 1 to sqrt(2)), else no pixel of the window shows the dark level
        # in full: on tiny-320x240's exact renders (no pixel point sampled, seed 0) the
        # corners of strips narrower than that erred 0.012-0.016 px RMS, 0.12 max (162 of
        # 1677), the rest 0.0002-0.0009 RMS, 0.0024 max, whatever their pixel count
        u = steps2 / np.linalg.norm(steps2, axis=1, keepdims=True)      # columns: the edges
        across = np.abs(_cross(u[:, :, 0], u[:, :, 1]))
        width = nb2[:, None] * np.linalg.norm(steps2, axis=1)[:, ::-1] * across[:, None]
        narrow = ~np.all(width >= np.abs(u).sum(axis=1), axis=-1)
        fit2.q[narrow] = np.nan
        fit2.reasons[narrow] = "edge strip narrower than a pixel"
        smin = np.linalg.svd(steps2, compute_uv=False)[:, -1]
        thin = ~(nb2 * smin >= BLUR_REACH_SIGMAS * sigma + 0.5)
        fit2.q[thin] = np.nan
        fit2.reasons[thin] = "edge strip too thin for the blur"
    q[ok], reasons[ok], misfit[ok] = fit2.q, fit2.reasons, fit2.misfit
    npix[ok], directions[ok] = fit2.npixels, fit2.directions
    pred = np.full(len(q0), np.nan)
    pred[ok] = fit2.predicted_sigma
    return CornerFit(q=q, reasons=reasons, misfit=misfit, npixels=npix,
                     iterations=fit.iterations + fit2.iterations, directions=directions,
                     info=info, predicted_sigma=pred)


def _clearly_blurred(look):
    r'''True when a quick look's blur (estimate_blur on BLUR_QUICK_SAMPLE corners) is
beyond BLUR_NEGLIGIBLE_PX by 3 standard errors of its median (1.2533 x the estimates'
spread / sqrt(n)): a sharp render's few corners can read a blur of that size by chance
(0.023 px, spread 0.033 on 8 corners of a 5120x3840 fisheye), and such a look is checked
by the full estimate instead of stopping the window fit'''
    n = int(look.get("psf_estimates", 0))
    if n == 1:
        return False    # one corner's sigma has no spread (its MAD is 0): the full estimate
    n = max(n, 1)       # no count given: the median decides (its spread is unknown)
    spread = float(look.get("psf_sigma_spread_px", float("nan")))
    se = 1.2533 * spread / math.sqrt(n) if math.isfinite(spread) else 0.0
    low = max(float(look["psf_sigma_px"]) - 3.0 * se, 0.0)
    return added_blur_px(low, look["psf_kind"]) >= BLUR_NEGLIGIBLE_PX


def added_blur_px(sigma, kind="gaussian"):
    r'''The blur (px, standard deviation per axis) a kernel of this sigma and kind adds
to the pixel's own area: the sampled kernel's taps carry ~no weight below sigma ~0.2 px,
so its sigma wanders there on a sharp image (0.09-0.13 px measured on exact renders)
while it blurs nothing'''
    Z, W, _, _ = blur_kernel([max(float(sigma), 1e-3)], kind)
    return float(np.sqrt((W[0] * Z[0, :, 0] ** 2).sum()))


def estimate_blur(image, q, directions, wedges, steps, half_box, clearance, kinds=PSF_KINDS,
                  sample=None, notch=None, notch_clearance=None, sharp_sigma_px=0.0,
                  **options):
    r'''The image's Gaussian blur (px) from the edge profiles at its corners

SYNOPSIS

    info = estimate_blur(img, q, directions, wedges, steps, half_box, clearance)
    info["psf_sigma_px"]     # the median over the corners fitted; 0 for a sharp image

Fits the blurred model with sigma free (one sigma per corner, beside the corner, rays,
light level and contrast) on up to BLUR_SAMPLE corners spread over the list, in windows
kept BLUR_PROBE_PX of blur away from the next feature, and takes the median of the fits
that converged with a misfit below max_misfit. Each kind of kernel (blur_kernel) is
fitted; the one with the lower median misfit is kept ("psf_kind"; "psf_misfit" has each
kind's). The pixel's own area is in the model, so a sharp area-sampled render gives
sigma ~ 0 (1e-5 px). info also has "psf_sigma_spread_px" (the estimates' MAD x 1.4826),
"psf_estimates" (how many) and "psf_source" ("estimated"; "estimated (no corner fitted):
0" when none converged). sharp_sigma_px > 0 ends a corner's fit once its sigma is below it
(the quick look's LOOK_SHARP_SIGMA_PX: its estimates of a sharp image then lie in [0, it),
the median within it of the full fits'); "psf_sharp_stops" counts the corners it ended.
'''
    q = np.asarray(q, dtype=np.float64).reshape(-1, 2)
    n = len(q)
    sample = BLUR_SAMPLE if sample is None else int(sample)
    pick = np.unique(np.linspace(0, n - 1, min(n, sample)).round().astype(np.int64))
    steps = np.asarray(steps, dtype=np.float64).reshape(n, 2, 2)[pick]
    clearance = np.broadcast_to(np.asarray(clearance, dtype=np.float64), (n,))[pick]
    half_box = np.broadcast_to(np.asarray(half_box, dtype=np.float64), (n,))[pick]
    hb = blurred_half_box(steps, half_box, clearance, BLUR_PROBE_PX)
    if notch is not None and notch_clearance is None:
        notch_clearance = notch
    nb = None if notch is None else blurred_half_box(steps, notch, notch_clearance,
                                                      BLUR_PROBE_PX)
    options.pop("psf_kind", None)
    best, misfits, stops = None, {}, 0
    # small features (AprilTag bits of 3-4 px) leave windows too small to fit once
    # shrunk for BLUR_PROBE_PX: then the sharp image's windows (a blurred neighbour may
    # reach into them; a blur estimate slightly high beats none: 0.3 px errors, camera 17)
    for box, nbox in ((hb, nb), (half_box, notch)):
        for kind in kinds:
            fit = _fit(image, q[pick], np.asarray(directions)[pick], wedges, steps, box,
                       notch=nbox,
                       sigma=BLUR_START_PX, fit_sigma=True, psf_kind=kind,
                       sharp_sigma=sharp_sigma_px, **options)
            good = fit.reasons == ""
            if fit.predicted_sigma is not None:
                good &= np.isfinite(fit.predicted_sigma)
            sig = fit.info.get("sigma", np.full(len(good), np.nan))
            stops += int(np.count_nonzero(sig < sharp_sigma_px))
            est = np.abs(sig[good])
            if not len(est):
                continue
            mis = float(np.median(fit.misfit[good]))
            misfits[kind] = mis
            if best is None or mis < best[0]:
                best = (mis, kind, est)
        if best is not None:
            break
    stopped = {"psf_sharp_stops": stops} if sharp_sigma_px > 0.0 else {}
    if best is None:
        return {"psf_sigma_px": 0.0, "psf_source": "estimated (no corner fitted): 0",
                "psf_kind": kinds[0], "psf_estimates": 0, "psf_sigma_spread_px": float("nan"),
                **stopped}
    _, kind, est = best
    med = float(np.median(est))
    return {"psf_sigma_px": med, "psf_source": "estimated", "psf_kind": kind,
            "psf_misfit": misfits, "psf_estimates": int(len(est)),
            "psf_sigma_spread_px": float(1.4826 * np.median(np.abs(est - med))), **stopped}


def _ray_angles(tied, R):
    r'''T (R,L): ray r turns with angle parameter l where T[r, l] = 1: each pair (i, j) of
tied (one straight line) one parameter, then each other ray its own'''
    free = [r for r in range(R) if not any(r in p for p in tied)]
    T = np.zeros((R, len(tied) + len(free)))
    for col, (i, j) in enumerate(tied):
        T[i, col] = T[j, col] = 1.0
    for col, r in enumerate(free, start=len(tied)):
        T[r, col] = 1.0
    return T


def _fit(image, q0, directions, wedges, steps, half_box, *, notch=None,
         max_window_px=MAX_WINDOW_PX,
         max_misfit=MAX_MISFIT, min_contrast=MIN_CONTRAST, widen=0.0,
         converged_px=CONVERGED_PX, kernel="numba", value_range=None, sigma=0.0,
         fit_sigma=False, lines=(), psf_kind="gaussian", strips=None, sharp_sigma=0.0,
         max_sigma_px=None, min_window_pixels=0):
    r'''One pass of refine_corners (the window about q0, half_box a number or (N,); widen:
see wedge_area; kernel: "numba" the compiled pixel-area model of targets._corner_kernels,
"numpy" wedge_area's; sigma: the Gaussian blur, px, fitted per corner from there with
fit_sigma, the fits in info["sigma"], a corner's fit ending once its sigma is below
sharp_sigma (LOOK_SHARP_SIGMA_PX); lines: pairs of rays (i, j) fitted as one straight
line through the corner when sigma > 0)'''
    if kernel not in ("numba", "numpy"):
        raise ValueError(f"kernel must be 'numba' or 'numpy', not {kernel!r}")
    # float32 stays float32 (the windows' pixels are taken as float64 below): a large
    # image is not copied
    img = np.asarray(image)
    if img.dtype not in (np.float32, np.float64):
        img = img.astype(np.float64)
    q0 = np.asarray(q0, dtype=np.float64).reshape(-1, 2)
    N = len(q0)
    dirs = np.asarray(directions, dtype=np.float64).reshape(N, -1, 2)
    steps = np.asarray(steps, dtype=np.float64).reshape(N, 2, 2)
    reasons = np.full(N, "", dtype=object)
    q = np.full((N, 2), np.nan)
    misfit = np.full(N, np.nan)
    npix = np.zeros(N, np.int64)
    ok = np.all(np.isfinite(q0), axis=-1) & np.all(np.isfinite(dirs), axis=(-1, -2)) \
        & np.all(np.isfinite(steps), axis=(-1, -2))
    ok[ok] &= np.abs(np.linalg.det(steps[ok])) > 1e-12
    reasons[~ok] = "not detected"
    if not ok.any():
        return CornerFit(q=q, reasons=reasons, misfit=misfit, npixels=npix)
    idx = np.flatnonzero(ok)
    half_box = np.broadcast_to(np.asarray(half_box, dtype=np.float64), (N,))
    if notch is not None:
        notch = np.broadcast_to(np.asarray(notch, dtype=np.float64), (N,))[idx]
    if strips is not None:
        strips = (np.broadcast_to(np.asarray(strips[0], dtype=np.float64), (N,))[idx],
                  strips[1], np.broadcast_to(np.asarray(strips[2], dtype=np.float64), (N,))[idx])
    ix, iy, inside, on_image = _window(q0[idx], steps[idx], half_box[idx], img.shape,
                                       max_window_px, notch, strips)
    off = (inside & ~on_image).any(axis=-1)
    n_in = (inside & on_image).sum(axis=-1)
    npix[idx] = n_in
    # unknowns: light level, contrast, corner (2), the rays' angles (tied pairs one), the
    # blur when fitted. A window of n pixels determines them when n > K, and its misfit
    # (what judges the fit, and its predicted error) has n - K degrees of freedom: as many
    # as the unknowns at least (WINDOW_PIXELS_PER_UNKNOWN), else a fit through every pixel
    # reads as exact (a 160x120 camera's 9-pixel chessboard windows, 8 unknowns: misfit
    # 2e-7 of the contrast 0.27 px off)
    n_unknowns = 4 + dirs.shape[1] - (len(lines) if (float(sigma) > 0.0 or fit_sigma) else 0) \
        + int(bool(fit_sigma))
    need = max(WINDOW_PIXELS_PER_UNKNOWN * n_unknowns, int(min_window_pixels))
    few = ~off & (n_in < need)
    reasons[idx[off]] = "window off the image"
    reasons[idx[few]] = f"window too small: fewer than {need} pixels for {n_unknowns} unknowns"
    keep = ~off & ~few
    rows = np.flatnonzero(keep)
    idx = idx[rows]
    if not len(idx):
        return CornerFit(q=q, reasons=reasons, misfit=misfit, npixels=npix)
    # each window's pixels first, then only as many columns as the largest window has: the
    # pixels' values (float64), weights (1 inside) and centres, one compiled pass
    from ._corner_kernels import window_pixels
    v, w, centres = window_pixels(ix, iy, inside, rows, img)

    # the rays' angles; each wedge (i, j) oriented per corner so that its angle is below pi
    u = dirs[idx]
    theta = np.arctan2(u[..., 1], u[..., 0])                 # (n,R)
    wedges = np.asarray(wedges, dtype=np.int64).reshape(-1, 2)
    ui = u[:, wedges[:, 0]]
    uj = u[:, wedges[:, 1]]
    flip = _cross(ui, uj) < 0                                # (n,Nw)
    first = np.ascontiguousarray(np.where(flip, wedges[None, :, 1], wedges[None, :, 0]))
    second = np.ascontiguousarray(np.where(flip, wedges[None, :, 0], wedges[None, :, 1]))
    c = q0[idx].copy()
    n, R = theta.shape
    sig = np.full(n, float(sigma))
    # T (R,L): ray r turns with angle parameter l where T[r, l] = 1. Blurred, the rays of a
    # line are tied: four free rays let a blurred X junction fit a kinked X whose apex
    # slides along it (0.25 px on navcam 15 chessboards, sigma 0.7 px)
    tied = [tuple(p) for p in lines] if (float(sigma) > 0.0 or fit_sigma) else []
    T = _ray_angles(tied, R)
    for i, j in tied:
        # start the line from both rays' directions, exactly opposite
        phi = np.arctan2(u[:, i, 1] - u[:, j, 1], u[:, i, 0] - u[:, j, 0])
        theta[:, i], theta[:, j] = phi, phi + np.pi
    L = T.shape[1]
    blurred = float(sigma) > 0.0 or fit_sigma

    def model(s, c, theta, sg):
        # D (m,P) dark area of each window pixel and its derivatives, for the corners s;
        # with fit_sigma the blur's derivative is the last column of dD_dt
        uu = np.stack((np.cos(theta), np.sin(theta)), axis=-1)     # (m,R,2)
        if blurred:
            Z, W, dZ, dW = blur_kernel(sg, psf_kind)
        else:
            Z, dZ = np.zeros((len(s), 1, 2)), np.zeros((len(s), 1, 2))
            W, dW = np.ones((len(s), 1)), np.zeros((len(s), 1))
        if kernel == "numba":
            from ._corner_kernels import wedge_model
            # writable C arrays always (blur_kernel's cached kernels are read-only): one
            # compiled signature, the one harness.warmup compiles
            Z, W, dZ, dW = (np.require(a, np.float64, ("C", "W")) for a in (Z, W, dZ, dW))
            D, dD_dc, dD_dt, dD_ds = wedge_model(
                centres, np.ascontiguousarray(s, dtype=np.int64), np.ascontiguousarray(c),
                uu, first, second, float(widen), Z, W, dZ, dW)
        else:
            d0 = centres[s] - c[:, None, :]
            m = len(s)
            D = np.zeros(d0.shape[:-1])
            dD_dc = np.zeros(d0.shape)
            dD_dt = np.zeros(d0.shape[:-1] + (R,))
            dD_ds = np.zeros(d0.shape[:-1])
            for q in range(W.shape[1]):
                d = d0 + Z[:, q][:, None, :]
                wz = W[:, q][:, None]
                for k in range(first.shape[1]):
                    i1, i2 = first[s, k], second[s, k]
                    u1 = uu[np.arange(m), i1][:, None, :]
                    u2 = uu[np.arange(m), i2][:, None, :]
                    A, dA_dc, dA_dt1, dA_dt2 = wedge_area(
                        d, np.broadcast_to(u1, d.shape), np.broadcast_to(u2, d.shape), True,
                        widen)
                    D += wz * A
                    dD_dc += wz[..., None] * dA_dc
                    dD_dt += wz[..., None] * (
                        dA_dt1[..., None] * (np.arange(R) == i1[:, None])[:, None, :]
                        + dA_dt2[..., None] * (np.arange(R) == i2[:, None])[:, None, :])
                    dD_ds += dW[:, q][:, None] * A \
                        - wz * (dA_dc * dZ[:, q][:, None, :]).sum(-1)
        if tied:
            dD_dt = dD_dt @ T
        if fit_sigma:
            dD_dt = np.concatenate((dD_dt, dD_ds[..., None]), axis=-1)
        return D, dD_dc, np.ascontiguousarray(dD_dt)

    def linear(s, D):
        # light level a and contrast b for the current geometry (weighted least squares)
        from ._corner_kernels import light_levels
        return light_levels(s, np.ascontiguousarray(D), w, v)

    alls = np.arange(n)
    D, dD_dc, dD_dt = model(alls, c, theta, sig)
    a, b, S, r = linear(alls, D)
    K = 4 + L + int(bool(fit_sigma))
    lam = np.full(n, 1e-3)
    prev = np.zeros((n, K))
    converged = np.zeros(n, bool)
    it = 0
    eye = np.eye(K)
    if kernel == "numba":
        # each corner's normal equations, kept from one step that changes its model to the
        # next (lm_accept): the model's (P,...) arrays are not carried over
        from ._corner_kernels import lm_accept, lm_system, normal_equations
        JtJ_all, Jtr_all = normal_equations(D, dD_dc, dD_dt, b, w, r)
    while it < MAX_ITERATIONS and not converged.all():
        it += 1
        s = np.flatnonzero(~converged)
        # Jacobian of the model in (a, b, cx, cy, theta...) for the corners still fitting
        if kernel == "numba":
            # damped in the kernel, with the numpy branch's arithmetic
            A, Jtr = lm_system(s, JtJ_all, lam), Jtr_all[s]
        else:
            J = np.concatenate((np.ones(D[s].shape + (1,)), D[s][..., None],
                                b[s, None, None] * dD_dc[s], b[s, None, None] * dD_dt[s]),
                               axis=-1)
            Jw = J * w[s][..., None]
            JtJ = Jw.transpose(0, 2, 1) @ J
            Jtr = (Jw.transpose(0, 2, 1) @ r[s][..., None])[..., 0]
            diag = np.einsum("nii->ni", JtJ)
            A = JtJ + (lam[s, None] * diag)[:, :, None] * eye + 1e-12 * eye
        step = np.linalg.solve(A, Jtr[..., None])[..., 0]
        # a singular system (a window that does not determine the fit) takes no step: the
        # fit ends where it is, and the predicted error (inf) drops the corner
        step[~np.all(np.isfinite(step), axis=-1)] = 0.0
        c1 = c[s] + step[:, 2:4]
        t1 = theta[s] + step[:, 4:4 + L] @ T.T
        # the model is even in sigma: keep it positive
        g1 = np.minimum(np.abs(sig[s] + step[:, 4 + L]), BLUR_MAX_PX) if fit_sigma \
            else sig[s]
        D1, dD_dc1, dD_dt1 = model(s, c1, t1, g1)
        a1, b1, S1, r1 = linear(s, D1)
        if kernel == "numba":
            # the acceptance, damping and convergence of the numpy branch below, compiled:
            # one call for its ~20 array operations per iteration (the same bits), and the
            # normal equations of the corners whose model changed
            lm_accept(s, np.ascontiguousarray(step), S1, c1, np.ascontiguousarray(t1),
                      np.ascontiguousarray(g1, dtype=np.float64), D1, dD_dc1, dD_dt1, a1, b1,
                      r1, w, c, theta, sig, a, b, S, lam, prev, converged, JtJ_all, Jtr_all,
                      float(converged_px), float(max_window_px))
            if sharp_sigma > 0.0:
                converged[s] |= sig[s] < sharp_sigma
            continue
        better = S1 <= S[s]
        sb = s[better]
        c[sb], theta[sb], sig[sb] = c1[better], t1[better], g1[better]
        D[sb], dD_dc[sb], dD_dt[sb] = D1[better], dD_dc1[better], dD_dt1[better]
        a[sb], b[sb], S[sb], r[sb] = a1[better], b1[better], S1[better], r1[better]
        # a step back along the last accepted one is a zig-zag across a kink of the misfit
        # (pixel areas are piecewise smooth): damp it like a failed step
        zig = (step * prev[s]).sum(-1) < -0.5 * np.linalg.norm(step, axis=-1) \
            * np.linalg.norm(prev[s], axis=-1)
        lam[s] = np.where(better & ~zig, np.maximum(lam[s] * 0.3, 1e-6), lam[s] * 10.0)
        prev[sb] = step[better]
        dc = np.abs(step[:, 2:4]).max(-1)
        small = (dc < converged_px) & (np.abs(step[:, 4:]).max(-1) * max_window_px < converged_px)
        # a damping this large moves nothing: the fit is at its minimum to rounding
        converged[s] = (better & small) | ((lam[s] > 1e6) & (dc < converged_px))
        if sharp_sigma > 0.0:
            converged[s] |= sig[s] < sharp_sigma
    if value_range is not None:
        rng = float(value_range)
    else:
        rng = float(np.nanmax(img) - np.nanmin(img)) if img.size else 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        mis = np.sqrt(S / w.sum(-1)) / np.abs(b)
    misfit[idx] = mis
    # each corner's predicted standard error (px): the misfit per degree of freedom through
    # the window's normal equations at the fit (the larger axis of the corner's covariance)
    if kernel == "numba":
        JtJ = JtJ_all
    else:
        J = np.concatenate((np.ones(D.shape + (1,)), D[..., None], b[:, None, None] * dD_dc,
                            b[:, None, None] * dD_dt), axis=-1)
        JtJ = (J * w[..., None]).transpose(0, 2, 1) @ J
    dof = np.maximum(w.sum(-1) - K, 1.0)
    pred = _predicted_sigma(JtJ, S / dof)
    # the corner must stay inside its window: its board offset from the coarse corner
    rel = np.einsum("nij,nj->ni", np.linalg.inv(steps[idx]), c - q0[idx])
    moved = np.abs(rel).max(-1) > half_box[idx]
    why = np.full(len(idx), "", dtype=object)
    why[~converged] = f"fit not converged in {MAX_ITERATIONS} iterations"
    why[converged & moved] = "corner moved out of its window"
    low = converged & ~moved & ~(np.abs(b) > min_contrast * rng)
    why[low] = "no contrast"
    bad = converged & ~moved & ~low & ~(mis <= max_misfit)
    why[bad] = [f"misfit: {m:.3g} of the contrast (blurred or occluded)" for m in mis[bad]]
    if max_sigma_px is not None:
        judged = converged & ~moved & ~low & ~bad
        fin = judged & np.isfinite(pred)
        limit = max(float(max_sigma_px), NOISE_SIGMA_FACTOR * float(np.median(pred[fin]))) \
            if fin.any() else float(max_sigma_px)
        loose = judged & ~(pred <= limit)
        why[loose] = [f"predicted error too large: {p:.3g} px, above {limit:.3g} px"
                      for p in pred[loose]]
    sigma_pred = np.full(N, np.nan)
    sigma_pred[idx] = pred
    good = why == ""
    q[idx[good]] = c[good]
    reasons[idx] = why
    directions = np.full(dirs.shape, np.nan)
    directions[idx] = np.stack((np.cos(theta), np.sin(theta)), axis=-1)
    sigmas = np.full(N, np.nan)
    sigmas[idx] = sig
    return CornerFit(q=q, reasons=reasons, misfit=misfit, npixels=npix, iterations=it,
                     directions=directions, info={"sigma": sigmas},
                     predicted_sigma=sigma_pred)


def _predicted_sigma(JtJ, noise_var):
    r'''(n,) the corners' predicted standard error (px): sqrt(noise_var x the larger
eigenvalue of the (cx, cy) block of (J^T W J)^-1), inf where the normal equations are
singular (a window that does not determine the fit)'''
    n = len(JtJ)
    out = np.full(n, np.inf)
    if not n:
        return out
    # equilibrated (unit diagonal) before the condition test and the inverse
    scale = np.sqrt(np.maximum(np.einsum("nii->ni", JtJ), 1e-300))
    Js = JtJ / (scale[:, :, None] * scale[:, None, :])
    cond = np.linalg.cond(Js)
    ok = np.isfinite(cond) & (cond < 1e12)
    if ok.any():
        inv = np.linalg.inv(Js[ok]) / (scale[ok][:, :, None] * scale[ok][:, None, :])
        C = inv[:, 2:4, 2:4]
        tr = C[:, 0, 0] + C[:, 1, 1]
        det = C[:, 0, 0] * C[:, 1, 1] - C[:, 0, 1] * C[:, 1, 0]
        lmax = 0.5 * tr + np.sqrt(np.maximum(0.25 * tr * tr - det, 0.0))
        out[ok] = np.sqrt(np.maximum(noise_var[ok], 0.0) * lmax)
    return out


# ---------------------------------------------------------------------------------------------
# the two corner targets
# an AprilTag's outer corner: within 1 bit of it along both tag axes the tag is its black
# border; the window keeps to 0.8 bit, leaving 0.2 bit for the coarse corner's error and for
# the local affine map's error (the tag's edges are 8 bits long, distortion bends them)
TAG_HALF_BOX_BITS = 0.8
# the slack (tag bits) a tag's window keeps from the features its model does not have: the
# coarse corner's error and the local affine map's (as TAG_HALF_BOX_BITS keeps from 1 bit)
TAG_SLACK_BITS = 0.2
# the fewest pixels of an AprilTag corner's window (refine_tag_corners), beside the 2 per
# unknown every window needs. The fit needs a whole pixel inside each edge's strip
# (refine_corners, "edge strip narrower than a pixel"), but the small windows that rule
# alone keeps have an error of their own (not understood): on campaigns/cameras/tiny-320x240
# (tag bits of 1.5-2 px, 12 poses), now that the ray caster integrates every pixel of its
# tags (renderers._raycast_kernels.AREA_MAX_CELLS 256; at 16 2.6% of them were point
# sampled), pose seed 0: without this floor 1522 / 1538 corners kept (CAHV / CAHVOR) at jpl
# residual RMS 0.0016 / 0.0013 px, with it 1378 / 1455 at 0.0000 / 0.0013; seed 1 0.0060 /
# 0.0047 without, 0.0004 / 0.0048 with.
TAG_MIN_WINDOW_PIXELS = 30
# board units from a corner to the nearest feature its model does not have, along the box's
# axes: an AprilTag's data bits start one bit inside its border; a chessboard's next corner
# is a square away (its mark dots: chessboard_clearance)
TAG_CLEARANCE_BITS = 1.0
CHESSBOARD_CLEARANCE = 1.0
# a chessboard corner's rays (refine_chessboard_corners, corner_rays: +x, +y, -x, -y along
# the board) that are one straight line through it, tied when the image is blurred
CHESSBOARD_LINES = ((0, 2), (1, 3))
# board units a blurred chessboard corner's line strips keep short of the next feature's
# blur (line_strips) for the local affine map's error there: the steps are central
# differences over a square either side, and a board's perspective and the lens' scale
# change the step across a square by a few %; as an AprilTag window's TAG_SLACK_BITS
LINES_SLACK = 0.2
# a chessboard corner's window (half-width, squares) where no mark dot is near: the next
# corner's lines less the slack (chessboard_half_box): 0.8 square
CHESSBOARD_HALF_BOX = CHESSBOARD_CLEARANCE - LINES_SLACK
# refine_chessboard_corners' window when the caller does not say where the board's marks are:
# clear of a mark in the middle of any square (chessboard_half_box's 0.9 (0.5 - r / sqrt(2))
# of a dot of radius r -> 0)
CHESSBOARD_UNKNOWN_MARKS_HALF_BOX = 0.45
# the line strips' half-width in the edge profile's sigma (line_strips)
STRIP_SIGMAS = 2.0
# the largest bias (px) of a straight line fitted over a bent line's strips that the first-order
# curvature_bias leaves (line_strips)
LINES_BIAS_PX = 2e-4


def refine_tag_corners(image, Q, half_box=TAG_HALF_BOX_BITS, clearance=TAG_CLEARANCE_BITS,
                       **options):
    r'''Refine the outer corners of AprilTags

SYNOPSIS

    fit = refine_tag_corners(img, Q, **tag_window(target))
    # Q (Ntags,4,2) corners in order round each tag; fit.q (Ntags*4,2), NaN where dropped

Corner k of a tag is the apex of the tag's black border between the edges to corners
k-1 and k+1; one bit of a tag is its side / 8 (tag36h11: 6x6 data bits in a 1-bit border).
Without tag_window's options the window is the box of TAG_HALF_BOX_BITS, inside the
border: 30 pixels need bits of 3.4 px or more.
'''
    Q = np.asarray(Q, dtype=np.float64).reshape(-1, 4, 2)
    nxt = np.roll(Q, -1, axis=1) - Q
    prv = np.roll(Q, 1, axis=1) - Q
    dirs = np.stack((nxt, prv), axis=2).reshape(-1, 2, 2)
    steps = tag_steps(Q)
    options.setdefault("min_window_pixels", TAG_MIN_WINDOW_PIXELS)
    shrink = _tag_box_shrink(Q, steps, half_box)
    return refine_corners(image, Q.reshape(-1, 2), dirs, [(0, 1)], steps, half_box / shrink,
                          clearance=clearance / shrink, **options)


def tag_steps(Q):
    r'''(Ntags*4,2,2) columns: one of each tag's mean bits (side / 8) along its edges to the
next and to the previous corner, at each of its corners Q (Ntags,4,2) in order round it'''
    Q = np.asarray(Q, dtype=np.float64).reshape(-1, 4, 2)
    return np.stack((np.roll(Q, -1, axis=1) - Q, np.roll(Q, 1, axis=1) - Q),
                    axis=-1).reshape(-1, 2, 2) / 8.0


def homographies(src, dst):
    r'''(N,3,3) the homographies taking the 4 points src (N,4,2) to dst (N,4,2), NaN where
they do not determine one (targets.tag_edges' tags too)'''
    N = len(src)
    A = np.zeros((N, 8, 8))
    rhs = np.zeros((N, 8))
    x, y = src[..., 0], src[..., 1]
    u, v = dst[..., 0], dst[..., 1]
    A[:, 0::2, 0], A[:, 0::2, 1], A[:, 0::2, 2] = x, y, 1.0
    A[:, 0::2, 6], A[:, 0::2, 7] = -u * x, -u * y
    A[:, 1::2, 3], A[:, 1::2, 4], A[:, 1::2, 5] = x, y, 1.0
    A[:, 1::2, 6], A[:, 1::2, 7] = -v * x, -v * y
    rhs[:, 0::2], rhs[:, 1::2] = u, v
    h = np.full((N, 8), np.nan)
    ok = np.all(np.isfinite(A), axis=(-1, -2)) & (np.abs(np.linalg.det(
        np.where(np.isfinite(A), A, 0.0))) > 1e-300)
    if ok.any():
        h[ok] = np.linalg.solve(A[ok], rhs[ok][..., None])[..., 0]
    return np.concatenate((h, np.ones((N, 1))), axis=-1).reshape(N, 3, 3)


def _tag_box_shrink(Q, steps, half_box):
    r'''(N,) >= 1: the factor by which each tag corner's window (and its clearances) must
shrink, in the tag's mean bits (steps), to stay within half_box of the tag's true bits

The window's box is laid out by the local affine map of the tag's mean edges (steps: side /
8), and reaches half_box bits out to the light region's end (tag_window: the gap to the
next tag less TAG_SLACK_BITS). A board seen obliquely or through a fisheye changes its
scale across a tag: the bits beyond an edge are smaller than the tag's mean ones where the
board recedes, and the mean bits' box runs into the next tag (hazcam 17 CAHVORE: its far
pixels 2.0 mean bits out, 8 px, on the next tag's border where the gap is 2.4; the corner
then misfits by 1% of the contrast and was dropped, "predicted error too large"). The tag's
own homography (its 4 corners) has that change to first order: each box edge's end and
middle is taken through it to the tag's bits, and the box shrinks by the largest overreach.
'''
    Q = np.asarray(Q, dtype=np.float64).reshape(-1, 4, 2)
    hb = float(half_box)
    # corner k's bit frame: (0,0) at corner k, (8,0) at k+1, (8,8) at k+2, (0,8) at k-1
    img = np.stack([np.roll(Q, -k, axis=1) for k in range(4)], axis=1).reshape(-1, 4, 2)
    bits = np.broadcast_to(np.array([[0.0, 0.0], [8.0, 0.0], [8.0, 8.0], [0.0, 8.0]]),
                           img.shape)
    Hinv = homographies(img, bits)                                   # image -> bits
    g = np.array([-1.0, 0.0, 1.0])
    box = np.array([(a, b) for a in g for b in g if (a, b) != (0.0, 0.0)]) * hb   # (8,2)
    p = Q.reshape(-1, 2)[:, None, :] + np.einsum("nij,mj->nmi", steps, box)
    ph = np.concatenate((p, np.ones(p.shape[:-1] + (1,))), axis=-1)
    b = np.einsum("nij,nmj->nmi", Hinv, ph)
    with np.errstate(divide="ignore", invalid="ignore"):
        reach = np.abs(b[..., :2] / b[..., 2:3]).max(axis=(-1, -2)) / hb
    out = np.where(np.isfinite(reach), np.maximum(reach, 1.0), 1.0)
    return out


def tag_window(target):
    r'''The window of an AprilGrid's tag corners: {half_box, clearance, notch,
notch_clearance} (tag bits) for refine_tag_corners / refine_corners

Around an outer corner the tag is dark only in its 1-bit border strips; outside it the
board is light as far as the gap to the next tag (tag_spacing x 8 bits) or the board's
edge (margin). The window is the box up to that light region's end less TAG_SLACK_BITS,
with the tag's inside beyond its border (both tag axes past 1 bit less the slack) cut
out: an L-shaped window of ~15 bits^2 at tag_spacing 0.3 against the 2.6 of the box
inside the border, so that small tags (bits of 3 px: a 640x480 fisheye's far tags)
keep windows that determine their fits (MAX_WINDOW_PX still caps it on large tags).
'''
    spec = target.spec
    if "tag_spacing" not in spec:
        return {"half_box": TAG_HALF_BOX_BITS, "clearance": TAG_CLEARANCE_BITS}
    bit = float(spec["tag_size"]) / 8.0
    light = min(float(spec["tag_spacing"]) * 8.0, float(spec.get("margin", np.inf)) / bit)
    return {"half_box": max(TAG_HALF_BOX_BITS, light - TAG_SLACK_BITS), "clearance": light,
            "notch": TAG_CLEARANCE_BITS - TAG_SLACK_BITS, "notch_clearance": TAG_CLEARANCE_BITS}


def chessboard_half_box(target):
    r'''(N,) the window half-width (squares) of each chessboard corner (target.points()'
order): clear of the next corner's lines and of the orientation mark's dots

The next grid lines are a square away: the window keeps LINES_SLACK short of them (the local
affine map's error there, as the blurred lines' strips do), CHESSBOARD_HALF_BOX = 0.8 square.
A mark dot of radius r squares sits in the middle of a square: it comes within
sqrt(2)/2 - r of the square's four corners along the diagonal, where the box reaches
sqrt(2) half_box; those corners keep to 0.9 (0.5 - r / sqrt(2)) (0.32 square for the
catalogue board's dots of 0.4 square; 0.33, a slack of LINES_SLACK c^2 at c = 0.36, let the
dot into 17 CAHVORE's windows: 0.0017 px max against 0.0007). Only the corners of a marked
square are that near a dot (chessboard_clearance). (The window was 0.45 square for every
corner, and the mark's 0.32 for every corner of a marked board: the 88 of the catalogue
board's 100 corners a square from anything took 17 CAHVORE's sharp corners from 0.00023 /
0.0017 to 0.00010 / 0.0006 px RMS / max after the bias step at 0.8, and tiny-320x240's kept
corners from 994 to 1056; docs/corners.md, session 19.)
'''
    nx, ny = target.grid_shape
    out = np.full(nx * ny, float(CHESSBOARD_HALF_BOX))
    mark = target.spec.get("orientation_mark")
    if mark is None:
        return out
    r = 0.5 * float(mark["dot_diameter"]) / float(target.spec["square"])
    near = chessboard_clearance(target) < float(CHESSBOARD_CLEARANCE)
    out[near] = np.minimum(out[near], 0.9 * (0.5 - r / np.sqrt(2.0)))
    return out


def chessboard_clearance(target):
    r'''(N,) board units (squares) each chessboard corner's window may reach before a
blurred neighbour (target.points()' order, iy * nx + ix)

The next corner is a square away; a mark dot of radius r squares in a square's middle is
0.5 - r / sqrt(2) away along the box's axes from the four corners of its square (its
nearest point to the box's corner, taken along the axes: conservative by up to
sqrt(2)), and 1.5 - r or more from any other corner. Only the corners of a marked
square keep the dot's clearance: a blurred window shrinks by 3 sigma from it, and on a
640x480 hazcam's squares of ~10 px every corner's window had shrunk below
the 30 pixels then required where only 12 of 100 corners touch a dot (camera 17: 52 of 528
corners away from the dots dropped, "window too small").
'''
    nx, ny = target.grid_shape
    out = np.full((ny, nx), float(CHESSBOARD_CLEARANCE))
    mark = target.spec.get("orientation_mark")
    if mark is None:
        return out.ravel()
    r = 0.5 * float(mark["dot_diameter"]) / float(target.spec["square"])
    near = min(float(CHESSBOARD_CLEARANCE), 0.5 - r / np.sqrt(2.0))
    # square (sx, sy) spans the corners ix in {sx - 1, sx}, iy in {sy - 1, sy}
    for sx, sy in mark["squares"]:
        out[max(sy - 1, 0):min(sy + 1, ny), max(sx - 1, 0):min(sx + 1, nx)] = near
    return out.ravel()


def refine_chessboard_corners(image, G, half_box=CHESSBOARD_UNKNOWN_MARKS_HALF_BOX,
                              clearance=CHESSBOARD_CLEARANCE, **options):
    r'''Refine the inner corners of a chessboard

SYNOPSIS

    fit = refine_chessboard_corners(img, G, chessboard_half_box(target))
    # G (ny,nx,2) coarse corners of the grid, NaN where missing; fit.q (ny*nx,2)

The four edges at a corner run along the grid lines towards the neighbouring corners
(differences along the grid; central where both neighbours are found).
'''
    G = np.asarray(G, dtype=np.float64)
    steps = grid_steps(G)
    ex, ey = steps[..., 0], steps[..., 1]
    dirs = np.stack((ex, ey, -ex, -ey), axis=1)

    def kappa(q):
        Q = q.reshape(G.shape)
        # NaN where either line's curvature is unknown (a corner on the grid's edge): its
        # strips would follow that line too
        return np.maximum(_grid_curvature(Q, axis=1), _grid_curvature(Q, axis=0)).ravel()
    return refine_corners(image, G.reshape(-1, 2), dirs, [(0, 1), (2, 3)], steps, half_box,
                          clearance=clearance, lines=CHESSBOARD_LINES, line_curvature=kappa,
                          **options)


def _grid_differences(G, axis):
    r'''(fwd, bwd) (ny,nx,2): each corner's image step to the next and from the previous corner
along an axis, NaN where that neighbour is beyond the grid'''
    fwd = np.full(G.shape, np.nan)
    bwd = np.full(G.shape, np.nan)
    if axis == 1:
        fwd[:, :-1] = G[:, 1:] - G[:, :-1]
        bwd[:, 1:] = G[:, 1:] - G[:, :-1]
    else:
        fwd[:-1] = G[1:] - G[:-1]
        bwd[1:] = G[1:] - G[:-1]
    return fwd, bwd


def _grid_curvature(G, axis):
    r'''(ny,nx) curvature (1/px) of the grid line along an axis at each corner: the turn
from the step before it to the step after it over their mean length; a corner at the
line's end takes the line's curvature extrapolated from the next two corners (the next
one alone where the line has no third; NaN where neither has both neighbours)

The strips' length follows this curvature (line_strips), and the bias step's follows the
model's at the corner: the two must agree. Through camera 1's CAHVORE (exact grid
corners) they do to 0.05% RMS inside the grid; at its ends the next corner's copy is
1% RMS, 3% max off, the extrapolation 0.2% RMS, 0.7% max.'''
    fwd, bwd = _grid_differences(G, axis)
    turn = np.arctan2(_cross(bwd, fwd), (bwd * fwd).sum(-1))
    k = np.abs(turn) / (0.5 * (np.linalg.norm(fwd, axis=-1) + np.linalg.norm(bwd, axis=-1)))
    k = np.moveaxis(k, axis, 0).copy()
    if len(k) > 2:
        for end, k1, k2 in ((0, k[1], k[2] if len(k) > 3 else np.nan),
                            (-1, k[-2], k[-3] if len(k) > 3 else np.nan)):
            # a curvature stays >= 0: a steep change is not extrapolated below 0
            ext = np.where(np.isfinite(k2), np.maximum(2.0 * k1 - k2, 0.0), k1)
            k[end] = np.where(np.isnan(k[end]), ext, k[end])
    return np.moveaxis(k, 0, axis)


def grid_steps(G):
    r'''(ny*nx,2,2) columns: the image step of one square along the grid's x and y at each
corner of G (ny,nx,2) (_grid_step: central differences where both neighbours are found)'''
    return np.stack((_grid_step(G, axis=1), _grid_step(G, axis=0)), axis=-1).reshape(-1, 2, 2)


def _grid_step(G, axis):
    r'''(ny,nx,2) image step to the next corner along an axis: central difference where both
neighbours are found, else one-sided, NaN for a corner with neither'''
    fwd, bwd = _grid_differences(G, axis)
    both = 0.5 * (fwd + bwd)
    return np.where(np.isfinite(both), both, np.where(np.isfinite(fwd), fwd, bwd))


# ---------------------------------------------------------------------------------------------
# the bias of straight rays on curved edges
def corner_rays(target):
    r'''The board-frame rays of every corner of a corner target

SYNOPSIS

    rays, unit, wedges, window = corner_rays(target)
    # rays (N,R,3) unit board directions of the edges leaving each of target.points();
    # unit: board length of one window unit (a square, a tag bit); wedges as
    # refine_chessboard_corners / refine_tag_corners use them; window {"half_box",
    # "notch", "clearance"}: the window the detector fits (curvature_bias's keywords)
'''
    p = target.points()
    if target.kind == "chessboard":
        ex, ey = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
        rays = np.broadcast_to(np.stack((ex, ey, -ex, -ey)), (len(p), 4, 3)).copy()
        return rays, float(target.spec["square"]), [(0, 1), (2, 3)], {
            "half_box": chessboard_half_box(target), "notch": None,
            "clearance": chessboard_clearance(target)}
    if target.kind == "apriltag":
        Q = p.reshape(-1, 4, 3)
        nxt = np.roll(Q, -1, axis=1) - Q
        prv = np.roll(Q, 1, axis=1) - Q
        rays = np.stack((nxt, prv), axis=2).reshape(-1, 2, 3)
        rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
        w = tag_window(target)
        return rays, float(target.spec["tag_size"]) / 8.0, [(0, 1)], {
            "half_box": w["half_box"], "notch": w.get("notch"), "clearance": w["clearance"],
            "tag_corners": True}
    raise ValueError(f"corner_rays() needs a chessboard or apriltag target; got {target.kind!r}")


def corner_steps(target, q):
    r'''(N,2,2) the steps (image step of one window unit along the corner's two box axes) a
corner target's refiner lays its window out by, from its corners q (N,2), target.points()'
order: a chessboard's grid_steps (its grid's central differences), an AprilGrid's tag_steps
(each tag's mean bits); NaN where they are not found (a chessboard corner with neither
neighbour along an axis)'''
    q = np.asarray(q, dtype=np.float64).reshape(-1, 2)
    if target.kind == "chessboard":
        nx, ny = target.grid_shape
        return grid_steps(q.reshape(ny, nx, 2))
    if target.kind == "apriltag":
        return tag_steps(q)
    raise ValueError(f"corner_steps() needs a chessboard or apriltag target; got {target.kind!r}")


def curvature_bias(q, tangents, curvatures, wedges, steps, half_box, notch=None,
                   max_window_px=MAX_WINDOW_PX, lines=(), sigma=0.0, clearance=None,
                   tag_corners=False, window_at=None):
    r'''Where refine_corners puts a corner whose edges are curved, minus the corner: px

SYNOPSIS

    b = curvature_bias(q, tangents, curvatures, wedges, steps, half_box)
    # q (N,2) true corners; tangents (N,R,2) unit tangents of the R edges at the corner;
    # curvatures (N,R): edge i passes through q + s t + (k s^2 / 2) perp(t), perp(t) =
    # (-t_y, t_x); b (N,2); q_refined - b estimates the corner

The model fits straight rays; an edge bent by k moves each pixel's dark area by
the area between the curve and its tangent inside the pixel, k (s1^3 - s0^3) / 6
over the tangent's stretch [s0, s1] in it (to first order in k). The fit's
response to that change is its linearised least-squares step, (J^T J)^-1 J^T dv,
in the window the refiner would use about the true corner. First order in k:
the neglected terms are of order k^2 w^3 (5e-4 px for k = 1e-3/px, w = 8 px). lines: pairs of
rays fitted as one straight line (refine_corners' lines on a blurred image: one angle,
the pair's two columns of the Jacobian summed).

sigma > 0: the corners were fitted on a blurred image with the "sampled" kernel of that
sigma (blur_kernel; what detect_chessboard fits X junctions with), and the bias is that
fit's: every pixel term (the model's columns and the bent edges' added area) is the
kernel's sum of the sharp terms at the pixel's taps (whole-pixel offsets: the terms are
computed once on the window's square grown by the taps' reach), in the window the
blurred fit keeps (blurred_half_box with clearance, a number or (N,), default half_box;
the notch is left as it is). Both matter and pull apart: the taps reach past the window's
edge, where the edges have bent further (more bias), and the blurred window is smaller
(less); on MER hazcams 8 and 17 (area renders, the response's sampled blur of 0.7 px, no
noise) the corners moved by 0.65-1.14x the sharp terms' lines bias, by 0.995-1.010x this
one (docs/corners.md, "The lines' bias under blur").

tag_corners: q are an AprilGrid's tag corners, four a tag in order round it (corner_rays'
window says so): the window shrinks as refine_tag_corners shrinks it (_tag_box_shrink: the
tag's homography against its mean bits), from the tag's corners (window_at's).

window_at: (N,2) where the refiner laid each window (_window's centre: the pixel grid it
snaps to and the box's centre), None or NaN rows: about q. The refiner lays its last pass's
window about its first pass's corner, the image's; q here is a model's projection, and a
window laid about it gains or loses an edge pixel wherever the model moves it across a pixel
square's corner's reach: a jump of ~1e-3 px in the bias (1.4e-3 px on camera 17 CAHVORE's
realistic chessboard, which can keep the calibrators' bias passes from settling below their
1e-5 px tolerance: docs/corners.md, session 19). Laid about a point
that does not move with the model (the detected corner, Observations.q), the window is
fixed and the bias a smooth function of the model (harness.calibrators.bias.corner_bias).
'''
    q = np.asarray(q, dtype=np.float64).reshape(-1, 2)
    at = q if window_at is None else np.asarray(window_at, dtype=np.float64).reshape(-1, 2)
    at = np.where(np.all(np.isfinite(at), axis=-1)[:, None], at, q)
    if tag_corners:
        Q = at.reshape(-1, 4, 2)
        shrink = _tag_box_shrink(Q, tag_steps(Q), half_box)
        clearance = (half_box if clearance is None else clearance) / shrink
        half_box = half_box / shrink
    N = len(q)
    t = np.asarray(tangents, dtype=np.float64).reshape(N, -1, 2)
    k = np.asarray(curvatures, dtype=np.float64).reshape(N, -1)
    steps = np.asarray(steps, dtype=np.float64).reshape(N, 2, 2)
    out = np.full((N, 2), np.nan)
    ok = np.all(np.isfinite(q), -1) & np.all(np.isfinite(t), (-1, -2)) \
        & np.all(np.isfinite(k), -1) & np.all(np.isfinite(steps), (-1, -2))
    ok[ok] &= np.abs(np.linalg.det(steps[ok])) > 1e-12
    if not ok.any():
        return out
    idx = np.flatnonzero(ok)
    big = (1 << 40, 1 << 40)
    sigma = float(sigma)
    half_box = np.broadcast_to(np.asarray(half_box, dtype=np.float64), (N,))
    if sigma > 0.0:
        clearance = np.broadcast_to(half_box if clearance is None else
                                    np.asarray(clearance, dtype=np.float64), (N,))
        strips = line_strips(steps[idx], clearance[idx], sigma, np.abs(k[idx]).max(-1)) \
            if len(lines) else None
        half_box = blurred_half_box(steps[idx], half_box[idx], clearance[idx], sigma)
    else:
        strips = None
        half_box = half_box[idx]
    ix, iy, inside, _ = _window(at[idx], steps[idx], half_box, big, max_window_px, notch,
                                strips)
    w = inside.astype(np.float64)
    taps = 0
    if sigma > 0.0:
        Z, W, _, _ = blur_kernel(sigma, "sampled")
        taps = int(np.rint(np.abs(Z[0]).max()))
        # the kernel is the outer product of its 1-D taps k (Z's offsets -taps..taps along
        # both axes, rows first): k is W's row sums
        k1 = W[0].reshape(2 * taps + 1, 2 * taps + 1).sum(axis=1)
        # the window's square (rows of oy, then ox, as _window's) grown by the taps' reach
        r = int(max(max_window_px, 0.0 if strips is None else np.max(strips[2], initial=0.0))) \
            + taps
        off = np.arange(-r, r + 1)
        oy, ox = np.meshgrid(off, off, indexing="ij")
        c0 = np.round(at[idx]).astype(np.int64)
        ix = c0[:, 0:1] + ox.ravel()
        iy = c0[:, 1:2] + oy.ravel()
    centres = np.stack((ix, iy), axis=-1).astype(np.float64)
    d = centres - q[idx, None, :]
    n, R = k[idx].shape
    wedges = np.asarray(wedges, dtype=np.int64).reshape(-1, 2)
    u = t[idx]
    # each wedge's rays counter-clockwise (first, second), as wedge_area takes them
    first = np.empty((n, len(wedges)), dtype=np.int64)
    second = np.empty((n, len(wedges)), dtype=np.int64)
    for iw, (i, j) in enumerate(wedges):
        flip = _cross(u[:, i], u[:, j]) < 0
        first[:, iw] = np.where(flip, j, i)
        second[:, iw] = np.where(flip, i, j)
    from ._corner_kernels import curvature_terms
    D, dD_dc, dD_dt, dv = curvature_terms(np.ascontiguousarray(d), np.ascontiguousarray(u),
                                          first, second, np.ascontiguousarray(k[idx]))
    if taps:
        # each window pixel's blurred terms: the taps' weighted sum of the sharp terms, one
        # axis at a time (the kernel is separable), all terms stacked
        side, inner = 2 * r + 1, 2 * (r - taps) + 1
        T = np.concatenate((D[..., None], dD_dc, dD_dt, dv[..., None]), axis=-1)
        # B (side, inner): output pixel i sums input pixels i..i + 2 taps
        B = np.zeros((side, inner))
        for j in range(2 * taps + 1):
            B[np.arange(inner) + j, np.arange(inner)] = k1[j]
        T = T.reshape(n, side, side, -1).transpose(0, 1, 3, 2) @ B      # (n,y,C,x')
        T = (T.transpose(0, 3, 2, 1) @ B).transpose(0, 3, 1, 2)          # (n,y',x',C)
        T = T.reshape(n, inner * inner, -1)
        D, dD_dc, dD_dt, dv = T[..., 0], T[..., 1:3], T[..., 3:3 + R], T[..., 3 + R]
    if len(lines):
        dD_dt = dD_dt @ _ray_angles([tuple(p) for p in lines], R)
    J = np.concatenate((np.ones(D.shape + (1,)), D[..., None], dD_dc, dD_dt), axis=-1)
    Jw = J * w[..., None]
    JtJ = Jw.transpose(0, 2, 1) @ J + 1e-12 * np.eye(J.shape[-1])
    step = np.linalg.solve(JtJ, (Jw.transpose(0, 2, 1) @ dv[..., None]))[..., 0]
    out[idx] = step[:, 2:4]
    return out
