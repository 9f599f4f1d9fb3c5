r'''AprilTag corners from the tags' whole border edges, for blurred images

SYNOPSIS

    from targets.tag_edges import refine_tag_edges

    fit = refine_tag_edges(img, Q, sigma, kind, bits=bits)
    # Q (Ntags,4,2) corners round each tag (coarse: pupil_apriltags', or refined);
    # sigma, kind: the image's blur (targets.corners.estimate_blur); bits (Ntags,8,8) each
    # tag's cells (targets.boards.tag36h11_bits: True = white), None: data bits unknown
    fit.q          # (Ntags*4,2) corners, NaN where dropped
    fit.reasons    # (Ntags*4,) "" or why the corner was dropped

Why. Blurred (the `realistic` response profile: a PSF of sigma 0.7 px) and noisy, a
corner fitted in its own window (targets.corners.refine_tag_corners) sees two edges of
about half a tag bit each: its error is the noise over a few px of edge (0.02-0.03 px RMS
on the quick cameras against the dots' 0.004-0.006), and on tags of 3-4 px bits no window
is left once it keeps 3 sigma of blur from the data bits. The tag's black border is a full
square: each of its four edges is 8 bits long. Here each edge is fitted along its whole
length, and each corner is where its two edges meet.

The model. Along edge k (from corner k to corner k+1, length L px), with t the position
along the chord and s the signed distance from it into the tag, the edge is the curve
s(t) = d0 + d1 tau + d2 tau^2 (+ d3 tau^3), tau = 2 t / L - 1: straight under a
homography, bent by lens distortion. A pixel at distance x from the curve (into the dark
side) is

    v = a + b * F(x),  F(x) = P(n . (U + z) <= x)

U uniform on the pixel's square (the area it integrates), z the blur's offset (a Gaussian
PSF of sigma on the scene, or the "sampled" kernel on the pixel image: blur_kernel's two
kinds) and n the edge's normal: F is the blurred pixel's dark fraction next to a straight
edge, exact but for the curve's bend within the kernel: to first order in the bend s''
(1/px) a pixel reads F(x - V s'' / 2), V = sigma^2 + _KIND_VARIANCE[kind] the kernel's
variance along the edge, so each fitted curve lies V kappa / 2 (0.33 kappa px^2 at the
realistic blur; 3e-4 - 6e-4 px on the MER hazcams) towards its centre of curvature. F is
tabulated per blur on a grid of x and of the edge's angle (the pixel's projected width
depends on it) and interpolated linearly (errors ~1e-5 of the contrast).

That shift and the span's own model error (below) are taken off together where the board
lines' shape is known without the image's noise (line_reference: camera_line_reference from
a camera model and the board's pose, e.g. a first calibration's; _unbent, _span_choice).
Either alone leaves the other (noise-free blurred corners, bench_corners' area renders, 6
poses, RMS px: MER hazcam 8 0.00079, the shift alone 0.00090, the span's error alone 0.00075,
both 0.00072; hazcam 17 as CAHVORE 0.00099, 0.00091, 0.00091, 0.00079; the last three with
the adjacent edges' curve clearance tried below, which changed nothing): h-tag16c's
"end-offset" (the corners -0.4 to -1 kappa px^2 off where the shift alone is taken off) is
the span's model error. A polynomial over a span cannot follow all of a bent board line; a
cubic fitted to the true line of a constructed barrel's edges over the pixels' span
(tests/test_tag_edges.py _barrel_tag_grid) and extrapolated to the corners (~3 px) misses
them by -0.62 kappa px^2 (k1 = -3.5e-6) and -1.18 (k1 = -7e-6): the truth's quartic term,
second order in the distortion, not the blur nor the pixels. On the quick cameras a cubic
over one edge misses by little (5e-5 px RMS on hazcam 17), the long spans (the edge with its
board line's neighbours) by more, and the first pass's estimate of that error (from its own
curves, _span_choice) is as noisy as the corners. With the shape known, the long spans are
chosen and their error taken off: realistic corners of hazcam 17 as CAHVORE 0.00475 ->
0.00366 px RMS (the true model and pose; 6 poses). In a calibration the shape comes from a
first fit: jpl on the realistic renders (bench_corners' 6 poses of each camera in its own
family, 4 noise seeds, pooled as bench_corner_campaign.py does), AprilTag / dots residual /
projection difference RMS ratio, detected as before -> re-detected with the first fit's
model and surveyed poses (weak edges then dropped, place_weak_edges) and refitted (a third
pass changes nothing): navcam 15 CAHVOR 0.70 / 0.54 -> 0.58 / 0.42, hazcam 17 CAHVORE 0.86 /
1.78 -> 0.57 / 0.88, hazcam 8 CAHVORE 1.12 / 1.31 -> 0.78 / 0.91, blur-wide-1024 CAHVOR
0.77 / 2.14 -> 0.62 / 1.37 (per seed 0.58, 1.45, 0.58, 1.89: still above 1). h-tag16d, a
script outside the harness (harness.stages' detect, observations_from, calibrate_stage and
compare_stage twice).

The campaign's calibrators do not re-detect: they take the same two parts off in their bias
loop instead (h-tag16e), as they take the dots' centroid bias off. Without a line_reference
each fit records, per corner, what its error needs (info["edge_spans"], SPAN_RECORD per
edge: the chosen span's functional h on a board line's quintic, _span_choice's, and the
blur's variance V); targets.detect_apriltag carries it (Detection.corner_spans) through
harness.stages.observations_from to Observations.corner_spans, and
harness.calibrators.bias.tag_edges_bias computes it from the current model and pose
(edge_span_bias: the board line projected, moved by V s'' / 2, followed by the span's
polynomial; the two edges' misses along their normals move the corner). The spans are
chosen as if that error were taken off (defer_span_bias, detect_apriltags' default: the
long spans, as with a line_reference), so the corners alone carry it (a constructed barrel,
test_the_bias_step_takes_off_a_deferred_spans_model_error: blurred, median 0.00126 px as
chosen before; deferred less span_miss 0.00056, the true line reference's 0.00057; realistic
noise RMS 0.0072 -> 0.0045). bench_corner_campaign.py --response realistic --seeds 0-3
(cached renders, back to back with main, load ~4 on 2 cores), AprilTag / dots residual /
projection difference ratio, main -> this: 15 CAHVOR 0.73 / 0.29 -> 0.62 / 0.30, 17
CAHVOR 0.78 / 0.89 -> 0.67 / 0.81, 17 CAHVORE 0.82 / 1.43 -> 0.65 / 0.79, 8 CAHVOR 0.86 /
0.97 -> 0.79 / 0.65, 8 CAHVORE 1.15 / 1.41 -> 0.83 / 0.89, blur-wide-1024 0.79 / 1.87 ->
0.66 / 1.02 (single seeds up to 2.71: 8 CAHVORE seed 1, 4.01 on main). Blur alone (seed 0,
no noise) 17 CAHVORE 0.44 / 3.38 -> 0.39 / 2.38: the weak edges' model error (dropped, as
with a line_reference: 0.26 / 0.90, but realistic 1.40, its seed 1 3.21: kept); 8 CAHVORE
0.68 / 0.96 -> 0.63 / 1.28, though its corners less tag_edges_bias under the true model
improve (6 poses, blur: 0.00078 px RMS before, 0.00070 after); the others' fall: 15 CAHVOR
0.17 / 0.49 -> 0.07 / 0.20, 17 CAHVOR 0.15 / 0.45 -> 0.08 / 0.06, blur-wide 0.23 / 1.18 ->
0.19 / 0.23, 8 CAHVOR 0.31 / 1.20 -> 0.81 / 1.09 (its residual up, below the dots'; the
bias under a CAHVOR fit of a CAHVORE lens). Tried and left out: the
shape from a local map of the image's own corners (a homography and a degree-5
polynomial over the 5 x 5 tags round an edge): it cannot follow the hazcams' lines (its
cubic misfit at the ends 4.7e-4 px RMS off the truth's 5e-5 on hazcam 17, from exact
corners) and made every corner worse (hazcam 8 0.00078 -> 0.0078 px RMS); the adjacent
edges' clearance measured from their fitted curves instead of their chords (a bent edge
leaves its chord at the corner by kappa L / 2): no change (0.00078 -> 0.00079, 0.00099 ->
0.00099).

The line is represented over the span's own reach (SPAN_RECORD's tau lo, hi: the edge alone,
with its nearer neighbour's half, or with both neighbours), not over the whole stretch past
both neighbours: at a fisheye's rim a board line bends beyond a quintic there (MER hazcam 8
as CAHVOR, a corner tag of the image's corner: sag 9.8 px over an 88 px edge, the stretch's
quintic 0.05 px off at the corners), and the functional of a short span, weighing the
quintic's high terms, took that misfit for the span's miss: corners corrected the wrong way
by up to 0.026 px (detected - bias - projection under the truth, 0.053 px). Over the reach:
realistic noise, seed 5 (benchmarks/bench_corner_campaign.py --seeds 4-7), all corners
0.00377 -> 0.00283 px RMS, max 0.053 -> 0.013; seed 6 0.00331 -> 0.00300, max 0.026 ->
0.016. (8 as CAHVORE kept its rim error: the sheared tags' bit depth, below.)

Board lines. An AprilGrid's tags stand in rows and columns: edge k of a tag lies on the
same board line as edge k of its row's (k = 0, 2) or column's (k = 1, 3) neighbours
(`grid`). Each edge's last fit takes, per corner, the span and degree of least expected
error of that corner (_span_choice: bias^2 + variance, both computed per edge from the
first pass): the edge alone, the edge with the nearer half of its board line's neighbour
beyond that corner (NEIGHBOUR_REACH), or the edge with both its neighbours (~3.6 edge
lengths: the noise averaged over 3x the pixels, the corner inside the span), a cubic, or
over the three a quadratic (CANDIDATES). The long span averages the noise; a shorter one
follows a bent line (a fisheye's big tags near the image's corner: a cubic over the
three edges missed the line by up to 0.04 px). The choice weighs the two on the image's
own numbers, no length or bend threshold: it replaced a rule chosen on MER hazcam 8 (the
three edges' cubic for an edge up to 64 px or bent by up to 0.05 px, else per corner),
which left 0.0091 px RMS, max 0.040 on the corner pose of
tests/test_tag_edges_fisheye.py's constructed fisheye (now 0.0034, max 0.020: the rest
are corners of weak edges, below).

The pixels. Each edge uses the pixels that see no other feature of the board through the
blur: a pixel at distance x and position t is kept where the light gap outside the tag
(the board's tag spacing) and the dark cells inside it (the 1-bit border, and the data
bit next to it where that is dark too) reach at least BLUR_REACH_SIGMAS sigma plus the
pixel's half-diagonal beyond it, and where it is that far from the adjacent edges' lines.
The cells are placed along the edge by the homography of the tag's four current corners,
across it by the depth from the fitted curve, in bits of the adjacent edges' depth across
it (their extent along its normal / 8: an oblique tag has bits of two sizes, a sheared one
bits 1/sin(corner angle) longer than deep; until session 19 their length: "The bits' depth
across the edge" below), with SAFETY_PX more margin. An edge whose band has no dark plateau
(bits of 2-3 px across) takes its tag's contrast b from the edges that have one
(_fit_contrast_first). On bits under ~3.5 px at sigma 0.7 (camera 17's 2.8 px) every
dark-side pixel sees the data row inside the border, so where a light data cell lines an
edge its band keeps too few dark-side pixels to place it alone ("seen from its light side
only": ~40% of camera 17's edges). Such a weak edge's pixels (its light side, clean of the
data row) still join its board line's fits, and it is placed, its corners kept, only on
the one cubic through it and both neighbours where that fit sees the dark side beyond both
its ends (_sees_dark: interpolated between dark sides, not extrapolated); elsewhere it is
dropped with that reason. An edge that sees its dark side along part of its length only
places a corner only where it sees it in the half next to that corner, or beyond it
(_sees_dark_near); elsewhere the corner is dropped (NEAR_CORNER_LIGHT_ONLY). Not where a
line_reference is given (place_weak_edges): their
corners carry a model error none of the corrections here remove, 0.0018-0.0019 px RMS
noise-free on hazcam 17 as CAHVORE against 0.0005-0.0007 for the others' (84 of 646
corners, blurred, 6 poses); jpl on those blurred renders, AprilTag projection difference
0.00358 -> 0.00211 px without them (dots 0.00106), with a first fit's line_reference 0.00254
-> 0.00100; realistic (bench_corners' 6 poses, 4 noise seeds), AprilTag / dots ratio with
the line reference 0.66 / 1.15 -> 0.57 / 0.88. Without a reference they are kept: the
campaign (bench_corner_campaign.py --response realistic --seeds 0-3 --cameras 17) without
them went 0.78 / 0.89 -> 0.71 / 0.78 as CAHVOR but 0.82 / 1.43 -> 0.80 / 1.94 as CAHVORE
(every seed's projection ratio up: the fit loses the corners where the bits are smallest).
The other quick cameras and blur-wide-1024 have none. Modelling the data row's light
instead (F(x) - gl F(x - wl),
the cells placed by the tag's homography; commits 73e4c2b, fdce4a3, reverted) kept 854 of
864 corners, but their model error under the hazcam's distortion (0.0016 px RMS on blur
without noise, against 0.0009 for the corners kept without it) raised the realistic
AprilTag / dots projection ratio of 17 as CAHVORE from 0.63 to 1.46 (docs/corners.md).

The bits' depth across the edge (h-cornerbias's diagnosis, session 18; landed in session 19
with _sees_dark_near): a bit's depth across an edge is the adjacent edges' extent along its
normal / 8, sin(corner angle) of their length / 8, which placed the data row until then. On
a sheared tag (corner angles 45-135 deg at MER hazcam 8's rim) the length placed the data
row too deep and the dark-side pixels saw it: on 8 CAHVORE, blur only, seeds 0-3, corners at
angles under 60 or over 120 deg erred 0.0018-0.0024 px RMS (the rest 0.0003-0.0004, after
tag_edges_bias under the truth), tags read larger. The depth leaves more edges without clean
dark-side pixels near a corner, and a corner placed from the far half's dark side erred up
to 0.40 px (MER hazcam 17 as CAHVOR, realistic, seed 4, pose 2): hence _sees_dark_near.
Realistic, bench_corner_campaign.py --response realistic --seeds 0-7 --cameras
15,17,8,campaigns/cameras/blur-wide-1024.cahvor --models CAHVOR,CAHVORE --targets apriltag,
AprilTag / dots projection difference ratio (predicted sigma ratio), the length -> the depth:
15 0.41 -> 0.43 (0.43); 17 CAHVOR 0.82 -> 0.94 (0.52 -> 0.55); 17 CAHVORE 0.88 -> 0.93 (0.96
-> 1.06); 8 CAHVOR 0.69 -> 0.65 (0.63); 8 CAHVORE 1.21 -> 0.59 (0.66 -> 0.67); blur-wide-1024
0.74 -> 0.76 (0.56 -> 0.55); residual ratios 0.61-0.75. The cost: corners kept on 17 per
seed 605-677 -> 573-644 of 864 (more "seen from its light side only"), and on
tests/test_tag_edges_fisheye.py's poses 1-5 127, 123, 121, 144, 128 -> 121, 116, 108, 137,
121 of 144, every pose's RMS and max lower.

The blur. Handed an estimate (choose_kind: the corner windows' quick look, one kind on
BLUR_QUICK_SAMPLE corners), the first pass fits sigma on the edges: one Gauss-Newton step
of the sigma all edges share, each edge's own parameters eliminated (_blur_step,
targets._tag_edge_kernels.blur_step, with dF/dsigma tabulated beside F), for each kind of
kernel (the second started at the first's variance, from its curves); the kind of least
summed squared misfit after its step is kept (_choose_kind: the corner windows tell the
kinds apart on too few pixels) with its sigma after the step (standard error 2e-4 - 9e-4
px on the quick cameras' realistic renders, where the windows' median over 32 corners had
~1e-3 and cost ~0.04 s per 1024x1024 image).

The fit: Levenberg-Marquardt on (a, b, d0..d3) of every edge at once (compiled:
targets._tag_edge_kernels), twice: the first pass fits each edge alone and places the
second's pixels; the second weights each pixel by the inverse of its noise variance, a line
in its value fitted to the first pass's residuals (_noise_line: shot noise grows with the
signal; realistic corners 0.0029 -> 0.0027 px RMS on navcam 15, 0.0050 -> 0.0045 on hazcam
17 as CAHVORE). A corner is dropped, with the reason, when either of its edges has too
few pixels or sees only its light side, did not converge, misfits by more than MAX_MISFIT
of its contrast, has too little contrast, or when the two curves do not meet within
MAX_CORNER_SHIFT_PX of the corner they started from (start_error_px in the first pass).

Measured (benchmarks/bench_corners.py --targets apriltag --methods camval --response
realistic; K = 16 renders, 6 poses): corner error RMS / max 0.0029 / 0.0134 px (navcam 15),
0.0050 / 0.0220 (hazcam 17 as CAHVORE, 652 of 864 corners: the rest's bits are too small
for the blur; 0.0059 over 573 before the weak edges joined their board lines), 0.0050 /
0.0293 (hazcam 8 fisheye), 0.0023 / 0.0089 (camera 1, 5120x3840; 0.0059 and 0.0037 before
NEIGHBOUR_REACH); with the length rule before _span_choice 0.0032 / 0.0135, 0.0052 /
0.0218, 0.0053 / 0.0293, 0.0025 / 0.0112; the corner windows gave 0.014-0.03. CPU per
image, whole detection (median; docs/corners.md, "Blurred AprilTag detection time", load 3
on 2 cores): 0.043 s on 640x480, 0.090 s on 1024x1024, 0.30 s on 5120x3840 (0.135, 0.194,
0.561 s before the blur was fitted on the edges, back to back); _span_choice adds ~0.011 s
per 1024x1024 image (hazcam 8 realistic, back to back at load 6-9: 0.106 -> 0.117 s).

Sharp images keep the corner window model (targets.corners): it is exact there to 1e-7 px
on the ray caster's area renders, which this model is not built to match (its F ignores
the edge's bend and the tabulation's rounding at sigma 0).
'''

import functools
import math

import numpy as np

from ._tag_edge_kernels import (
    PIECE_ALL,
    PIECE_BEFORE_START,
    PIECE_BEYOND_END,
    PIECE_OWN,
    SPAN_FG,
    SPAN_G,
    SPAN_GG,
    SPAN_MOMENTS,
    SPAN_W,
    blur_step,
    edge_moments,
    fit_edges,
    fit_pixels,
    meet_curves,
    noise_moments,
    pixel_weights,
    plateau_counts,
    sampled_table,
    tag_edge_pixels,
)
from .corners import (
    BLUR_REACH_SIGMAS,
    MAX_MISFIT,
    MIN_CONTRAST,
    PSF_KINDS,
    CornerFit,
    blur_kernel,
    homographies,
)
from .detection import median

# px added to every clearance: the coarse corners' error and the bend of an edge between
# them (a homography of the 4 corners places the cells; the sagitta of a hazcam's 60 px
# tag edge is ~0.1-0.3 px)
SAFETY_PX = 0.3
# fewest pixels an edge's fit needs: 5 parameters, each wants tens of edge pixels to
# average the noise rather than follow it; half of them on the edge's dark side (a band
# that sees only the light side's tail of the blurred edge places it 5-20x worse)
MIN_EDGE_PIXELS = 40
# the band's half-width beyond the blur's reach (px): plateau pixels fix a and b; more of
# them add nothing to the edge's position
PLATEAU_PX = 1.0
MAX_ITERATIONS = 30
# a long bent edge's per-corner fit takes its neighbour's pixels out to this fraction of the
# neighbour's length past the gap: its nearer half. A cubic over this edge and the whole
# neighbour (~2.3 edge lengths) misses a fisheye's bent board line: noise-free blurred
# corners of MER hazcam 8's big tags (100-150 px) 0.005-0.008 px RMS, of the nearest pose
# 0.0064 (this edge alone, a cubic: 0.0007, but its corner at the span's end: 0.0086 px
# RMS with the realistic noise, against 0.0059). Reach 0.5: 0.0025 noise-free on that
# pose, 0.0053 realistic (0.7, the corner at the span's middle: 0.0049 / 0.0055; 0.25:
# 0.0011 / 0.0056); on camera 1 (5120x3840, not used to choose it) realistic 0.0037 ->
# 0.0025 px RMS, max 0.021 -> 0.011 (docs/corners.md)
NEIGHBOUR_REACH = 0.5
# pixels on the dark plateau (beyond the blur's reach inside the edge) an edge needs for its
# own contrast; with fewer it takes its tag's (_fit_contrast_first)
MIN_PLATEAU_PIXELS = 10
# converged when no curve coefficient moves by more than this (px): a tenth of 1e-3 px
CONVERGED_PX = 1e-4
# the blur's first pass (kind and sigma, each edge alone) only places the second pass's
# pixels (SAFETY_PX of margin) and compares misfits, second order in a curve's error
FIRST_PASS_CONVERGED_PX = 1e-3
# an edge's fitted contrast |b| may exceed the image's range (max - min over every pixel:
# the board's light and the tags' dark levels, each widened by the noise of its extreme
# pixels) by this many RMS residuals of its own fit (its pixels' noise) before the fit is
# taken to have run off (EDGE_CONTRAST_OFF): a blurred image of a two-level scene lies
# between its levels, and the levels are reached wherever a tag's dark or the board's light
# is wider than the blur; beyond that the contrast is not the image's
CONTRAST_NOISE_SIGMAS = 4.0
# the most the meeting point of two fitted edges may move from the corner it started at
MAX_CORNER_SHIFT_PX = 2.0
# the most Newton steps to where two fitted edges meet (they stop at a step below 1e-9 px)
MEET_ITERATIONS = 8
# the tabulation of F: step in x (px) and the angle bins over [0, pi/4]
TABLE_STEP_PX = 0.01
TABLE_ANGLES = 9
# the blur is tabulated to this (px): a sigma off by half of it changes the symmetric edge
# profile by ~1e-4 of the contrast and moves no edge
TABLE_SIGMA_STEP_PX = 1e-3


def _phi_integral(y, sigma, order):
    r'''The order-th (1 or 2) antiderivative in y of Phi(y / sigma), 0 at -infinity, and
its derivative in sigma'''
    from scipy.special import ndtr
    z = y / sigma
    pdf = np.exp(-0.5 * z * z) / np.sqrt(2.0 * np.pi)
    if order == 1:
        return sigma * (z * ndtr(z) + pdf), pdf
    cdf = ndtr(z)
    return sigma * sigma * 0.5 * ((z * z + 1.0) * cdf + z * pdf), sigma * cdf


@functools.lru_cache(maxsize=8)
def _edge_table(sigma, kind):
    r'''(x0, F (A,X), dF/dx (A,X), dF/dsigma (A,X)): the blurred dark fraction at x px into
the dark side, per angle bin phi_m = m pi/4 / (A-1) of the normal (folded: |n_x| >= |n_y|)'''
    Z, W, _, dW = blur_kernel([sigma], kind)
    Z, W, dW = Z[0], W[0], dW[0]
    reach = BLUR_REACH_SIGMAS * max(sigma, 0.3) + 2.0
    x = np.arange(-reach, reach + TABLE_STEP_PX / 2, TABLE_STEP_PX)
    phi = np.linspace(0.0, np.pi / 4, TABLE_ANGLES)
    F = np.zeros((len(phi), len(x)))
    Fs = np.zeros((len(phi), len(x)))
    if kind == "gaussian":
        # every angle's row at once (the same elementwise arithmetic as one row at a time,
        # the four terms summed in the same order; ~0.6 ms a table against 1.1): the angle
        # 0 alone below, where the square's projection is a segment
        u = np.array([np.cos(p) for p in phi[1:]])[:, None]
        w = np.array([np.sin(p) for p in phi[1:]])[:, None]
        terms = [(sgn, _phi_integral(x + dx, sigma, 2)) for sgn, dx in
                 ((1, (u + w) / 2), (-1, (u - w) / 2), (-1, -(u - w) / 2),
                  (1, -(u + w) / 2))]
        F[1:] = sum(sgn * t[0] for sgn, t in terms) / (u * w)
        Fs[1:] = sum(sgn * t[1] for sgn, t in terms) / (u * w)
        phi = phi[:1]
    for m, p in enumerate(phi):
        u, w = np.cos(p), np.sin(p)
        if kind == "gaussian":
            # a Gaussian on the scene: E over the pixel's square of Phi((x - n.U) / sigma),
            # n.U = u U1 + w U2: the mean over each uniform is a difference of Phi's
            # antiderivative in x, closed form (within 2e-13 of a 12 x 12 Gauss-Legendre
            # rule over the square, which took 0.024 s per table against 0.001)
            if w < 1e-12:
                hi, lo = _phi_integral(x + u / 2, sigma, 1), _phi_integral(x - u / 2, sigma, 1)
                F[m], Fs[m] = (hi[0] - lo[0]) / u, (hi[1] - lo[1]) / u
            else:
                terms = [(sgn, _phi_integral(x + dx, sigma, 2)) for sgn, dx in
                         ((1, (u + w) / 2), (-1, (u - w) / 2), (-1, -(u - w) / 2),
                          (1, -(u + w) / 2))]
                F[m] = sum(sgn * t[0] for sgn, t in terms) / (u * w)
                Fs[m] = sum(sgn * t[1] for sgn, t in terms) / (u * w)
        else:
            # the sampled kernel's taps on the pixel image: the exact pixel fraction at
            # each tap's offset (the taps fixed, their weights a function of sigma)
            sampled_table(x, Z @ np.array([u, w]), W, dW, u, w, F[m], Fs[m])
    dF = np.gradient(F, TABLE_STEP_PX, axis=1)
    return float(x[0]), F, dF, Fs


def _lookup(table, x, phi):
    r'''F(x) and F'(x) for the folded angles phi (same shape as x), linear in both'''
    x0, F, dF = table[:3]
    A, X = F.shape
    fi = np.clip((x - x0) / TABLE_STEP_PX, 0.0, X - 1.000001)
    i = fi.astype(np.int64)
    fx = fi - i
    fa = np.clip(phi / (np.pi / 4) * (A - 1), 0.0, A - 1.000001)
    j = fa.astype(np.int64)
    fy = fa - j
    out = []
    for T in (F, dF):
        t0 = T[j, i] * (1 - fx) + T[j, i + 1] * fx
        t1 = T[j + 1, i] * (1 - fx) + T[j + 1, i + 1] * fx
        out.append(t0 * (1 - fy) + t1 * fy)
    # beyond the table the fraction is 0 or 1 and flat
    below, above = x < x0, x > x0 + (X - 1) * TABLE_STEP_PX
    out[0] = np.where(below, 0.0, np.where(above, 1.0, out[0]))
    out[1] = np.where(below | above, 0.0, out[1])
    return out


# the tag's corners in its cell coordinates (col, row), pupil_apriltags' order:
# bottom-left, bottom-right, top-right, top-left of the upright tag (row 0 at the top)
_TAG_CORNERS = np.array([[0.0, 8.0], [8.0, 8.0], [8.0, 0.0], [0.0, 0.0]])


# a corner dropped where its edge's fit sees no dark side in the half of the edge next to it
# (_sees_dark_near)
NEAR_CORNER_LIGHT_ONLY = ("edge seen from its light side only near the corner (the light data "
                          "bits beside it too close for the blur)")
# an edge whose fit had no pixel on its blurred profile's slope at its start curve (its band
# all beyond the blur's reach on one side: a free-contrast fit of an edge seen from one side
# only that ran off, restarted there; targets._tag_edge_kernels.fit_edges: not fitted)
EDGE_OFF_PROFILE = ("edge fit started off its blurred profile (no pixel on the edge's slope: "
                    "the band all on one side of it)")
# an edge whose free contrast ran beyond what the image holds (|b| above the image's range
# by more than CONTRAST_NOISE_SIGMAS of its pixels' noise): a fit that slid its curve into
# the blur's tail on one side, where any contrast fits the few pixels left on the slope
# (_fit_edges: not converged, misfit inf); its curve places nothing, its corners are dropped
EDGE_CONTRAST_OFF = ("edge fit ran off: its contrast beyond the image's range (its curve slid "
                     "into the blur's tail)")
# targets._tag_edge_kernels.tag_edge_pixels's status of an edge: why it has no pixels
_EDGE_STATUS = {1: "edge too short for its blur",
                2: "edge seen from its light side only (tag bits too small for the blur)",
                3: "edge off the image or within its blur's reach of the image border"}


def _homographies(Q):
    r'''(N,3,3) each tag's image -> cells homography from its corners Q (N,4,2)'''
    Q = np.asarray(Q, dtype=np.float64)
    return homographies(Q, np.broadcast_to(_TAG_CORNERS, Q.shape))


def _neighbours(grid, N):
    r'''{(i, k): [(i2, k)]}: the edges on the same board line in the adjacent tags'''
    out = {}
    if grid is None:
        return out
    where = {(int(c), int(r)): i for i, (c, r) in enumerate(np.asarray(grid).reshape(N, 2))}
    for (c, r), i in where.items():
        for k in range(4):
            # edges 0 and 2 lie on rows of the board (y = const), 1 and 3 on columns
            dc, dr = ((1, 0) if k % 2 == 0 else (0, 1))
            out[(i, k)] = [(where[(c + sgn * dc, r + sgn * dr)], k) for sgn in (-1, 1)
                           if (c + sgn * dc, r + sgn * dr) in where]
    return out


def refine_tag_edges(image, Q, sigma, kind="gaussian", *, bits=None, grid=None, gap_bits=2.4,
                     value_range=None, passes=2, max_misfit=MAX_MISFIT,
                     min_contrast=MIN_CONTRAST, choose_kind=False, start_error_px=None,
                     line_reference=None, place_weak_edges=None, defer_span_bias=False):
    r'''Corners of AprilTags from their four whole border edges; see the module docstring

ARGUMENTS

- image: (H,W) float image, linear in albedo
- Q: (Ntags,4,2) corners round each tag (NaN: not detected)
- sigma, kind: the blur (targets.corners.blur_kernel), px; sigma > 0
- bits: (Ntags,8,8) bool cells of each tag, True = white (None: every data bit light)
- grid: (Ntags,2) each tag's (column, row) on the board (None: tags fitted alone); an
  edge is fitted together with the edges on the same board line of the adjacent tags
- gap_bits: tag bits of light board between a tag and its neighbour (tag_spacing x 8)
- value_range: the image's max - min (the contrast test's scale; default computed)
- start_error_px: the most the first pass's corners may move from Q (default
  MAX_CORNER_SHIFT_PX; the passes after it keep to MAX_CORNER_SHIFT_PX of the previous
  pass's corners): a detector's coarse corners may err by more
- line_reference: None, or a callable (ik (m,2) each edge's tag and edge index, qs (m,2)
  its chord's start, es, ns (m,2) its direction and normal into the tag, Ls (m,) its length;
  grid=, gap_bits= as given here) -> (m,6) the board line through each edge as a quintic
  s(tau) in that frame, NaN rows where unknown: a shape known without the image's noise (the
  camera model and the board's pose, camera_line_reference). _span_choice then judges each
  candidate span by its bias under it and takes that bias off the corner, and the blur's
  shift of a bent edge is taken off each curve (_unbent); see the module docstring
- place_weak_edges: True: an edge seen from its light side only is placed on the cubic
  through it and its board line's neighbours where they see their dark side beyond both its
  ends (_sees_dark); False: its corners are dropped with that reason; None (default): placed
  unless a line_reference is given (see the module docstring: with one, their model error is
  most of what is left of hazcam 17's)
- defer_span_bias: without a line_reference, True: each corner's span is chosen as if its
  model error were taken off later (its risk REFERENCE_BIAS_LEFT of the first pass's bias
  estimate, as with a line_reference): the calibrators' bias step takes it off with the
  current camera model and pose (edge_span_bias, from info["edge_spans"]); False: the span
  of least expected error of the corner as it is
- choose_kind: True: (sigma, kind) is an estimate, a start: sigma is fitted on the edges
  and the kind chosen among targets.corners.PSF_KINDS (the others started at the sigma of
  the same variance, _same_variance) by the first pass's squared misfit summed over the
  edges every kind fitted (_choose_kind)

RETURNED VALUE: a targets.corners.CornerFit of the Ntags*4 corners (info: "corner_model",
"edge_spans" (Ntags*4,2,SPAN_RECORD) without a line_reference: each corner's edges' spans,
edge_span_bias's record, NaN where dropped or not known; "corner_sigma_px" (Ntags*4,): each
corner's predicted error under the image's noise, the RMS of its 2-d error (px; per
coordinate it is over sqrt 2), from its two edges' chosen spans' variances (_span_choice),
NaN where dropped or not known;
the edge fits' median misfit; with choose_kind "psf_kind" and "psf_sigma_px" used (sigma
fitted on the edges, _choose_kind), "psf_sigma_se_px" its standard error,
"psf_kind_misfit": each kind's sum of squared misfits after its sigma step)
'''
    img = np.asarray(image)
    H, W = img.shape
    if place_weak_edges is None:
        place_weak_edges = line_reference is None
    Q = np.asarray(Q, dtype=np.float64).reshape(-1, 4, 2)
    N = len(Q)
    if bits is not None:
        bits = np.asarray(bits, dtype=bool).reshape(N, 8, 8)
    rng = float(value_range) if value_range is not None else float(np.nanmax(img) - np.nanmin(img))
    blurs = [(float(sigma), kind)]
    if choose_kind:
        blurs += [(s1, k1) for k1 in PSF_KINDS if k1 != kind
                  for s1 in [_same_variance(float(sigma), kind, k1)] if s1 > 0]
    # the first pass's pixels keep the widest candidate's reach
    reach = BLUR_REACH_SIGMAS * max(s1 for s1, _ in blurs) + np.sqrt(0.5)
    table = _table(*blurs[0])
    info = {}
    nbrs = _neighbours(grid, N)
    q = Q.copy()
    # each edge's current curve as image points (None: the chord)
    shapes = {}
    why_edge = np.full((N, 4), "", dtype=object)
    mis_edge = np.full((N, 4), np.nan)
    far = np.zeros((N, 4), bool)
    found = np.full((N, 4, 2), np.nan)
    noise = 0.0
    # the pixels' noise variance as a line in their value (None: every pixel alike): the
    # first pass's fits tell it, the later passes weight their pixels by its inverse
    line = None
    funcs, end_var = {}, {}
    for npass in range(passes):
        # the passes before the last only place its pixels: each edge alone
        last = npass == passes - 1
        why_edge = np.full((N, 4), "", dtype=object)
        # a corner whose edge's fit sees the dark side only far from it (_sees_dark_near)
        why_corner = np.full((N, 4), "", dtype=object)
        own, start = {}, {}
        live = np.all(np.isfinite(q), axis=(1, 2))
        why_edge[~live] = "not detected"
        # the edges whose curve is the previous pass's fit (not the chord)
        curved = set(shapes)
        curves = _curves_in_frames(q, live, shapes)
        Hc = np.zeros((N, 3, 3))
        if bits is not None and live.any():
            Hc[live] = _homographies(q[live])
        status, Ls, es, ns, off, pix, piy, pt, ps = tag_edge_pixels(
            q, live, np.zeros((N, 8, 8), bool) if bits is None else bits, bits is not None,
            Hc, curves, reach, gap_bits, SAFETY_PX, PLATEAU_PX, MIN_EDGE_PIXELS, W, H)
        # edges seen from their light side only (status 2): their pixels are clean of the
        # data row, but too few on the dark side to place the edge alone
        weak = set()
        for code, why in _EDGE_STATUS.items():
            if code != 2:
                why_edge[status == code] = why
        a_b = off.tolist()
        for f in np.flatnonzero((status == 0) | (status == 2)).tolist():
            i, k = divmod(f, 4)
            if status[i, k] == 2:
                weak.add((i, k))
            a, b = a_b[f], a_b[f + 1]
            own[(i, k)] = (pix[a:b], piy[a:b], pt[a:b], ps[a:b], Ls[i, k], es[i, k], ns[i, k])
            start[(i, k)] = curves[i, k]
        if not own:
            break
        # each edge's last fit, per corner, the span and degree of least expected error
        # (_span_choice: bias^2 + variance from the first pass's curves and noise): the edge
        # alone, with its board line's neighbour beyond that corner (NEIGHBOUR_REACH of it),
        # or with all its board line's neighbours (CANDIDATES)
        choice, end_bias, funcs, end_var = {}, {}, {}, {}
        if last and npass > 0:
            choice, end_bias, funcs, end_var = _span_choice(own, start, weak, nbrs, q, curved,
                                                            table, noise,
                                            gap_bits, (pix, piy, pt, ps, off), grid,
                                            _weights(line, img[piy, pix]),
                                            None if line_reference is None else
                                            functools.partial(line_reference, grid=grid,
                                                              gap_bits=gap_bits),
                                            defer_span_bias and line_reference is None,
                                            np.sqrt(blurs[0][0] ** 2
                                                    + _KIND_VARIANCE[blurs[0][1]]))
        # each fit: (i, k, L, e, n, cubic, start curve, end, weak) and its pieces, (its
        # index, the edge whose pixels, how taken: targets._tag_edge_kernels.PIECE_OWN..,
        # reach px); fit_pixels gathers them all in one pass
        geo, pieces = [], []
        # the first pass only places the second's pixels: each edge alone
        members_of = {key: [m for m in nbrs.get(key, []) if m in own] for key in own} \
            if last else {}
        # each edge's board line neighbours by the end of its chord they lie beyond
        ends_of = {key: {} for key in members_of}
        pairs = [(key, m) for key, ms in members_of.items() for m in ms]
        if pairs:
            (pi, pk), (mi_, mk_) = (np.array(x).T for x in zip(*pairs, strict=True))
            mid = 0.5 * (q[mi_, mk_] + q[mi_, (mk_ + 1) % 4])
            beyond = ((mid - q[pi, pk]) * es[pi, pk]).sum(-1) >= 0
            for (key, m), end in zip(pairs, beyond.tolist(), strict=True):
                ends_of[key][int(end)] = m
        for (i, k), (_, _, _, _, L, e, n) in own.items():
            members = members_of.get((i, k), [])
            if (i, k) in weak and last:
                # a weak edge is placed by its board line's neighbours' dark sides only, on
                # the one cubic through the three (_sees_dark, once its pixels are gathered),
                # where asked (place_weak_edges)
                if not members or not place_weak_edges:
                    why_edge[i, k] = _EDGE_STATUS[2]
                    continue
                pieces += [(len(geo), m, PIECE_ALL, 0.0) for m in [(i, k)] + members]
                geo.append((i, k, L, e, n, True, start[(i, k)], 2, True))
                continue
            ends = ends_of.get((i, k), {})
            picks = choice.get((i, k), (("alone", 2), ("alone", 2)))
            # one fit where both corners chose the same (a "corner" span differs per end)
            tags = [2] if picks[0] == picks[1] and picks[0][0] != "corner" else [0, 1]
            for end in tags:
                span, deg = picks[0 if end == 2 else end]
                if span == "alone":
                    pieces.append((len(geo), (i, k), PIECE_OWN, 0.0))
                elif span == "line":
                    pieces += [(len(geo), m, PIECE_ALL, 0.0) for m in [(i, k)] + members]
                else:
                    # the neighbour's pixels out to NEIGHBOUR_REACH of its length past the
                    # gap (along this edge's chord from its corner k; this edge is 0..L)
                    m = ends[end]
                    reach_px = gap_bits * L / 8.0 + NEIGHBOUR_REACH * own[m][4]
                    pieces += [(len(geo), (i, k), PIECE_ALL, 0.0),
                               (len(geo), m, PIECE_BEYOND_END if end == 1
                                else PIECE_BEFORE_START, reach_px)]
                geo.append((i, k, L, e, n, deg == 3, start[(i, k)], end, False))
        if not geo:
            # every edge seen from its light side only, none placed by its neighbours: each
            # has its reason
            break
        geo, pixels = _fit_pixels(img, geo, pieces, q, (pix, piy, pt, ps, off), why_edge,
                                  why_corner if last else None)
        if not geo:
            break
        E = _Edges(geo, pixels, reach, line, rng)
        if len(blurs) > 1:
            (sigma, kind), table, fits, info = _choose_kind(E, blurs)
            blurs = [(sigma, kind)]
            reach = BLUR_REACH_SIGMAS * sigma + np.sqrt(0.5)
        else:
            fits = _fit_contrast_first(E, table)
        pf, ok, mis = fits
        gi, gk, gend = (np.array([g[f] for g in geo], dtype=np.int64) for f in (0, 1, 7))
        if last:
            np.fmax.at(mis_edge, (gi, gk), mis)
        else:
            mis_edge[gi, gk] = mis
        # each failed fit's reason, in the fits' order (an edge's later one stands)
        failed = ~ok | ~(np.abs(pf[:, 1]) > min_contrast * rng) | ~(mis <= max_misfit)
        for j in np.flatnonzero(failed):
            why_edge[gi[j], gk[j]] = (
                EDGE_OFF_PROFILE if not ok[j] and np.isnan(mis[j])
                else EDGE_CONTRAST_OFF if np.isinf(mis[j])
                else f"edge fit not converged in {MAX_ITERATIONS} iterations" if not ok[j]
                else "no contrast" if not abs(pf[j, 1]) > min_contrast * rng
                else f"misfit: {mis[j]:.3g} of the contrast")
        keys = zip(gi.tolist(), gk.tolist(), gend.tolist(), strict=True)
        # the board's edges: the fitted curves less the blur's shift of a bent edge
        dc = pf[:, 2:] if line_reference is None else \
            _unbent(pf[:, 2:], np.array([g[2] for g in geo]), *blurs[0])
        curves = dict(zip(keys, dc, strict=True))
        # each edge's curve at its ends 0 and 1 (a fit of both ends, end 2, gives both)
        at_end = np.zeros((N, 4, 2, 4))
        both = gend == 2
        at_end[gi[both], gk[both], 0] = at_end[gi[both], gk[both], 1] = dc[both]
        at_end[gi[~both], gk[~both], gend[~both]] = dc[~both]
        # each end's curve less its fit's model error there (_span_choice's board map: the
        # bend of the board line that the fit's polynomial cannot follow)
        for (i, k), bb in end_bias.items():
            at_end[i, k, 0, 0] -= bb[0]
            at_end[i, k, 1, 0] -= bb[1]
        good = np.isfinite(mis) & ok
        # the next pass's measure of the image's noise: the edges' median misfit (RMS over
        # the contrast; each edge alone, noise-free a quadratic's model error), and how it
        # varies with the pixel's value
        noise = float(np.median(mis[good])) if good.any() else 0.0
        if line is None and not last:
            line = _noise_line(E, table, pf, good)

        qn = np.full((N, 4, 2), np.nan)
        # edge a ends at corner k, edge b starts there: both without a reason
        clean = why_edge == ""
        mi, mk = np.nonzero(np.roll(clean, 1, axis=1) & clean)
        if len(mi):
            ma = (mk - 1) % 4
            qn[mi, mk] = meet_curves(q[mi, ma], Ls[mi, ma], es[mi, ma], ns[mi, ma],
                                     at_end[mi, ma, 1], q[mi, mk], Ls[mi, mk], es[mi, mk],
                                     ns[mi, mk], at_end[mi, mk, 0], MEET_ITERATIONS)
        # the next pass places its pixels about these curves, its chords through these corners
        # (none after the last pass); an edge fitted per corner keeps its end 1's curve
        pick = {} if last else {
            (i, k): c for (i, k, end), c in curves.items()
            if not (end != 2 and (i, k, 2) in curves)
            # a weak edge's failed fit alone places nothing: the chord does
            and not ((i, k) in weak and why_edge[i, k])
            # nor does a fit that never started (its curve is its start's), or one that ran
            # off into the blur's tail
            and why_edge[i, k] not in (EDGE_OFF_PROFILE, EDGE_CONTRAST_OFF)}
        shapes = {}
        if pick:
            tau9 = np.linspace(-1.0, 1.0, 9)
            keys = list(pick)
            ki, kk = np.array(keys).T
            L, e, n = Ls[ki, kk], es[ki, kk], ns[ki, kk]
            c = np.array(list(pick.values()))
            pts = q[ki, kk][:, None, :] + (0.5 * L[:, None] * (tau9 + 1.0))[..., None] \
                * e[:, None, :] + _curve_s(c.T[..., None], tau9)[..., None] * n[:, None, :]
            shapes = dict(zip(keys, pts, strict=True))
        # the first pass starts from Q, the next ones from the previous pass's corners
        far = np.linalg.norm(qn - q, axis=-1) > (
            start_error_px if npass == 0 and start_error_px else MAX_CORNER_SHIFT_PX)
        found = np.where(far[..., None], np.nan, qn)
        # a corner not found keeps its place for the next pass's chords (its edges are
        # fitted again, and judged there)
        q = np.where(np.isfinite(found), found, q)
    # corner k's reason: its edge k-1's, else its edge k's, else where they met
    before = np.roll(why_edge, 1, axis=1)
    edges = np.where(before != "", before, why_edge)
    met = np.where(far, "edges meet far from the corner",
                   np.where(np.isfinite(found).all(-1), "", "edges do not meet near the corner"))
    reasons = np.where(edges != "", edges, np.where(why_corner != "", why_corner,
                                                    met.astype(object)))
    q = np.where((reasons == "")[..., None], found, np.nan)
    good = np.isfinite(mis_edge)
    if line_reference is None and funcs:
        # what the calibrators' bias step needs of each corner (edge_span_bias): its edges'
        # span functionals and the blur's variance
        spans = np.full((N, 4, 2, SPAN_RECORD), np.nan)
        for (i, k), (h0, h1) in funcs.items():
            spans[i, (k + 1) % 4, 0, :6], spans[i, (k + 1) % 4, 0, 7:] = h1[:6], h1[6:]
            spans[i, k, 1, :6], spans[i, k, 1, 7:] = h0[:6], h0[6:]
        spans[..., 6] = blurs[0][0] ** 2 + _KIND_VARIANCE[blurs[0][1]]
        spans[reasons != ""] = np.nan
        info["edge_spans"] = spans.reshape(N * 4, 2, SPAN_RECORD)
    if end_var:
        # each corner's predicted error (_span_choice's variance of its two edges' chosen
        # spans across each edge at the corner, the noise's share of its risk): the edges'
        # misses ea, eb along their normals na, nb move the corner by M^-1 (ea, eb), M the
        # normals' rows, whose 2-d variance is (va + vb) / sin^2 of the angle between them
        var = np.full((N, 4, 2), np.nan)
        for (i, k), (v0, v1) in end_var.items():
            var[i, (k + 1) % 4, 0], var[i, k, 1] = v1, v0
        na = np.roll(ns, 1, axis=1)
        sin = na[..., 0] * ns[..., 1] - na[..., 1] * ns[..., 0]
        with np.errstate(invalid="ignore", divide="ignore"):
            v2 = var.sum(-1) / (sin * sin)
        info["corner_sigma_px"] = np.where((reasons == "") & np.isfinite(v2) & (v2 > 0),
                                           np.sqrt(v2), np.nan).ravel()
    return CornerFit(q=q.reshape(-1, 2), reasons=reasons.ravel(),
                     misfit=np.repeat(np.nanmax(np.where(good, mis_edge, -1.0), axis=1), 4),
                     npixels=np.zeros(N * 4, np.int64),
                     info={**info, "corner_model": "tag edges",
                           "edge_misfit_median": float(np.median(mis_edge[good]))
                           if good.any() else float("nan")})


# the span/degree candidates of an edge's last fit, per corner (targets.tag_edges._span_choice):
# the edge alone or with its board line's neighbour beyond that corner (NEIGHBOUR_REACH of
# it), a cubic; the edge with all its board line's neighbours, a quadratic or a cubic. A
# quadratic over a short span has its corner at the span's end, where its bias is the
# line's third derivative, which the reference tells only by its curves' disagreement: on
# MER hazcam 17's realistic renders those were chosen on that noise (max corner error 0.025
# px against 0.022 without them; RMS 0.0051 against 0.0050)
CANDIDATES = (("alone", 3), ("corner", 3), ("line", 2), ("line", 3))
# the board line's reference (_span_choice): its polynomial degree from the first pass's
# curves of 1, 2 or 3 edges (3 samples each): the edge's own quadratic; with one neighbour a
# quartic (one sample of 6 to spare); with both a quintic (3 to spare: the quartic and quintic
# terms a cubic over the line cannot follow)
REFERENCE_DEGREE = {1: 2, 2: 4, 3: 5}
# where each first-pass quadratic is sampled (tau of its own chord): the zeros of the third
# Legendre polynomial, where a least-squares quadratic meets a cubic curve it was fitted to
_SAMPLE_TAU = np.array([-np.sqrt(0.6), 0.0, np.sqrt(0.6)])


def _normal_matrix(mu, deg):
    r'''(I (..., deg+3, deg+3), B (..., deg+3, 6)) from span_moments' sums mu (...,
SPAN_MOMENTS): the normal matrix of (light level, contrast, d0..d_deg), in units of the
contrast, and B r its right-hand side for a pixel data g r(tau) (a curve r = sum r_l tau^l
off the one fitted, l <= 5)'''
    n = deg + 1
    W, G, FG, GG = (mu[..., SPAN_W:SPAN_G], mu[..., SPAN_G:SPAN_FG], mu[..., SPAN_FG:SPAN_GG],
                    mu[..., SPAN_GG:])
    shape = mu.shape[:-1]
    I = np.zeros(shape + (n + 2, n + 2))
    I[..., 0, 0], I[..., 0, 1], I[..., 1, 1] = W[..., 0], W[..., 1], W[..., 2]
    I[..., 1, 0] = W[..., 1]
    I[..., 0, 2:], I[..., 1, 2:] = G[..., :n], FG[..., :n]
    I[..., 2:, 0], I[..., 2:, 1] = G[..., :n], FG[..., :n]
    idx = np.arange(n)[:, None] + np.arange(n)[None, :]
    I[..., 2:, 2:] = GG[..., idx]
    B = np.zeros(shape + (n + 2, 6))
    B[..., 0, :], B[..., 1, :] = G, FG
    B[..., 2:, :] = GG[..., np.arange(n)[:, None] + np.arange(6)[None, :]]
    return I, B


_BINOMIAL = np.array([[math.comb(r, c) for c in range(SPAN_MOMENTS - SPAN_GG)]
                      for r in range(SPAN_MOMENTS - SPAN_GG)], dtype=np.float64)


def _moved(mu, alpha, beta):
    r'''The moments mu (..., P, SPAN_MOMENTS) of edge_moments in a frame where tau' = alpha +
beta tau (alpha, beta (P,)): each sum of w tau'^k by the binomial expansion'''
    K = SPAN_MOMENTS - SPAN_GG
    k = np.arange(K)
    T = _BINOMIAL * np.vander(alpha, K, increasing=True)[:, np.clip(k[:, None] - k, 0, None)] \
        * np.vander(beta, K, increasing=True)[:, None, :]
    out = mu.copy()
    for lo, hi in ((SPAN_G, SPAN_FG), (SPAN_FG, SPAN_GG), (SPAN_GG, SPAN_MOMENTS)):
        n = hi - lo
        out[..., lo:hi] = np.einsum("pkj,...pj->...pk", T[:, :n, :n], mu[..., lo:hi])
    return out


def _solve(A, b):
    r'''A^-1 b for a stack of normal matrices A (..., n, n), b (..., n, k); a singular one
(an edge without pixels on its profile's slope) by its pseudo-inverse'''
    try:
        return np.linalg.solve(A, np.broadcast_to(b, A.shape[:-1] + b.shape[-1:]))
    except np.linalg.LinAlgError:
        return np.linalg.pinv(A) @ b


def _powers(tau, n):
    return np.asarray(tau, dtype=np.float64)[..., None] ** np.arange(n)


def _horner(c, tau):
    r'''(m,k): the polynomials c (m,l) (coefficients of tau^0..tau^(l-1)) at tau (m,k), by
Horner's rule (numpy's power per term took ~5 ms of a 1024x1024 image's _span_choice; the
values differ from the sum of powers by rounding, ~1e-16 relative)'''
    y = np.broadcast_to(c[:, -1:], tau.shape)
    for j in range(c.shape[1] - 2, -1, -1):
        y = y * tau + c[:, j:j + 1]
    return y


# the LINEAR_MISS test's samples of a span's reach (u: -1..1 across it)
_MISS_U = np.linspace(-1.0, 1.0, 33)


@functools.lru_cache(maxsize=4)
def _miss_projector(deg):
    r'''(33,33) the transposed least-squares projector onto the polynomials of degree deg at
the samples _MISS_U: y @ it is the fit of degree deg to y (_span_choice's LINEAR_MISS test;
the same for every span and image, an SVD each before it was kept)'''
    V = _MISS_U[:, None] ** np.arange(deg + 1)
    P = (V @ np.linalg.pinv(V)).T
    P.flags.writeable = False
    return P


def _corner_fits(M, deg, tc):
    r'''(var (x,m), h (x,m,6)) of the fits of degree deg on the moments M (x, m,
SPAN_MOMENTS), each row x's at its corner tau = tc[x]: the variance across the edge (px^2)
and the functional on a board line's quintic (the fit's miss at the corner)'''
    A, B = _normal_matrix(M, deg)
    vc = np.zeros((len(tc), 1, deg + 3, 1))
    vc[:, 0, 2:, 0] = tc[:, None] ** np.arange(deg + 1)
    z = _solve(A, vc)[..., 0]
    var = np.einsum("xnk,xk->xn", z, vc[:, 0, :, 0])
    h = np.einsum("xnk,xnkl->xnl", z, B) - (tc[:, None] ** np.arange(6))[:, None]
    return var, h


def _union(*ranges):
    r'''(m,2) the smallest range holding each row's ranges (m,2) lo, hi (NaN rows: none)'''
    r = np.stack(ranges)
    return np.stack((np.nanmin(r[..., 0], axis=0), np.nanmax(r[..., 1], axis=0)), -1)


def _span_choice(own, start, weak, nbrs, q, curved, table, noise, gap_bits, pixels, grid=None,
                 weights=None, line_reference=None, deferred=False, spread=None):
    r'''{(i, k): (choice at corner k, choice at corner k+1)}, each a (span, degree) of
CANDIDATES: the fit of each edge (not weak) with the least expected squared error of its
corner across the edge, bias^2 + variance

Why. A cubic over the edge and both its board line's neighbours (~3.6 edge lengths)
averages the noise over three edges' pixels, but misses a line bent more than a cubic
follows (a fisheye's big tags near the image's corner: 0.01-0.04 px); a shorter span or a
higher degree follows the bend and lets more noise through. Each candidate is judged per
corner on the image's own numbers:

- variance: the corner's (tau = -1 or 1 of the edge's chord, across it) under the
  candidate's linearised least squares, light level and contrast free, from the pixels'
  information (F, F'(x) about the first pass's curves, over the noise: the first pass's
  median misfit; targets._tag_edge_kernels.edge_moments, moved into the edge's frame by
  _moved). Checked against 8 noise seeds on navcam 15's realistic renders: the predicted
  corner scatter 0.0017 px (the three edges' cubic) and 0.0051 (a quadratic alone), the
  measured 0.0018 and 0.0048 (medians);
- bias: the candidate's weighted least-squares projection of the board line's reference
  (a polynomial, REFERENCE_DEGREE, through the first pass's curves of the edge and its
  neighbours, sampled at _SAMPLE_TAU) at the corner, less the reference there. The
  reference's noise (the first pass's curves' covariance) makes its square too large by
  its variance, which is subtracted: an unbiased estimate of bias^2. That estimate is as
  noisy as the fit it judges (on navcam 15's straight lines, the three edges' cubic:
  0.0011 px against its own scatter 0.0012), and the least of four noisy estimates picks a
  short span too often; the bend is the lens's, smooth across the image, so the estimate
  is pooled over the same edge of the 3 x 3 tags round it (`grid`; realistic corners of
  hazcam 17 0.0057 -> 0.0051 px RMS, hazcam 8 0.0054 -> 0.0049, navcam 15 0.0033 ->
  0.0030) and kept >= 0.

A span is judged only where the reference covers it: its neighbours' curves fitted in the
first pass (one seen from its light side only would be extrapolated over: a quadratic
over the line was chosen on the fisheye's corner pose and missed it by 0.029 px).

Tried and left out (h-tagbias), each aimed at the bend bias a calibration cannot average
(the realistic AprilTag / dots projection ratio of ~2 on blur-wide-1024: ~0.0008 px RMS of
corner bias left in the corners' mean over 6 noise seeds of bench_corners' images, scatter
0.0028 px). The estimate itself reads a bias noise-free: unpooled, against the edge's own
cubic's corners, the three edges' cubic's bias regresses on it with slope 0.86 (correlation
0.90), their quadratic's with 1.00 (1.00). Under the noise it is the estimate's noise:
- the chosen span's pooled bias taken off its corner: the pooled estimate is 0.0009 px RMS
  under noise (0.0001 noise-free), as big as the bias; scatter +9%, the bias not reduced;
- the variance over the pool's count nok (a bias shared by nok edges weighed like nok
  corners' noise averaged). bench_corner_campaign.py --response realistic --seeds 0-3
  (load 12-22), residual / projection ratio, before -> after: blur-wide 0.79 / 1.87 ->
  0.97 / 1.08, but 15 0.73 / 0.29 -> 0.89 / 0.37, 17 CAHVOR 0.78 / 0.89 -> 1.06 / 1.17,
  17 CAHVORE 0.82 / 1.43 -> 1.05 / 1.74, 8 CAHVOR 0.86 / 0.97 -> 1.04 / 1.15, 8 CAHVORE
  1.15 / 1.41 -> 1.38 / 1.35 (pooled over 5 x 5 tags: projection 1.41 on blur-wide, 1.28
  on 8 CAHVORE, the rest worse; residual 0.92-1.51): the shorter spans' noise costs
  every camera 20-30% of residual, and only on blur-wide is the projection excess this
  bias (17 and 8 as CAHVORE carry a model error noise-free);
- the three edges' quadratic left out of CANDIDATES (chosen for 90 of 576 corner ends
  under noise, 1 noise-free): bias over the seeds 0.0008 -> 0.00048 px, scatter +8%; the
  campaign as above: blur-wide 0.84 / 1.69, 8 CAHVORE 1.17 / 1.31, 17 CAHVORE 0.90 /
  1.39, but 17 CAHVOR 0.93 / 1.37 (one seed 0.93 -> 2.27), 15 0.83 / 0.42, 8 CAHVOR
  0.93 / 0.97: within the seeds' scatter, no clear gain;
- a fifth candidate, the edge with the nearer halves of both neighbours (a cubic, the
  corner inside the span): chosen for 96 of 576 ends, the bias over the seeds unchanged
  (0.00077 px);
- b2 plus its standard error (4 b^2 bvar + 2 bvar^2, pooled) as the risk: the bias over
  the seeds unchanged (0.00081 px).
Taking each corner's bias off with an estimate whose noise the board averages needs a
reference far less noisy than the first pass's single-edge quadratics. What one would give
(the noise-free image's reference replayed on its 6 noisy images, an oracle): every corner
on the three edges' cubic (or the edge alone, or half its neighbour, by variance), its
unpooled bias taken off: bias over the seeds 0.00035 px, scatter +7% (0.0030 px); with
today's choice and no correction it is 0.00136 (the choice takes the long spans more).
A board line's bend predicted for the whole image (one plane, one lens) would be such a
reference.

own: {(i, k): (ix, iy, t, s, L, e, n)}; start: each edge's first-pass curve (d0..d2) in its
frame; weak: the edges seen from their light side only (no choice: the three edges'
cubic places them); curved: the edges whose start is a fit (not the chord); nbrs:
_neighbours; q (N,4,2) the corners; table: _edge_table; noise: misfit RMS / contrast;
pixels: (ix, iy, t, s, a) of tag_edge_pixels: edge (i, k)'s are [a[4i+k], a[4i+k+1]);
grid: refine_tag_edges' (None: no pooling); weights: the pixels' (_weights; None: alike)

Also returned: the end biases taken off (with a line_reference), the chosen spans'
functionals ({(i, k): (end 0's, end 1's)}, edge_span_bias's) and their variances of the
corner across the edge ({(i, k): (end 0's, end 1's)} px^2, NaN where not known)'''
    ix, iy, pt, ps, off = pixels
    # every edge's own moments (a weak one's curve may still be a neighbour's reference)
    keys = list(own)
    row = {key: j for j, key in enumerate(keys)}
    # every edge's moments about its first-pass curve, in its own frame, in three bins
    # along it: its nearer NEIGHBOUR_REACH from either end and the rest
    Ne = len(keys)
    ik = np.array(keys)
    flat = 4 * ik[:, 0] + ik[:, 1]
    Ls = np.array([own[key][4] for key in keys])
    es = np.array([own[key][5] for key in keys])
    ns = np.array([own[key][6] for key in keys])
    ds = np.array([start[key][:3] for key in keys])
    qs = q[ik[:, 0], ik[:, 1]]
    fa = np.clip(np.arctan2(np.abs(ns).min(-1), np.abs(ns).max(-1)) / (np.pi / 4)
                 * (TABLE_ANGLES - 1), 0.0, TABLE_ANGLES - 1.000001)
    j0 = fa.astype(np.int64)
    cut = 2.0 * NEIGHBOUR_REACH - 1.0
    cuts = np.array([min(cut, -cut), max(cut, -cut)])
    # each end's board line neighbour, its moments moved into this edge's frame (tau
    # affine in the neighbour's own tau along its chord): all of them, and those of its
    # nearer part (NEIGHBOUR_REACH of it)
    pairs = [(j, row[m]) for j, key in enumerate(keys) for m in nbrs.get(key, ()) if m in row]
    ends = [{} for _ in keys]
    if pairs:
        pj, pm = np.array(pairs).T
        e = es[pj]
        mid = 0.5 * (q[ik[pm, 0], ik[pm, 1]] + q[ik[pm, 0], (ik[pm, 1] + 1) % 4])
        pe = np.where(((mid - qs[pj]) * e).sum(-1) < 0, 0, 1)
        for j, end, r in zip(pj.tolist(), pe.tolist(), pm.tolist(), strict=True):
            ends[j][end] = keys[r]
    has = np.array([[end in at for end in (0, 1)] for at in ends])
    # the reference: samples of the first pass's curves of the edge (slot 0) and its
    # neighbours at ends 0, 1 (slots 1, 2), in the edge's frame
    S = len(_SAMPLE_TAU)
    tau_s = np.zeros((Ne, 3, S))
    v_s = np.zeros((Ne, 3, S))
    use = np.zeros((Ne, 3), bool)
    proj = np.zeros((Ne, 3))
    Vs = _powers(_SAMPLE_TAU, 3)
    trip = [(j, c, row[m]) for j, key in enumerate(keys)
            for c, m in enumerate((key, ends[j].get(0), ends[j].get(1)))
            if m is not None and m in curved]
    if trip:
        tj, tc_, tm = np.array(trip).T
        e, n, nm = es[tj], ns[tj], ns[tm]
        P = (qs[tm] - qs[tj])[:, None] \
            + ((_SAMPLE_TAU + 1.0) * 0.5)[None, :, None] * (Ls[tm, None] * es[tm])[:, None, :] \
            + (ds[tm] @ Vs.T)[..., None] * nm[:, None, :]
        tau_s[tj, tc_] = 2.0 * (P * e[:, None]).sum(-1) / Ls[tj, None] - 1.0
        v_s[tj, tc_] = (P * n[:, None]).sum(-1)
        use[tj, tc_] = True
        proj[tj, tc_] = (nm * n).sum(-1)
    nc = use.sum(1)
    R = np.zeros((Ne, 6, 3 * S))
    for cnt, D in REFERENCE_DEGREE.items():
        sel = np.flatnonzero(nc == cnt)
        if not len(sel):
            continue
        w = np.repeat(use[sel], S, axis=1).astype(np.float64)
        V = _powers(tau_s[sel].reshape(len(sel), -1), D + 1) * w[..., None]
        R[sel, :D + 1] = np.linalg.solve(V.transpose(0, 2, 1) @ V, V.transpose(0, 2, 1))
    ref = np.einsum("nks,ns->nk", R, v_s.reshape(Ne, -1))
    # an edge without a first-pass curve (its fit alone failed; a weak edge's, seen from its
    # light side, often does) between two neighbours with one: its moments about the
    # reference's quadratic over it (interpolated between them) rather than its chord (the
    # first pass's corners, off the edge by up to the pixels' margin), where its pixels'
    # slopes, and so its fits' predicted variances, would be misread
    bridged = np.flatnonzero(~use[:, 0] & use[:, 1] & use[:, 2])
    if len(bridged):
        ds = ds.copy()
        ds[bridged] = np.linalg.solve(Vs, _horner(ref[bridged], np.broadcast_to(
            _SAMPLE_TAU, (len(bridged), S)))[..., None])[..., 0]
    wt = np.ones(len(pt)) if weights is None else weights
    mom = edge_moments(pt, ps, wt, off[flat], off[flat + 1], ds, Ls, j0, fa - j0, cuts, table[0],
                       TABLE_STEP_PX, table[1], table[2]) / max(noise, 1e-12) ** 2
    m_own = mom.sum(1)
    m_nb = np.zeros((Ne, 2, 2, SPAN_MOMENTS))
    ext_nb = np.full((Ne, 2, 2, 2), np.nan)     # (edge, end, all / nearer part, lo / hi)
    if pairs:
        L, Lm, e = Ls[pj], Ls[pm], es[pj]
        c = (es[pm] * e).sum(-1)
        alpha = (2.0 * ((qs[pm] - qs[pj]) * e).sum(-1) + Lm * c) / L - 1.0
        beta = Lm * c / L
        # the neighbour's end nearer this edge: tau = -1 where its direction runs away
        low = (c > 0) == (pe == 1)
        near = np.where(low[:, None], [[True, cut >= 0, False]], [[False, cut >= 0, True]])
        moved = _moved(np.stack((mom[pm].sum(1), (mom[pm] * near[..., None]).sum(1))), alpha,
                       beta)
        m_nb[pj, pe, 0], m_nb[pj, pe, 1] = moved
        # where each neighbour (all of it, its nearer part) lies along this edge's chord
        nb_lo = np.where(low, -1.0, -cut)
        nb_hi = np.where(low, cut, 1.0)
        for w, (a, b) in enumerate(((-1.0, 1.0), (nb_lo, nb_hi))):
            ta, tb = alpha + beta * a, alpha + beta * b
            ext_nb[pj, pe, w] = np.stack((np.minimum(ta, tb), np.maximum(ta, tb)), -1)
    m_all = m_own + m_nb[:, 0, 0] + m_nb[:, 1, 0]
    # the first pass's curve of each edge alone: its (d0, d1, d2)'s covariance
    own_G = _solve(_normal_matrix(m_own, 2)[0], np.eye(5)[None, :, 2:])[:, 2:, :]
    Ginv = np.zeros((Ne, 3, 3, 3))
    if trip:
        Ginv[tj, tc_] = own_G[tm]
    mapped = None
    if line_reference is not None:
        mapped = np.asarray(line_reference(ik, qs, es, ns, Ls), dtype=np.float64)
    # the samples' sensitivity to each curve's (d0, d1, d2), across this edge's frame
    dS = (proj * use)[..., None, None] * Vs[None, None]
    # the bias pooled over the same edge of the tags round it (a 3 x 3 block of the grid):
    # the bend is the lens's, smooth across the image, the estimates' noise independent
    pool = np.eye(Ne)
    if grid is not None:
        # (each axis compared apart: numpy's max over a trailing axis of 2 took ~1-4 ms here)
        cell = np.asarray(grid).reshape(-1, 2)[ik[:, 0]].T
        pool = ((np.abs(cell[0][:, None] - cell[0][None]) <= 1)
                & (np.abs(cell[1][:, None] - cell[1][None]) <= 1)
                & (ik[:, None, 1] == ik[None, :, 1])).astype(np.float64)
    # a span is judged only where the reference covers it: its neighbours' curves in it
    # (a neighbour without one, seen from its light side, would be extrapolated over)
    covered = (use[:, 1:] | ~has).all(1)
    # each span's moments, where it is judged, and where it exists: its variance and
    # functional need only its pixels (a weak edge's cubic over its board line, placed
    # whether or not the reference covers it, refine_tag_edges; its corners' prediction)
    spans = {"alone": lambda end: (m_own, use[:, 0], np.ones(Ne, bool)),
             "corner": lambda end: (m_own + m_nb[:, end, 1],
                                    use[:, 0] & has[:, end] & use[:, 1 + end], has[:, end]),
             "line": lambda end: (m_all, use[:, 0] & has.any(1) & covered, has.any(1))}
    combos = [(end, span, deg) for end in (0, 1) for span, deg in CANDIDATES]
    # each span's reach along the edge's chord (tau; the edge itself -1..1): where the board
    # line's shape enters its fit, what edge_span_bias represents the line over
    own_ext = np.broadcast_to([-1.0, 1.0], (Ne, 2))
    reach = {"alone": lambda end: own_ext,
             "corner": lambda end: _union(own_ext, ext_nb[:, end, 1]),
             "line": lambda end: _union(own_ext, ext_nb[:, 0, 0], ext_nb[:, 1, 0])}
    exts = np.stack([reach[span](end) for end, span, _ in combos])
    risk = np.full((len(combos), Ne), np.inf)
    # each span's variance of its corner across the edge, px^2 (the noise's share of risk)
    variance = np.full((len(combos), Ne), np.nan)
    mbias = np.full((len(combos), Ne), np.nan)
    # each span's functional on a board line's coefficients: its fit's miss at the corner
    hs = np.full((len(combos), Ne, 6), np.nan)
    for deg in sorted({c[2] for c in combos}):
        sel = [i for i, c in enumerate(combos) if c[2] == deg]
        M, ok, can = (np.stack(x) for x in zip(*[spans[combos[i][1]](combos[i][0])
                                                 for i in sel], strict=True))
        tc = np.array([2.0 * combos[i][0] - 1.0 for i in sel])
        var, h = _corner_fits(M, deg, tc)
        variance[sel] = np.where(can & (var > 0), var, np.nan)
        # the bias's functional h on the reference's coefficients (those above its degree
        # are 0), and its noise through the first pass's curves
        bias = (h * ref).sum(-1)
        hs[sel] = np.where(can[..., None], h, np.nan)
        um = np.einsum("xnms,nmsd->xnmd",
                       np.einsum("xnk,nks->xns", h, R).reshape(len(sel), Ne, 3, S), dS)
        bvar = (np.einsum("xnmd,nmde->xnme", um, Ginv) * um).sum((-2, -1))
        # bias^2 less its estimate's noise, pooled, kept >= 0
        b2 = np.where(ok & np.isfinite(bias * bvar), bias * bias - bvar, 0.0)
        nok = ok @ pool.T
        b2 = np.where(nok > 0, (b2 @ pool.T) / np.where(nok > 0, nok, 1.0), 0.0)
        if deferred:
            # the bias is taken off later (the calibrators' bias step, edge_span_bias): the
            # risk left is its error, as with a line_reference
            b2 = np.where(ok & np.isfinite(bias), (REFERENCE_BIAS_LEFT * bias) ** 2, 0.0)
        if mapped is not None:
            # the given reference's bias where it has one: taken off the corner (the risk
            # left is its error, a fraction of it), else the first pass's estimate as before
            have = np.isfinite(mapped).all(-1)
            mb = (h * np.where(have[:, None], mapped, 0.0)).sum(-1)
            mbias[sel] = np.where(have, mb, np.nan)
            b2 = np.where(have, (REFERENCE_BIAS_LEFT * mb) ** 2, b2)
        risk[sel] = np.where(ok & (var > 0), np.maximum(b2, 0.0) + var, np.inf)
    if spread is not None:
        # a span's functional is its fit's linearised in the board line's shape: where its
        # polynomial misses the line (the reference over its reach) by more than
        # LINEAR_MISS of the blurred edge's spread, neither its bias estimate nor a later
        # bias step holds, and the span is not chosen (the edge alone always may be)
        u = _MISS_U
        for x, (_, span, deg) in enumerate(combos):
            if span == "alone":
                continue
            lo, hi = exts[x, :, 0:1], exts[x, :, 1:2]
            y = _horner(ref, 0.5 * (lo + hi) + 0.5 * (hi - lo) * u[None])
            miss = np.abs(y - y @ _miss_projector(deg)).max(-1)
            risk[x] = np.where(miss > LINEAR_MISS * spread, np.inf, risk[x])
    out = {}
    n = len(CANDIDATES)
    pick = [np.argmin(risk[n * end:n * (end + 1)], axis=0) for end in (0, 1)]
    fine = np.isfinite(risk[:n].min(0)) & np.isfinite(risk[n:].min(0))
    biases = {}
    # the chosen spans' functionals (a weak edge's: the cubic over its board line)
    funcs = {}
    c = CANDIDATES.index(("line", 3))

    # and their variances at each end (the corner's noise across the edge, px^2)
    end_var = {}

    def func(x, j):     # a span's functional and its reach
        return np.concatenate((hs[x, j], exts[x, j]))
    for j in [row[key] for key in weak if key in row]:
        funcs[keys[j]] = (func(c, j), func(n + c, j))
        end_var[keys[j]] = (variance[c, j], variance[n + c, j])
    for j in np.flatnonzero(fine):
        out[keys[j]] = (CANDIDATES[pick[0][j]], CANDIDATES[pick[1][j]])
        if keys[j] not in weak:
            funcs[keys[j]] = (func(pick[0][j], j), func(n + pick[1][j], j))
            end_var[keys[j]] = (variance[pick[0][j], j], variance[n + pick[1][j], j])
        bb = (mbias[pick[0][j], j], mbias[n + pick[1][j], j])
        if mapped is not None and np.isfinite(bb).all() and keys[j] not in weak:
            biases[keys[j]] = bb
    # an edge no span was judged for (its first pass's curve not kept: no reference) is
    # fitted alone, a quadratic (refine_tag_edges' default): its own pixels' variances
    rest = [j for j in np.flatnonzero(~fine).tolist() if keys[j] not in weak]
    if rest:
        var2, h2 = _corner_fits(np.broadcast_to(m_own[rest], (2,) + m_own[rest].shape), 2,
                                np.array([-1.0, 1.0]))
        var2 = np.where(var2 > 0, var2, np.nan)
        for x, j in enumerate(rest):
            funcs[keys[j]] = tuple(np.concatenate((h2[end, x], own_ext[j])) for end in (0, 1))
            end_var[keys[j]] = (var2[0, x], var2[1, x])
    if mapped is not None:
        # a weak edge is placed by the cubic over its board line (refine_tag_edges)
        c = CANDIDATES.index(("line", 3))
        for j in [row[key] for key in weak if key in row]:
            bb = (mbias[c, j], mbias[n + c, j])
            if np.isfinite(bb).all():
                biases[keys[j]] = bb
    return {key: v for key, v in out.items() if key not in weak}, biases, funcs, end_var


# the fraction of a reference's bias taken as the risk left once it is taken off
# (_span_choice with a line_reference: the reference's own error)
REFERENCE_BIAS_LEFT = 0.25
# the most a span's polynomial may miss its board line over the span's reach (the first
# pass's reference), in the blurred edge's spread s = sqrt(V) (_span_choice): the edge's
# profile Phi(x / s) is linear in a shift x to 1% where (x / s)^2 / 6 <= 0.01. On a barrel
# built here (campaigns/cameras/barrel-1024x768.cahvor, R1 -0.2), pose 3, blur only: a
# quadratic over an edge and its one neighbour 0.81 px off the line was chosen (its
# deferred bias estimate blind to the quintic term the reference lacked): the corner 0.071
# px off after the bias step, the pose 0.0062 px RMS; refused, 0.012 and 0.0014
# (test_a_span_is_chosen_only_where_its_fit_is_linear). Realistic, 8 seeds, the catalogue
# pairs of docs/corners.md move by 0.03 at most
LINEAR_MISS = 0.25


def camera_line_reference(model, Rt_cam_board, bit_m, Rt_ref_board=None):
    r'''A line_reference for refine_tag_edges from a camera model and the board's pose: each
edge's board line (the grid's tag pitch 8 + gap_bits bits of bit_m metres, the tags'
corners as targets.boards' AprilGrid) projected at _REFERENCE_LAMBDA (past both board line
neighbours) and fitted by a quintic in the edge's chord frame. Rt_ref_board: the board's
pose in the model's world frame (a calibration's survey) instead of Rt_cam_board composed
with the model's Rt_ref_cam'''
    from reference_models.poseutils import transform_point_Rt

    from .centroids import board_to_ref

    def to_ref(P):
        return board_to_ref(model, Rt_cam_board, P) if Rt_ref_board is None else \
            transform_point_Rt(np.asarray(Rt_ref_board, dtype=np.float64), P)

    def reference(ik, qs, es, ns, Ls, grid, gap_bits):
        ik = np.asarray(ik).reshape(-1, 2)
        g = np.asarray(grid).reshape(-1, 2)[ik[:, 0]]
        B = g[:, None, :] * (8.0 + gap_bits) + _TAG_CORNERS[None]
        b0 = B[np.arange(len(ik)), ik[:, 1]]
        b1 = B[np.arange(len(ik)), (ik[:, 1] + 1) % 4]
        z = np.zeros((len(ik), 1))
        return _line_quintics(lambda x: model.project(to_ref(x)), np.hstack((b0 * bit_m, z)),
                              np.hstack((b1 * bit_m, z)), qs, es, ns, Ls)
    return reference


def _line_quintics(to_image, b0, b1, qs, es, ns, Ls, reach=None, samples=False):
    r'''(m,6) the board lines through b0 -> b1 (m,3) (board frame) projected at
_REFERENCE_LAMBDA and fitted by a quintic s(tau) in each chord frame (qs, es, ns, Ls);
to_image: (n,3) board points -> (n,2) px; NaN rows where a sample does not project.
reach (m,2): fit each line only where its chord's tau lies in [lo, hi] (a span's reach,
SPAN_RECORD), from _REACH_SAMPLES samples over _REFERENCE_LAMBDA's stretch; all of them
where fewer than _REACH_MIN_SAMPLES fall in it. samples: also return (tau, r, w) (m,S): each
sample's place along the chord, the line less its quintic there and its weight in the fit
(0 outside the reach; NaN rows where the quintic is)'''
    b0, b1 = np.asarray(b0, dtype=np.float64), np.asarray(b1, dtype=np.float64)
    lam = _REFERENCE_LAMBDA if reach is None else \
        np.linspace(_REFERENCE_LAMBDA[0], _REFERENCE_LAMBDA[-1], _REACH_SAMPLES)
    b = b0[:, None] + lam[None, :, None] * (b1 - b0)[:, None]
    p = np.asarray(to_image(b.reshape(-1, 3))).reshape(b.shape[:-1] + (2,))
    p = p - np.asarray(qs)[:, None]
    out = np.full((len(b0), 6), np.nan)
    finite = np.isfinite(p).all(-1)
    ok = finite.all(1)
    w = np.ones(p.shape[:2])
    if reach is not None:
        # where the span's fit reaches (its own edge 1 / 8 px past its pixels' ends is
        # inside a margin of 0.05 of the chord's half length at 20 px and more)
        r = np.asarray(reach, dtype=np.float64)
        tau_all = 2.0 * np.einsum("msk,mk->ms", np.where(finite[..., None], p, 0.0),
                                  np.asarray(es)) / np.asarray(Ls)[:, None] - 1.0
        inside = finite & (tau_all >= r[:, :1] - _REACH_MARGIN) \
            & (tau_all <= r[:, 1:] + _REACH_MARGIN)
        n_in = inside.sum(1)
        use = np.isfinite(r).all(1) & (n_in >= _REACH_MIN_SAMPLES)
        w = np.where(use[:, None], inside, 1.0).astype(np.float64)
        # a line that leaves the image only outside its span's reach is still represented
        ok = np.where(use, inside.any(1) & (finite | ~inside).all(1), ok)
        p = np.where(finite[..., None], p, 0.0)
    if ok.any():
        tau = 2.0 * np.einsum("msk,mk->ms", p[ok], np.asarray(es)[ok]) \
            / np.asarray(Ls)[ok, None] - 1.0
        v = np.einsum("msk,mk->ms", p[ok], np.asarray(ns)[ok])
        wk = w[ok]
        # least squares, each edge's powers scaled to its samples' reach (as polyfit does)
        scale = np.where(wk > 0, np.abs(tau), 0.0).max(1, keepdims=True)
        V = (tau / scale)[..., None] ** np.arange(6)
        WV = V * wk[..., None]
        c = np.linalg.solve(WV.transpose(0, 2, 1) @ V, (WV.transpose(0, 2, 1) @ v[..., None]))
        out[ok] = c[..., 0] / scale ** np.arange(6)
    if not samples:
        return out
    S = p.shape[1]
    tau_s, r_s, w_s = (np.full((len(b0), S), np.nan) for _ in range(3))
    if ok.any():
        tau_s[ok], w_s[ok] = tau, wk
        r_s[ok] = v - (V @ c)[..., 0]
    return out, (tau_s, r_s, w_s)


# edge_span_bias's board line over a span's reach: samples over _REFERENCE_LAMBDA's stretch,
# at least _REACH_MIN_SAMPLES of them in the reach (a lone edge's 1 of 3.9 board edges: 41)
_REACH_SAMPLES = 160
_REACH_MIN_SAMPLES = 12
_REACH_MARGIN = 0.05


# per corner and each of its two edges (the one ending at it, the one starting there), the
# record refine_tag_edges leaves in info["edge_spans"] for edge_span_bias: the functional
# (6) of the span fitted, on a board line's quintic in the edge's chord frame, the blur's
# variance V (px^2), and the span's reach along the chord (tau lo, hi; the edge -1..1)
SPAN_RECORD = 9


def edge_span_bias(model, Rt_cam_board, p_corner, p_before, p_after, spans):
    r'''(m,2) px: where refine_tag_edges (no line_reference) places each corner less its
projection, for the camera model and board pose given (Rt_cam_board: the board in the
model's camera frame); span_miss with that projection'''
    from .centroids import board_to_ref
    return span_miss(lambda x: model.project(board_to_ref(model, Rt_cam_board, x)),
                     p_corner, p_before, p_after, spans)


def span_miss(to_image, p_corner, p_before, p_after, spans):
    r'''(m,2) px: where refine_tag_edges (no line_reference) places each corner less its
image, the board mapped to the image by to_image ((n,3) board points -> (n,2) px)

p_corner, p_before, p_after (m,3): each corner and its tag's corners before and after it
(board frame, m): its edge from p_before ends at it, its edge to p_after starts there;
spans (m,2,SPAN_RECORD): refine_tag_edges' info["edge_spans"] of those two edges.

Each edge's board line, projected (the quintic of camera_line_reference, in the chord frame
of the projected corners), is what the image shows; the fit sees it moved by the blur
towards its centre of curvature (V s''/2, _unbent's shift) and follows it with its span's
polynomial, which misses the corner by the span's functional on that curve (_span_choice's
h). The two edges' misses along their normals move the corner where they meet. NaN where a
record is missing or a line does not project.'''
    m = len(p_corner)
    out = np.full((m, 2), np.nan)
    spans = np.asarray(spans, dtype=np.float64).reshape(m, 2, SPAN_RECORD)
    ok = np.isfinite(spans).all((1, 2))
    if not ok.any():
        return out
    P = np.stack([np.asarray(x, dtype=np.float64)[ok] for x in (p_before, p_corner, p_after)],
                 axis=1)
    qp = np.asarray(to_image(P.reshape(-1, 3))).reshape(-1, 3, 2)
    # edge 0: before -> corner (the corner at tau = 1), edge 1: corner -> after (tau = -1)
    starts = np.stack((qp[:, 0], qp[:, 1]), 1)
    ends = np.stack((qp[:, 1], qp[:, 2]), 1)
    d = ends - starts
    Ls = np.linalg.norm(d, axis=-1)
    es = d / Ls[..., None]
    ns = np.stack((-es[..., 1], es[..., 0]), -1)
    # the normal into the tag: towards the tag's other corner
    other = np.stack((qp[:, 2] - qp[:, 1], qp[:, 0] - qp[:, 1]), 1)
    ns = ns * np.where((ns * other).sum(-1) < 0, -1.0, 1.0)[..., None]
    b0 = np.stack((P[:, 0], P[:, 1]), 1).reshape(-1, 3)
    b1 = np.stack((P[:, 1], P[:, 2]), 1).reshape(-1, 3)
    c, (tau_s, r_s, w_s) = _line_quintics(to_image, b0, b1,
                                          starts.reshape(-1, 2), es.reshape(-1, 2),
                                          ns.reshape(-1, 2), Ls.ravel(),
                                          reach=spans[ok, :, 7:9].reshape(-1, 2), samples=True)
    c = c.reshape(-1, 2, 6)
    # the blur's shift of the curve, c V / 2 s'' (s'' = 4 / L^2 d2s/dtau2), as coefficients
    ddc = np.zeros_like(c)
    ddc[..., :4] = c[..., 2:] * np.array([2.0, 6.0, 12.0, 20.0])
    shift = (2.0 * spans[ok, :, 6] / Ls ** 2)[..., None] * ddc
    tc = np.array([1.0, -1.0])
    seen = c + shift
    # the fitted curve's miss at the corner along each edge's normal
    delta = (shift * tc[:, None] ** np.arange(6)).sum(-1) + (spans[ok, :, :6] * seen).sum(-1)
    # what of the line its quintic misses (a line bent beyond it over a long reach: a board
    # line at a strong barrel's rim), followed by the span's polynomial (_misfit_miss)
    delta = delta + _misfit_miss(spans[ok, :, :6].reshape(-1, 6), np.tile(tc, len(delta)),
                                 c.reshape(-1, 6), tau_s, r_s, w_s).reshape(-1, 2)
    out[ok] = np.linalg.solve(ns, delta[..., None])[..., 0]
    return out


# a span's functional h annihilates the powers its polynomial follows (h_k = 0 for k up to its
# degree, to rounding: ~1e-12 of the others, which are 0.01-1)
_ANNIHILATED = 1e-6


def _misfit_miss(h, tc, c, tau, r, w):
    r'''(m,) px: the span's miss at its corner (tc = +-1 of the chord) of the part r of its
board line that the line's quintic does not hold (_line_quintics' samples (tau, r, w) (m,S))

Why. edge_span_bias's functional h is the span's fit's miss of a quintic; a board line bent
beyond one over the span's reach (the long spans at a strong barrel's rim: sag 4-9 px over
2.6 edge lengths on campaigns/cameras/barrel-1024x768.cahvor) leaves the quintic 0.001-0.005
px off it near the corner, and the span's polynomial follows that misfit too. The span's
polynomial degree d is the powers h annihilates; its fit of r is approximated by the least
squares of degree d over the quintic's samples in the reach (their weights w, each times the
chord it stands for: the span's pixels spread evenly along its reach, the gaps between its
edges not modelled). The miss is that fit at the corner less r there: the line passes through
the corner, so r(tc) is minus the quintic c there. On that barrel, noise-free blurred renders,
the corners less the bias step under the truth: pose seed 2, pose 2 0.00087 -> 0.00057 px RMS
(max 0.0091 -> 0.0046); pose seed 0, pose 4 0.00083 -> 0.00069
(test_span_miss_follows_a_line_bent_beyond_its_quintic: 2.8e-4 -> 1.7e-5 px).'''
    h = np.asarray(h, dtype=np.float64)
    out = np.zeros(len(h))
    a = np.abs(h)
    scale = np.nanmax(a, axis=1, keepdims=True)
    zero = a <= _ANNIHILATED * np.where(scale > 0, scale, 1.0)
    # the degree: the leading run of annihilated powers, less one
    deg = np.where(zero.all(1), 6, np.argmin(zero, axis=1)) - 1
    good = np.isfinite(r).all(1) & np.isfinite(tau).all(1) & np.isfinite(c).all(1) \
        & (deg >= 0) & (deg < 5) & ((w > 0).sum(1) > 5)
    for d in np.unique(deg[good]).tolist():
        sel = np.flatnonzero(good & (deg == d))
        # each sample weighs as much of the chord as it stands for (the pixels lie evenly
        # along the image, the samples evenly along the board)
        t, rr = tau[sel], r[sel]
        ww = w[sel] * np.abs(np.gradient(t, axis=1))
        span = np.where(ww > 0, np.abs(t), 0.0).max(1, keepdims=True)
        V = (t / span)[..., None] ** np.arange(d + 1)
        WV = V * ww[..., None]
        A = WV.transpose(0, 2, 1) @ V
        k = np.linalg.solve(A, WV.transpose(0, 2, 1) @ rr[..., None])[..., 0]
        at = (tc[sel, None] / span) ** np.arange(d + 1)
        quintic = (c[sel] * tc[sel, None] ** np.arange(6)).sum(-1)
        out[sel] = (k * at).sum(-1) + quintic
    return out


# the board line's samples of camera_line_reference: board positions along the edge from its
# corner k (0) to k+1 (1), past both neighbours (gap 2.4 bits: a neighbour spans 1.3 - 2.3)
_REFERENCE_LAMBDA = np.linspace(-1.45, 2.45, 40)


def _sees_dark(n):
    r'''True where the pixels of a weak edge's fit (its board line's, in its chord's frame,
length L) see the dark side of its start curve beyond both its ends (t < 0 and t > L: the
edge's place is interpolated between them, not extrapolated), MIN_EDGE_PIXELS // 2 of them
in all: the count targets._tag_edge_kernels.tag_edge_pixels asks of an edge alone; n (4,):
the fit's dark-side pixel counts (targets._tag_edge_kernels.fit_pixels' dark, which counts
them as it gathers the pixels)

Why. An edge seen from its light side only (tag bits under ~3.5 px at sigma 0.7: every
dark-side pixel sees the light data row inside the 1-bit border) has its own pixels' light
side, clean of the data row; the board line's cubic through it and its neighbours is placed
across it by the neighbours' dark sides. On MER hazcam 17 as CAHVORE (realistic,
benchmarks/bench_corners.py): 81 more corners of 864, at 0.0068 px RMS against the others'
0.0049; with dark pixels beyond one end only (the line extrapolated), 154 more at 0.0095,
max 0.046 px (the others' 0.022).'''
    lo, hi = int(n[0]), int(n[1])
    return min(lo, hi) > 0 and lo + hi >= MIN_EDGE_PIXELS // 2


def _sees_dark_near(n, end):
    r'''True where the pixels of an edge's fit (in its chord's frame, length L) see the dark
side of its start curve nearer its end `end` (0: t = 0, 1: t = L) than the chord's middle, or
beyond that end (a board line's neighbour); n (4,): the fit's dark-side pixel counts
(targets._tag_edge_kernels.fit_pixels' dark)

Why. A corner is where its two edges' curves meet; an edge's curve there is placed by the
pixels that see both sides of it. Its light side alone places it weakly (the blur's tail),
and where the light data cells inside the border line the half of an edge next to a corner
(tag bits of ~3 px at sigma 0.7: their pixels are left out, they see the data row), the
fit's cubic runs from the other half's dark side to the corner unconstrained: MER hazcam 17
as CAHVOR, realistic, seed 4 pose 2, a corner of a tag whose other edges were seen from
their light side only, 0.076 px from its projection (0.40 with the bits' depth across the
edge), its edge's dark side 0.09 < tau < 0.75. Such a corner is dropped, as a weak edge's
corners are where its board line does not reach the dark side beyond its ends
(_sees_dark).'''
    return bool(n[2 + end] > 0)


def _table(sigma, kind):
    return _edge_table(round(float(sigma) / TABLE_SIGMA_STEP_PX) * TABLE_SIGMA_STEP_PX, kind)


# each kind's variance per axis on an area-sampled image beyond its sigma^2 (px^2): the
# pixel's square once (a Gaussian on the scene, which the pixel integrates) or twice (the
# sampled kernel, itself pixel-integrated, on area-sampled pixels; corners.blur_kernel)
_KIND_VARIANCE = {"gaussian": 1.0 / 12.0, "sampled": 1.0 / 6.0}


def _same_variance(sigma, kind, other):
    r'''The sigma of kind other whose blurred edge has the variance of (sigma, kind); 0 where
none has (a sampled kernel narrower than the pixel)'''
    v = sigma * sigma + _KIND_VARIANCE[kind] - _KIND_VARIANCE[other]
    return float(np.sqrt(v)) if v > 0 else 0.0


def _choose_kind(E, blurs):
    r'''((sigma, kind), table, fits, info): the candidate blur whose edge fits (the first
pass's, each edge alone) leave the least squared misfit summed over the edges every
candidate fitted to convergence, each kind at the sigma the edges fit best (_blur_step)

Why. targets.corners.estimate_blur picks the kind on ~32 corner windows of a few dozen
pixels each: the two kinds at the same variance differ in the edge's shape by less than
the noise there, and on half of camera 17's realistic images (as CAHVOR, tag bits of 2.8
px) it chose "gaussian" (sigma 0.75) for the response's sampled blur (0.7): the tag-edge
corners were 0.011-0.020 px RMS off against 0.0055-0.0065 with the right kind (an edge seen
mostly from its light side takes the profile's shape for its position). All the image's
tag edges (10^4-10^6 pixels) tell the shapes apart; both kinds are judged on the same
pixels, so the noise is common to both and no threshold enters. They tell sigma too: the
windows' estimate is a median of per-corner fits scattered by ~0.005 px on the realistic
images (standard error ~0.001 px from 32 corners, both kinds fitted: ~0.04 s per 1024x1024
image), where the one sigma of every edge comes to 2e-4 - 9e-4 px (info
"psf_sigma_se_px"); the windows' quick look (BLUR_QUICK_SAMPLE corners, one kind) only
starts it, and may be far off (0.3 px on camera 17's small windows, estimate_blur): the
first kind's sigma is stepped, the edges refitted, while a step exceeds FIRST_KIND_STEP_PX
(a Gauss-Newton step leaves ~6% of the distance: from 0.05-0.1 px off, 0.003-0.006 px;
from the realistic renders' quick look, 0.0015-0.006 px off, no refit). Each kind's
misfit is compared at its sigma after one more step (predicted: S - G^2 / H, the step's
own quadratic model), and the chosen kind takes that step. One step for the second kind:
it starts at the first's variance, ~0.005 px from its own best sigma on the realistic
renders, and its step lands within ~6e-4 px of the iterated sigma (1-3 standard errors);
iterating it too, a refit of the edges per step (~8% of the detection's CPU), moved the
quick cameras' corners by at most 0.0017 px and their RMS by at most 3e-6 px
(benchmarks/bench_corners.py --response realistic --compare-q).'''
    out = []
    for sg, kd in blurs:
        start = None
        if out:
            # the other kinds at the variance of the first one's stepped sigma, started from
            # its curves: at the same variance the kinds' edges lie within ~0.01 px
            sg = _same_variance(out[0][1] + out[0][4], out[0][0], kd)
            if not sg > 0:
                continue
            start = _restart(out[0][3])
        table = _table(sg, kd)
        fits = _fit_contrast_first(E, table, start, FIRST_PASS_CONVERGED_PX)
        step, dec, S, se = _blur_step(E, table, fits)
        for _ in range(BLUR_STEPS if not out else 0):
            # the first kind starts from the windows' quick look, which may be far off: its
            # sigma is stepped (the edges refitted) while a step is above FIRST_KIND_STEP_PX
            if not (abs(step) > FIRST_KIND_STEP_PX and sg + step > 0):
                break
            sg = sg + step
            table = _table(sg, kd)
            fits = _fit_contrast_first(E, table, _restart(fits), FIRST_PASS_CONVERGED_PX)
            step, dec, S, se = _blur_step(E, table, fits)
        out.append((kd, sg, table, fits, step, dec, S, se))
    both = np.ones(E.m, bool)
    for o in out:
        both &= o[3][1] & np.isfinite(o[3][2])
    sums = []
    for o in out:
        p, _, mis = o[3]
        # mis = RMS / |b|: an edge's squared residual sum is n (mis b)^2; less the step's
        # predicted decrease
        sq = (mis * p[:, 1]) ** 2 * E.n
        sums.append(float(sq[both].sum()) - o[5] if both.any() else np.inf)
    best = int(np.argmin(sums))
    kd, sg, table, fits, step, _, _, se = out[best]
    if sg + step > 0:
        # one step: the fits stay those at sg (they only place the second pass's pixels)
        sg = sg + step
        table = _table(sg, kd)
    info = {"psf_sigma_px": sg, "psf_kind": kd, "psf_kind_chosen_by": "tag edges",
            "psf_sigma_fitted_by": "tag edges", "psf_sigma_se_px": se,
            "psf_kind_misfit": {o[0]: v for o, v in zip(out, sums, strict=True)}}
    return (sg, kd), table, fits, info


# Gauss-Newton steps of the first kind's sigma at most (each refits the edges)
BLUR_STEPS = 4
# the first kind's sigma is stepped again (the edges refitted) after a step larger than this
# (px): a step leaves ~6% of itself (measured from 0.05-0.2 px off), so one below it leaves
# < 6e-4 px, a tenth of the second kind's own start offset (~0.005 px at the same
# variance, which its one step absorbs) and the kinds' misfits are compared near their best
FIRST_KIND_STEP_PX = 0.01


def _blur_step(E, table, fits):
    r'''(step, predicted decrease of the summed squared misfit, misfit sum, standard error
of sigma): a Gauss-Newton step of the one sigma of every edge fitted with its contrast free
(targets._tag_edge_kernels.blur_step: each edge's own parameters follow it); step 0 where
no edge tells'''
    p, done, mis = fits
    use = E.deep & done & np.isfinite(mis)
    if not use.any():
        return 0.0, 0.0, 0.0, float("nan")
    x0, F, dF, Fs = table
    H, G = blur_step(E.off, E.v, E.w, E.tau, E.s, E.cubic, E.j0, E.fy, p, x0, TABLE_STEP_PX, F,
                     dF, Fs, use)
    if not H > 0:
        return 0.0, 0.0, 0.0, float("nan")
    S = float(((mis[use] * p[use, 1]) ** 2 * E.n[use]).sum())
    dof = max(float(E.n[use].sum()) - 6 * int(use.sum()) - 1, 1.0)
    return G / H, G * G / H, S, float(np.sqrt(S / dof / H))


def _restart(fits):
    r'''(m,4) the curves of fits (p, done, mis) as the next fits' start, cubic term 0; NaN
rows (their own start, E.d) where a fit ran off (EDGE_CONTRAST_OFF: misfit inf): its curve
lies in the blur's tail, where no pixel tells the edge'''
    p, _, mis = fits
    return np.where(np.isinf(mis)[:, None], np.nan, p[:, 2:] * [1, 1, 1, 0])


def _fit_contrast_first(E, table, start=None, converged_px=CONVERGED_PX):
    r'''_fit_edges: first the edges whose band reaches the dark plateau (E.deep), then the
others with the contrast b given, the median of their tag's plateau edges (else of the
image's): a band that sees only the light side of an edge (bits of 2-3 px across, a tag
seen obliquely) cannot tell the contrast from the edge's position; start (m,4): the curves
the fits start from (None: E.d). (p (m,6), converged (m,), misfit (m,))'''
    deep = E.deep
    free = np.full(E.m, np.nan)
    p, done, mis = _fit_edges(E, table, free, start, skip=~deep, converged_px=converged_px)
    rest = np.flatnonzero(~deep)
    if not len(rest):
        return p, done, mis
    first = np.flatnonzero(deep & done)
    if not len(first):
        # no edge sees its plateau: fit them all free (poorly conditioned, judged by misfit)
        p2, d2, m2 = _fit_edges(E, table, free, start, skip=deep, converged_px=converged_px)
    else:
        bs = {}
        for j in first:
            bs.setdefault(int(E.tag[j]), []).append(p[j, 1])
        med = {t: float(median(np.array(b))) for t, b in bs.items()}
        ball = float(np.median(p[first, 1]))
        bfix = free.copy()
        bfix[rest] = [med.get(int(E.tag[j]), ball) for j in rest]
        p2, d2, m2 = _fit_edges(E, table, bfix, start, skip=deep, converged_px=converged_px)
    p[rest], done[rest], mis[rest] = p2[rest], d2[rest], m2[rest]
    return p, done, mis


def _noise_line(E, table, p, use):
    r'''(c0, c1, scale, lo, hi): the pixels' noise variance as a line in their value, E r^2
= c0 + c1 v, from the residuals of the fits p (m,6) of the edges in use (m,) (least squares
of r^2 on the fitted value, noise_moments), scale: the mean of r^2 over those pixels, lo, hi:
the least and largest fitted value (where the line was measured); None
where the line is no variance (c1 <= 0: no noise that grows with the signal, e.g. a
noise-free image's model errors; or not positive over the fitted values)

Why. A camera's pixel noise is shot noise and read noise: its variance grows with the
signal (the realistic profile: 20000 e- at 1.0, 12 e- read noise; the tags' black 0.1 has
~1/8 of the board's 0.9 variance). Least squares weighted by the inverse variance places an
edge with ~0.8 of the variance of the unweighted fit's (1/F-information over a blurred
edge's band, the fit's light level and contrast free).'''
    x0, F = table[0], table[1]
    n, s1, s2, r2, r2mu, lo, hi = noise_moments(E.off, E.v, E.tau, E.s, E.cubic, E.j0, E.fy,
                                               p, x0, TABLE_STEP_PX, F, use)
    det = n * s2 - s1 * s1
    if not (n > 2 and det > 0):
        return None
    c1 = (n * r2mu - s1 * r2) / det
    c0 = (r2 - c1 * s1) / n
    if not (c1 > 0 and c0 + c1 * lo > 0 and c0 + c1 * hi > 0):
        return None
    return c0, c1, r2 / n, lo, hi


def _weights(line, v):
    r'''The pixels' weights for values v: the inverse of their noise variance (_noise_line's
line), in units of its mean over the first pass's pixels (a pixel of average noise weighs 1:
the fits' misfits stay the noise of such a pixel); every pixel 1 where line is None. The
variance is the line's at the observed value (kept to the values it was measured on): a
pixel's noise moves its weight by ~its relative noise (1e-2), which biases every pixel's
level alike to first order (by -c1), the light level a takes it up.'''
    # every pixel 1 through the same kernel (1 / (1 + 0 v) is 1 exactly): a blurred image
    # without noise calls it too, and a warm-up of either compiles it
    c0, c1, scale, lo, hi = (1.0, 0.0, 1.0, -np.inf, np.inf) if line is None else line
    return pixel_weights(np.asarray(v, dtype=np.float64), float(c0), float(c1), float(scale),
                         float(lo), float(hi))


def _unbent(d, L, sigma, kind):
    r'''(m,4) the board edges' curves (d0..d3 in each edge's chord frame of length L (m,)
px) under the fitted curves d (m,4) of an image blurred by (sigma, kind)

Why. F is a straight edge's blurred profile. A pixel next to an edge bent by s''(t) (t px
along the chord) integrates the dark side over the kernel's spread along the edge too (the
pixel's square and the blur: variance V = sigma^2 + _KIND_VARIANCE[kind] along any
direction), where the edge has left its tangent by s'' Z_t^2 / 2: to first order in s''
the pixel reads F(x - V s'' / 2), and the fitted curve is the edge moved towards its centre
of curvature by V s'' / 2 (a blurred disc's half-level contour shrinks by V / 2R). With
s = d(tau), tau = 2 t / L - 1, s'' = 4 / L^2 (2 d2 + 6 d3 tau): d0 and d1 take
-2 V / L^2 (2 d2) and -2 V / L^2 (6 d3) (the shift's own bend is of second order in s'').
Applied with a line_reference only (the module docstring: alone it is partly cancelled by the
span's model error, which only a known line shape takes off).'''
    c = 2.0 * (sigma * sigma + _KIND_VARIANCE[kind]) / np.asarray(L, dtype=np.float64) ** 2
    out = np.array(d, dtype=np.float64, copy=True)
    out[:, 0] -= c * 2.0 * out[:, 2]
    out[:, 1] -= c * 6.0 * out[:, 3]
    return out


def _curve_s(d, tau):
    return d[0] + tau * (d[1] + tau * (d[2] + tau * d[3]))


def _curves_in_frames(Q, live, shapes):
    r'''(N,4,4): (d0, d1, d2, d3) of each edge's curve shapes[(i, k)] (points (M,2)) in
the frame of its chord in Q (N,4,2), d3 = 0 (zeros where shapes has none)'''
    out = np.zeros((len(Q), 4, 4))
    keys = [(i, k) for (i, k) in shapes if live[i]]
    if not keys:
        return out
    i, k = np.array(keys).T
    P0, P1 = Q[i, k], Q[i, (k + 1) % 4]
    e = P1 - P0
    L = np.hypot(e[:, 0], e[:, 1])
    e = e / L[:, None]
    n = np.stack((-e[:, 1], e[:, 0]), axis=-1)
    n = np.where(((Q[i].mean(1) - P0) * n).sum(-1)[:, None] < 0, -n, n)
    r = np.stack([shapes[key] for key in keys]) - P0[:, None, :]
    tau = 2.0 * (r * e[:, None, :]).sum(-1) / L[:, None] - 1.0
    V = np.stack((np.ones(tau.shape), tau, tau * tau), axis=-1)
    Vt = V.transpose(0, 2, 1)
    out[i, k, :3] = np.linalg.solve(Vt @ V, Vt @ (r * n[:, None, :]).sum(-1)[..., None])[..., 0]
    return out


def _fit_edges(E, table, bfix, start=None, skip=None, converged_px=CONVERGED_PX):
    r'''Levenberg-Marquardt of every edge's (a, b, d0..d3), each on its own (compiled:
targets._tag_edge_kernels.fit_edges), d3 = 0 unless the edge has its neighbours' pixels;
bfix (m,) the contrast of the edges whose b is given (NaN: fitted); start (m,4): the curves
to start from (None, or a row not finite: E.d); skip (m,): edges not fitted. (p (m,6),
converged (m,), misfit RMS / contrast (m,)); a fit whose free contrast ran beyond the image's
range E.rng by more than CONTRAST_NOISE_SIGMAS of its RMS residual is not converged, its
misfit inf (EDGE_CONTRAST_OFF)'''
    x0, F, dF = table[:3]
    d = E.d
    if start is not None:
        start = np.asarray(start, dtype=np.float64).reshape(E.m, 4)
        d = np.where(np.isfinite(start).all(-1)[:, None], start, d)
    skip = np.zeros(E.m, bool) if skip is None else skip
    bfix = np.asarray(bfix, dtype=np.float64)
    p, done, mis = fit_edges(E.off, E.v, E.w, E.tau, E.s, E.cubic, E.j0, E.fy,
                             np.ascontiguousarray(d), x0, TABLE_STEP_PX, F, dF, bfix, skip,
                             MAX_ITERATIONS, float(converged_px))
    # the contrast beyond what the image holds: the fit's RMS residual is mis |b|
    b = np.abs(p[:, 1])
    off = np.isnan(bfix) & np.isfinite(mis) & ~(b <= E.rng + CONTRAST_NOISE_SIGMAS * mis * b)
    if off.any():
        done[off] = False
        mis[off] = np.inf
    return p, done, mis


def _fit_pixels(img, geo, pieces, q, pixels, why_edge, why_corner):
    r'''(geo, (off, v, tau, s)): the pixels of the fits geo (refine_tag_edges' (i, k, L, e,
n, cubic, start, end, weak)) gathered from their pieces (fit index, edge (i, k), how taken,
reach px; targets._tag_edge_kernels.fit_pixels) out of tag_edge_pixels' pixels (ix, iy, t,
s, off), fit j's [off[j], off[j+1]), v their values in img; a weak edge's fit is dropped
(its reason in why_edge) where its pixels do not see the dark side beyond both its ends
(_sees_dark); an edge's end whose pixels see no dark side nearer it than the chord's
middle has its corner's reason in why_corner (N,4) (_sees_dark_near; None: not judged, a
pass before the last, whose corners only place the next pass's pixels)'''
    ix, iy, t, s, off = pixels
    fit, edge, mode, reach = zip(*pieces, strict=True)
    fit = np.array(fit, dtype=np.int64)
    edge = np.array(edge, dtype=np.int64).reshape(-1, 2)
    fit_off = np.zeros(len(geo) + 1, np.int64)
    np.cumsum(np.bincount(fit, minlength=len(geo)), out=fit_off[1:])
    gi = np.array([g[0] for g in geo])
    gk = np.array([g[1] for g in geo])
    out = fit_pixels(img, ix, iy, t, s, off, fit_off, 4 * edge[:, 0] + edge[:, 1],
                     np.array(mode, dtype=np.int64), np.array(reach, dtype=np.float64),
                     np.ascontiguousarray(q[gi, gk]), np.array([g[3] for g in geo]),
                     np.array([g[4] for g in geo]), np.array([g[2] for g in geo]),
                     np.array([g[6] for g in geo], dtype=np.float64).reshape(-1, 4))
    # dark (F,4): each fit's pixels on the dark side of its start curve (or on it), counted
    # beyond each end and in each half of the chord as fit_pixels gathers them
    fo, fv, ftau, fs, dark = out
    keep = np.ones(len(geo), bool)
    for j, (i, k, _, _, _, _, _, end, weak) in enumerate(geo):
        if weak:
            if not _sees_dark(dark[j]):
                why_edge[i, k] = _EDGE_STATUS[2]
                keep[j] = False
            continue
        for e in () if why_corner is None else (0, 1) if end == 2 else (end,):
            if not _sees_dark_near(dark[j], e):
                why_corner[i, (k + e) % 4] = NEAR_CORNER_LIGHT_ONLY
    if keep.all():
        return geo, (fo, fv, ftau, fs)
    counts = np.diff(fo)[keep]
    px = np.repeat(keep, np.diff(fo))
    fo = np.zeros(len(counts) + 1, np.int64)
    np.cumsum(counts, out=fo[1:])
    return [g for g, k in zip(geo, keep, strict=True) if k], (fo, fv[px], ftau[px], fs[px])


class _Edges:
    r'''The pixels of the fits geo (refine_tag_edges': (i, k, L, e, n, cubic, start, end,
weak)), gathered by _fit_pixels (off, v, tau, s), in the arrays of
targets._tag_edge_kernels.fit_edges (off, v, tau, s, cubic, j0, fy; d each edge's current
curve, cubic term 0), with n (m,) each edge's pixel count, tag (m,) its tag and deep (m,):
the edges whose band reaches the dark plateau (MIN_PLATEAU_PIXELS at least reach px inside
the curve)'''

    def __init__(self, geo, pixels, reach, line=None, rng=np.inf):
        m = self.m = len(geo)
        # the image's range (max - min): the most contrast an edge can have (_fit_edges)
        self.rng = float(rng)
        self.off, self.v, self.tau, self.s = pixels
        self.n = np.diff(self.off).astype(np.float64)
        self.w = _weights(line, self.v)
        n = np.abs(np.array([g[4] for g in geo], dtype=np.float64).reshape(m, 2))
        phi = np.arctan2(n.min(-1), n.max(-1))
        self.cubic = np.array([g[5] for g in geo], dtype=np.float64)
        fa = np.clip(phi / (np.pi / 4) * (TABLE_ANGLES - 1), 0.0, TABLE_ANGLES - 1.000001)
        self.j0 = fa.astype(np.int64)
        self.fy = fa - self.j0
        d = np.array([g[6] for g in geo], dtype=np.float64).reshape(m, 4)
        self.d = d * [1, 1, 1, 0]
        self.tag = np.array([g[0] for g in geo], dtype=np.int64)
        # about the start curves (cubic term kept, as the band was placed)
        self.deep = plateau_counts(self.off, self.tau, self.s, d, float(reach)) \
            >= MIN_PLATEAU_PIXELS
