r'''The stereo range check: render terrain through a stereo pair, rectify, match, triangulate

SYNOPSIS

    from harness.studies.stereo import StereoSetup, run_stereo_check

    setup = StereoSetup.from_catalogue(21, 22, scale=0.25)   # Mars 2020 navcam pair
    noise = {"shot_noise": {}, "read_noise": {"sigma_e": 15}}
    result = run_stereo_check(setup, variants={"clean": {}, "noise": noise})
    result.variants["clean"].stats["band"]["median_abs_rel_error"]   # near 5 m
    result.variants["clean"].range     # (Hr,Wr) stereo range (m), NaN: no match
    result.true_range                  # (Hr,Wr) exact range along the same rectified rays

A stereo pair of catalogue models that share a frame (left and right slots)
looks at a generated terrain placed in that frame (targets.terrain.ground_pose:
the frames are JPL's, z DOWN; the ground lies `camera_height_m` below the left
camera and, when the left camera's axis points above the ground at
`look_range_m`, the frame is pitched down, as a mast would, until it meets it
there). The two images are rendered through the TRUE models by a terrain
renderer of the registry (renderers.base.get_terrain_renderer; by default
DEFAULT_TERRAIN_RENDERER, the exact terrain ray caster of
renderers/raycast_terrain.py, K x K supersampled), optionally passed through
camera-response stages (renderers/response.py), then:

1. rectified with mrcal (mrcal.rectified_system, LENSMODEL_LATLON, and
   mrcal.rectification_maps) from the models converted by
   reference_models.mrcal_convert.to_mrcal(model, orthogonalise=True), at 1.5
   rectified px per raw px (at 1, a wide lens's rectified grid is coarser than
   its raw one along the rows, and the two cameras' resamplings disagree);
2. matched with OpenCV StereoSGBM (8-bit images);
3. refined to subpixel disparities (refine_disparity: a plane of disparities
   fitted over a 9x9 window by Gauss-Newton, on both rectified images
   low-passed by a Gaussian of 0.8 raw px), which removes SGBM's pull towards
   whole pixels and its staircase on slanted ground;
4. triangulated with mrcal.stereo_range (range from the left camera along its
   rectified ray);
5. compared with the exact range along the same rectified rays, computed by
   tracing those rays against the terrain (no interpolation). "At 5 m" is the
   band of pixels whose TRUE range is within +-10% of look_range_m (4.5-5.5
   m); the error is (stereo - true) / true over the pixels of the band that
   have a stereo range, and the valid fraction says how many do.

What moved the hazcam pair (slots 12, 11, 1024x1024) from 1.42% to 0.79%
median |range error| at 5 m: SGBM's disparities were 0.05 px too large there
(ranges 0.7% short) on smooth ground as well as at rock edges, for every
block size in HH mode, and moved with its smoothness penalties (SGBM mode:
-0.27 px), i.e. the matcher's bias on ground whose disparity rises ~0.1-0.2
px per row; the rectification itself is exact (ranges from the true
disparities agree to 3e-13), and rendering at K = 4 instead of 2 changed
SGBM's result by less than 0.25%. A refinement on the raw rectified images
was no better than SGBM (median |error| 0.11 px) because the bilinear
resampling of the two raw images into the rectified grid differs near the
Nyquist frequency (the right image warped by the true disparities differed
from the left by 1.4x the rms horizontal gradient, at K = 2 and K = 4
alike); on images rendered directly in the rectified geometry the same
refinement reached 0.39%. benchmarks/bench_stages.py stereo --ablation measures
each piece: all of them 0.79%; rectified at 1 px per raw px 0.91%; without
the low-pass 1.95%; window radius 3 instead of 4 0.85%; SGBM alone at 1 px
per raw px 1.42% (the old pipeline). Hence the oversampled
grid and the low-pass before the refinement.

The rectification uses the models mrcal can represent (rectifiable()): theta
= 90 deg (mrcal's camera frame is orthonormal) and, for CAHVORE, E = 0
(mrcal.rectified_system accepts central projections only). The images come
from the true models, so the rectification is wrong by the skew: a pixel at
row offset dy from the centre is displaced along the row by about
dy * cot(theta) (for the slot-12 hazcam, theta = 90.022 deg: 0.19 px at 500 px
from the centre), and by the entrance-pupil shift (sub-millimetre for these
cameras: ~0.01 px at 5 m). Both cameras of a pair have nearly the same skew,
so most of it cancels in the disparity; render_model = "rectifiable" renders
with the rectification's own models instead, which isolates the error of
matching from that of the models.

A camera model can be scaled down (scale_model) for speed: H, V and the image
size scale, in the pixel convention of reference_models.conventions.
'''

import math
import time
from dataclasses import dataclass, field

import numpy as np

from reference_models.errors import CamvalError


class StereoError(CamvalError):
    '''A stereo pair or stereo setting that cannot be used.'''


# two models of one stereo head: near-parallel axes, a short baseline
MAX_AXIS_ANGLE_DEG = 15.0
MAX_BASELINE_M = 1.5
# the terrain renderer of the images (renderers.base registry name)
DEFAULT_TERRAIN_RENDERER = "raycast_terrain"


# ---------------------------------------------------------------------------
def scale_model(model, s, width=None, height=None):
    r'''The model of the same camera with its image scaled by s

SYNOPSIS

    small = scale_model(model, 0.25)   # 5120x3840 -> 1280x960

A pixel q of the original maps to s (q + 1/2) - 1/2 (pixel centres at
integers, reference_models.conventions): H' = s H + (s/2 - 1/2) A, likewise V.
The image size is round(s * size) unless given.
'''
    if not (s > 0 and math.isfinite(s)):
        raise StereoError(f"model scale must be > 0; got {s!r}")
    off = 0.5 * s - 0.5
    w = int(round(model.width * s)) if width is None else int(width)
    h = int(round(model.height * s)) if height is None else int(height)
    return model.replace(H=s * model.H + off * model.A, V=s * model.V + off * model.A,
                         width=w, height=h)


def rectifiable(model):
    r'''The version of a model that mrcal can rectify: theta = 90 deg and, for
CAHVORE, E = 0 (mrcal rectifies central projections only)'''
    m = model.with_theta_90()
    if m.family == "CAHVORE" and np.any(m.E != 0):
        m = m.replace(E=np.zeros(3))
    return m


def default_geometry(role):
    r'''(camera height above the ground in m, range where the axis should meet it) for a role'''
    r = (role or "").lower()
    if "haz" in r:
        return 0.52, 5.0      # MER/M2020 hazcams are ~0.5 m above the ground
    return 1.9, 5.0           # mast cameras (navcam, pancam) ~1.9-2 m


def terrain_pose_for(model, camera_height_m, look_range_m):
    r'''Rt_ref_terrain placing the ground under a z-down frame for this camera

The ground's z = 0 plane is camera_height_m below the camera centre C. If the
camera's axis A dips less than atan(height / look_range) below the horizontal,
the frame is pitched down by the difference (as a mast is), so the axis meets
the ground at look_range_m; a camera already looking further down is left as
it is. Returns (Rt_ref_terrain, pitch_deg).
'''
    from targets.terrain import ground_pose
    dip = math.degrees(math.asin(max(-1.0, min(1.0, model.A[2]))))   # z is down
    want = math.degrees(math.atan2(camera_height_m, look_range_m))
    pitch = max(0.0, want - dip)
    # the ground is camera_height_m below C measured in the pitched frame's level
    # frame: solve for the height under the frame origin so that C is that high
    Rt0 = ground_pose(0.0, pitch_deg=pitch)
    # height of C above the terrain plane z = 0 for a ground 0 m below the origin
    c_t = (model.C - Rt0[3]) @ Rt0[:3]
    h_origin = camera_height_m - c_t[2]
    return ground_pose(h_origin, pitch_deg=pitch), pitch


@dataclass
class StereoSetup:
    r'''Everything that defines one stereo check

left, right:  the true camera models (same frame)
names:        labels of the two cameras
terrain:      targets.terrain.Terrain
Rt_ref_terrain: (4,3) the terrain in the models' frame
scale:        the factor the models were scaled by (1: native)
'''
    left: object
    right: object
    names: tuple
    terrain: object
    Rt_ref_terrain: np.ndarray
    scale: float = 1.0
    camera_height_m: float = 0.0
    pitch_deg: float = 0.0
    look_range_m: float = 5.0
    notes: list = field(default_factory=list)

    @classmethod
    def from_catalogue(cls, left, right, scale=1.0, camera_height_m=None, look_range_m=None,
                       seed=0, catalogue=None, sun=None, max_range_m=20.0):
        from reference_models.catalogue import load_catalogue
        from targets.terrain import Sun, make_terrain
        cat = catalogue if catalogue is not None else load_catalogue()
        eL, eR = cat.get(left), cat.get(right)
        if eL.key == eR.key:
            raise StereoError(f"a stereo pair needs two cameras; got {eL.key} twice")
        frames = (getattr(eL, "frame", None), getattr(eR, "frame", None))
        if eL.rover != eR.rover or frames[0] != frames[1]:
            raise StereoError(
                f"cameras {eL.key} ({eL.rover}, frame {frames[0]}) and {eR.key} "
                f"({eR.rover}, frame {frames[1]}) do not share a frame; a stereo pair "
                "needs two models in one frame (e.g. 21 and 22, or 12 and 11)")
        mL0, mR0 = eL.model, eR.model
        axes = math.degrees(math.acos(max(-1.0, min(1.0, float(mL0.A @ mR0.A)))))
        base = float(np.linalg.norm(mL0.C - mR0.C))
        if axes > MAX_AXIS_ANGLE_DEG or base > MAX_BASELINE_M:
            raise StereoError(
                f"cameras {eL.key} and {eR.key} do not share a frame as a stereo pair: their "
                f"axes are {axes:.1f} deg apart and their centres {base:.2f} m (expected < "
                f"{MAX_AXIS_ANGLE_DEG:g} deg, < {MAX_BASELINE_M:g} m); their models come from "
                "different rovers or frames")
        h0, r0 = default_geometry(eL.role)
        h = camera_height_m if camera_height_m is not None else h0
        look = look_range_m if look_range_m is not None else r0
        mL, mR = eL.model, eR.model
        if scale != 1.0:
            mL, mR = scale_model(mL, scale), scale_model(mR, scale)
        pose, pitch = terrain_pose_for(mL, h, look)
        # the terrain reaches max_range_m ahead; its sides cover the widest view
        half_width = max_range_m * 1.25
        terrain = make_terrain(extent=(-1.0, max_range_m, -half_width, half_width),
                               cell=0.05, texel=0.01, seed=seed,
                               sun=sun if sun is not None else Sun(azimuth_deg=140,
                                                                   elevation_deg=40))
        notes = [f"scene: generated terrain seed {seed}, camera {h:.2f} m above the ground, "
                 f"frame pitched {pitch:.2f} deg down so the axis meets the ground at "
                 f"{look:g} m" if pitch > 0 else
                 f"scene: generated terrain seed {seed}, camera {h:.2f} m above the ground "
                 f"(the camera already looks down {math.degrees(math.asin(mL.A[2])):.1f} deg)"]
        if scale != 1.0:
            notes.append(f"models scaled by {scale:g} for speed: "
                         f"{eL.model.width}x{eL.model.height} -> {mL.width}x{mL.height}")
        return cls(left=mL, right=mR, names=(f"{eL.key} {eL.name}", f"{eR.key} {eR.name}"),
                   terrain=terrain, Rt_ref_terrain=pose, scale=scale, camera_height_m=h,
                   pitch_deg=pitch, look_range_m=look, notes=notes)


@dataclass
class VariantResult:
    name: str
    response: dict
    range: np.ndarray          # (Hr,Wr) stereo range, NaN where no match
    disparity: np.ndarray      # (Hr,Wr) px, NaN where no match
    stats: dict
    seconds: dict
    stats_sgbm: dict = field(default_factory=dict)   # the same, from SGBM's disparities


@dataclass
class StereoResult:
    setup: StereoSetup
    images: tuple              # rendered (H,W) float32 left, right (clean)
    rectified: tuple           # rectified clean images (Hr,Wr) float32
    true_range: np.ndarray     # (Hr,Wr) exact range along the rectified left rays
    elevation_true: np.ndarray  # (Hr,Wr) terrain height of the true points
    models_rectified: list
    variants: dict
    meta: dict

    def as_dict(self):
        return {"cameras": list(self.setup.names), "meta": self.meta,
                "notes": self.setup.notes,
                "variants": {k: {"response": v.response, "stats": v.stats,
                                 "stats_sgbm": v.stats_sgbm, "seconds": v.seconds}
                             for k, v in self.variants.items()}}


# ---------------------------------------------------------------------------
def _error_stats(rng, truth, look_range_m, band_rel=0.1):
    r'''Range-error statistics over the pixels with a true range'''
    has_truth = np.isfinite(truth)
    matched = has_truth & np.isfinite(rng)
    out = {"pixels_with_truth": int(has_truth.sum()),
           "valid_fraction": float(matched.sum() / max(has_truth.sum(), 1))}

    def block(mask):
        n = int(mask.sum())
        if n == 0:
            return {"n": 0}
        e = rng[mask] - truth[mask]
        rel = e / truth[mask]
        return {"n": n, "median_error_m": float(np.median(e)),
                "median_abs_error_m": float(np.median(np.abs(e))),
                "p95_abs_error_m": float(np.percentile(np.abs(e), 95)),
                "median_rel_error": float(np.median(rel)),
                "median_abs_rel_error": float(np.median(np.abs(rel))),
                "p95_abs_rel_error": float(np.percentile(np.abs(rel), 95))}

    out["all"] = block(matched)
    lo, hi = look_range_m * (1 - band_rel), look_range_m * (1 + band_rel)
    in_band = has_truth & (truth >= lo) & (truth <= hi)
    out["band"] = {"range_m": [lo, hi],
                   "valid_fraction": float((in_band & matched).sum() / max(in_band.sum(), 1)),
                   **block(in_band & matched)}
    return out


def _to_u8(img):
    return np.clip(np.round(np.asarray(img, np.float64) * 255.0), 0, 255).astype(np.uint8)


def rectify_setup(setup, az_fov_deg=None, el_fov_deg=None, pixels_per_deg=None, oversample=1.0):
    r'''mrcal rectified system and maps for the pair (theta = 90 versions of the models)

RETURNED VALUE: (models_mrcal, models_rectified, maps)
'''
    import mrcal

    from reference_models.mrcal_convert import to_mrcal
    models = [to_mrcal(rectifiable(setup.left), orthogonalise=True),
              to_mrcal(rectifiable(setup.right), orthogonalise=True)]
    from reference_models.catalogue import field_of_view_deg
    try:
        fov = field_of_view_deg(setup.left)
        hfov, vfov = float(fov[0]), float(fov[1])
    except Exception:   # noqa: BLE001 - any failure: fall back to the focal length
        ph = setup.left.photogrammetric()
        hfov = 2 * math.degrees(math.atan(setup.left.width / 2 / ph.Hs))
        vfov = 2 * math.degrees(math.atan(setup.left.height / 2 / ph.Vs))
    az = az_fov_deg if az_fov_deg is not None else min(hfov * 0.95, 150.0)
    el = el_fov_deg if el_fov_deg is not None else min(vfov * 0.95, 150.0)
    ph = setup.left.photogrammetric()
    ppd = pixels_per_deg if pixels_per_deg is not None else \
        oversample * ph.Hs * math.pi / 180.0
    models_rect = mrcal.rectified_system(models, az_fov_deg=az, el_fov_deg=el,
                                         pixels_per_deg_az=ppd, pixels_per_deg_el=ppd)
    if isinstance(models_rect, tuple) and not isinstance(models_rect[0], mrcal.cameramodel):
        models_rect = models_rect[0]
    maps = mrcal.rectification_maps(models, models_rect)
    return models, list(models_rect), maps


def true_rectified_range(setup, model_rect):
    r'''Exact range along every rectified left ray (traced against the terrain)

RETURNED VALUE: (range (Hr,Wr) NaN for sky, elevation (Hr,Wr) terrain-frame z of the point)
'''
    import mrcal

    from renderers.raycast_terrain import trace_rays
    W, Hh = model_rect.imagersize()
    q = np.ascontiguousarray(np.stack(np.meshgrid(np.arange(W, dtype=float),
                                                  np.arange(Hh, dtype=float)), axis=-1))
    v_cam = mrcal.unproject(q, *model_rect.intrinsics(), normalize=True)
    Rt_ref_cam = model_rect.Rt_ref_cam()
    v_ref = v_cam @ Rt_ref_cam[:3].T
    o_ref = np.broadcast_to(Rt_ref_cam[3], v_ref.shape)
    _, t, _ = trace_rays(setup.terrain, o_ref, v_ref, shadows=False,
                         Rt_ref_terrain=setup.Rt_ref_terrain)
    p_ref = o_ref + t[..., None] * v_ref
    R, T = setup.Rt_ref_terrain[:3], setup.Rt_ref_terrain[3]
    z_t = ((p_ref - T) @ R)[..., 2]
    return t, z_t, v_ref, o_ref


def sgbm(left_u8, right_u8, num_disparities, block_size=5):
    import cv2
    nd = int(16 * math.ceil(num_disparities / 16))
    m = cv2.StereoSGBM_create(minDisparity=0, numDisparities=nd, blockSize=block_size,
                              P1=8 * block_size * block_size, P2=32 * block_size * block_size,
                              disp12MaxDiff=1, uniquenessRatio=5, speckleWindowSize=100,
                              speckleRange=2, mode=cv2.STEREO_SGBM_MODE_HH)
    d16 = m.compute(left_u8, right_u8)
    d = d16.astype(np.float64) / 16.0
    d[d16 <= 0] = np.nan
    return d


# ---------------------------------------------------------------------------
# subpixel refinement: a slanted-window Lucas-Kanade step on the rectified pair
REFINE_OK, REFINE_NO_MATCH, REFINE_DIVERGED, REFINE_FLAT, REFINE_EDGE = 1, 0, 2, 3, 4

_refine_kernel = None


def _get_refine_kernel():
    global _refine_kernel
    if _refine_kernel is not None:
        return _refine_kernel
    from numba import njit, prange

    @njit(cache=True, inline="always")
    def cubic(row, W, x):
        # Keys cubic convolution (a = -1/2): value and d/dx of a row at x
        i = int(math.floor(x))
        t = x - i
        v = 0.0
        g = 0.0
        for k in range(-1, 3):
            j = min(max(i + k, 0), W - 1)
            u = t - k
            s = abs(u)
            if s < 1.0:
                w = (1.5 * s - 2.5) * s * s + 1.0
                dw = (4.5 * s - 5.0) * s
            elif s < 2.0:
                w = ((-0.5 * s + 2.5) * s - 4.0) * s + 2.0
                dw = (-1.5 * s + 5.0) * s - 4.0
            else:
                continue
            v += w * row[j]
            g += (dw if u >= 0.0 else -dw) * row[j]
        return v, g

    @njit(cache=True)
    def solve(A, b, n, x):
        # Gaussian elimination with partial pivoting on the leading n x n block;
        # False if singular (A and b are overwritten)
        scale = 0.0
        for i in range(n):
            scale = max(scale, abs(A[i, i]))
        for c in range(n):
            piv = c
            for r in range(c + 1, n):
                if abs(A[r, c]) > abs(A[piv, c]):
                    piv = r
            if not abs(A[piv, c]) > 1e-12 * scale:
                return False
            if piv != c:
                for k in range(n):
                    A[c, k], A[piv, k] = A[piv, k], A[c, k]
                b[c], b[piv] = b[piv], b[c]
            for r in range(c + 1, n):
                f = A[r, c] / A[c, c]
                for k in range(c, n):
                    A[r, k] -= f * A[c, k]
                b[r] -= f * b[c]
        for c in range(n - 1, -1, -1):
            s = b[c]
            for k in range(c + 1, n):
                s -= A[c, k] * x[k]
            x[c] = s / A[c, c]
        return True

    @njit(parallel=True, cache=True)
    def kernel(L, R, d0, radius, max_iter, tol, max_step, min_texture, nparams, out, status,
               gain):
        Hh, W = L.shape
        for y in prange(Hh):
            A = np.empty((5, 5))
            bb = np.empty(5)
            J = np.empty(5)
            p = np.empty(5)
            step = np.empty(5)
            for x in range(W):
                out[y, x] = np.nan
                if not np.isfinite(d0[y, x]):
                    status[y, x] = 0
                    continue
                if y < radius or y + radius >= Hh or x < radius or x + radius >= W:
                    status[y, x] = 4
                    continue
                # d, dd/drow, dd/dcol, gain, offset: L ~ gain R(x - d(.)) + offset
                p[0] = d0[y, x]
                p[1] = 0.0
                p[2] = 0.0
                p[3] = 1.0
                p[4] = 0.0
                st = 2
                for _ in range(max_iter):
                    A[:, :] = 0.0
                    bb[:] = 0.0
                    sgg = 0.0
                    for dy in range(-radius, radius + 1):
                        rowR = R[y + dy]
                        for dx in range(-radius, radius + 1):
                            xs = x + dx - (p[0] + p[1] * dy + p[2] * dx)
                            if xs < 0.0 or xs > W - 1.0:
                                continue
                            rv, rg = cubic(rowR, W, xs)
                            e = L[y + dy, x + dx] - (p[3] * rv + p[4])
                            J[0] = -p[3] * rg
                            J[1] = J[0] * dy
                            J[2] = J[0] * dx
                            J[3] = rv
                            J[4] = 1.0
                            sgg += rg * rg
                            for i in range(nparams):
                                bb[i] += J[i] * e
                                for k in range(i, nparams):
                                    A[i, k] += J[i] * J[k]
                    if sgg < min_texture * (2 * radius + 1) ** 2:
                        st = 3
                        break
                    for i in range(nparams):
                        for k in range(i):
                            A[i, k] = A[k, i]
                    # e = L - model; model(p + step) ~ model + J step: J step = e
                    if not solve(A, bb, nparams, step):
                        st = 3
                        break
                    for i in range(nparams):
                        p[i] += step[i]
                    if (abs(p[0] - d0[y, x]) > max_step or abs(p[1]) > 1.0
                            or abs(p[2]) > 1.0 or not p[3] > 0.1):
                        st = 2
                        break
                    if abs(step[0]) < tol:
                        st = 1
                        break
                else:
                    # out of steps: a fit still moving by < 10 tol (noise makes
                    # Gauss-Newton circle its optimum) is as good as converged
                    if abs(step[0]) < 10.0 * tol:
                        st = 1
                status[y, x] = st
                gain[y, x] = p[3]
                if st == 1:
                    out[y, x] = p[0]
        return out

    _refine_kernel = kernel
    return kernel


def refine_disparity(left, right, disparity, radius=4, photometric="auto", max_iter=20,
                     tol=1e-3, max_step=None, min_texture=1e-8):
    r'''Subpixel disparities by a slanted-window Lucas-Kanade fit on a rectified pair

SYNOPSIS

    d, status = refine_disparity(left, right, d_sgbm, radius=4)
    # left, right (Hr,Wr) float rectified images; d_sgbm (Hr,Wr) px, NaN: no match
    # d (Hr,Wr) px, NaN where the refinement failed; status (Hr,Wr) uint8:
    # REFINE_OK, REFINE_NO_MATCH, REFINE_DIVERGED, REFINE_FLAT (no texture), REFINE_EDGE

StereoSGBM's disparities come in 1/16 px steps from a parabola through three
matching costs of a fronto-parallel block, and are pulled towards whole
pixels and flattened by the smoothness penalties on a slanted surface. Both
are systematic: on the ground seen by the MER hazcams (disparity rising
0.1-0.2 px per row) they made the ranges near 5 m 0.5-0.7% short.

This function starts at SGBM's disparity d0 and fits, for each pixel, a plane
of disparities over the (2 radius + 1)^2 window around it,

    d(x + dx, y + dy) = d + a dy + b dx

by Gauss-Newton on sum (L(x+dx, y+dy) - R(x+dx - d(x+dx, y+dy), y+dy))^2, the
right image's rows interpolated by Keys' cubic convolution (rectified rows
correspond exactly, so the interpolation is 1-D). The window's slant is part
of the model, so texture concentrated in part of the window does not pull the
estimate towards that part's disparity. A pixel is dropped (NaN) when the fit
moves more than max_step px from d0 (default: 2 px), tilts by more than 1 px
per px, finds no texture, or its last step is still above 10 tol px after
max_iter steps (noise makes Gauss-Newton circle the optimum by ~tol).

photometric: False fits (d, a, b) only; True also a gain and an offset of the
right image (L ~ gain R + offset); "auto" (default) fits (d, a, b) and gives
the pixels it lost a second try with gain and offset. Measured on the MER
hazcams at 5 m (1024x1024, median |range error|): geometric only 0.78% on
clean images but 4.9% (27% valid) under cos^4 vignetting, which makes the
same point 5% brighter in one camera than in the other; gain and offset
everywhere 0.91% and 0.80%; "auto" 0.81% and 1.7%.
Images should be low-pass filtered first (run_stereo_check does: the
resampling of the raw images into the rectified grid is not the same in the
two cameras near the Nyquist frequency).
'''
    L = np.ascontiguousarray(left, dtype=np.float64)
    R = np.ascontiguousarray(right, dtype=np.float64)
    d0 = np.ascontiguousarray(disparity, dtype=np.float64)
    if L.ndim != 2 or L.shape != R.shape or L.shape != d0.shape:
        raise StereoError(f"refine_disparity needs three (H,W) arrays of one shape; got "
                          f"{L.shape}, {R.shape}, {d0.shape}")
    if isinstance(radius, bool) or not isinstance(radius, int) or radius < 1:
        raise StereoError(f"refinement window radius must be an integer >= 1; got {radius!r}")
    if photometric not in (True, False, "auto"):
        raise StereoError(f"photometric must be True, False or 'auto'; got {photometric!r}")
    kernel = _get_refine_kernel()
    out = np.empty_like(d0)
    status = np.empty(d0.shape, np.uint8)
    args = (int(radius), int(max_iter), float(tol), float(2.0 if max_step is None else max_step),
            float(min_texture))
    gain = np.ones_like(d0)
    kernel(L, R, d0, *args, 5 if photometric is True else 3, out, status, gain)
    if photometric == "auto":
        # the pixels the geometric fit lost get a second try with gain and offset
        again = (status == REFINE_DIVERGED) | (status == REFINE_FLAT)
        if again.any():
            out5 = np.empty_like(d0)
            status5 = np.empty(d0.shape, np.uint8)
            kernel(L, R, np.where(again, d0, np.nan), *args, 5, out5, status5, gain)
            out = np.where(again, out5, out)
            status = np.where(again, status5, status).astype(np.uint8)
    return out, status


def run_stereo_check(setup, variants=None, spp=2, render_model="true", block_size=5,
                     oversample=1.5, refine=True, refine_radius=4, prefilter_px=0.8,
                     photometric="auto", flat_field=False, seed=0, progress=None,
                     renderer=DEFAULT_TERRAIN_RENDERER, renderer_options=None):
    r'''Render, rectify, match, triangulate and compare, for each response variant

SYNOPSIS

    result = run_stereo_check(setup, variants={"clean": {}}, spp=2)
    result.variants["clean"].stats["band"]["median_abs_rel_error"]
    result.variants["clean"].stats_sgbm          # the same, from SGBM's disparities

variants: {name: response config (renderers.response.ResponseChain.from_config)};
          default {"clean": {}}
spp:      K, K x K rays per pixel for the rendered images
renderer: the terrain renderer's registry name (renderers.base.get_terrain_renderer:
          raycast_terrain, povray_terrain, osmesa_terrain, command or a plugin)
renderer_options: its constructor's arguments (e.g. the command renderer's setup:
          {"command": [...], "persistent": True})
oversample: rectified pixels per degree, relative to the left camera's focal
          length (Hs). 1.5 by default: at 1 the rectified grid is coarser than
          the raw one along the rows over much of a wide lens's field (1.1 raw
          px per rectified px near 5 m for the MER hazcams), and the resampling
          aliases differently in the two cameras
refine:   fit subpixel disparities with refine_disparity (radius refine_radius)
          starting at SGBM's; False keeps SGBM's 1/16 px disparities
prefilter_px: std (in raw pixels) of the Gaussian low-pass applied to both
          rectified images before the refinement (0: none)
photometric: refine_disparity's photometric ("auto", True: fit a gain and
          offset everywhere, False)
flat_field: divide each image by its vignetting stage's falloff (if the
          variant has one) before rectification, as radiometric correction
          would; the images are then no longer clipped to [0,1] where the
          falloff brightened them past it
block_size: StereoSGBM's block size (px)
render_model: "true" (the catalogue models; the rectification is then off by
          their skew and CAHVORE pupil shift) or "rectifiable" (render with the
          theta = 90, E = 0 models that the rectification uses)

Each variant's statistics (_error_stats) cover the pixels with a true range:
the valid fraction and median / 95th-percentile range errors over all of
them and in the band of true ranges within +-10% of setup.look_range_m.
'''
    import cv2
    import mrcal

    from renderers.base import RenderSettings, get_terrain_renderer
    from renderers.response import ResponseChain

    say = progress or (lambda s: None)
    if render_model not in ("true", "rectifiable"):
        raise StereoError(f"render_model {render_model!r}; known: true, rectifiable")
    if not (oversample > 0 and math.isfinite(oversample)):
        raise StereoError(f"oversample must be > 0; got {oversample!r}")
    if not (prefilter_px >= 0 and math.isfinite(prefilter_px)):
        raise StereoError(f"prefilter_px must be >= 0; got {prefilter_px!r}")
    variants = variants or {"clean": {}}
    chains = {k: ResponseChain.from_config(v) for k, v in variants.items()}
    tm = {}
    t0 = time.perf_counter()
    mL, mR = setup.left, setup.right
    if render_model == "rectifiable":
        mL, mR = rectifiable(mL), rectifiable(mR)
    say(f"rendering {mL.width}x{mL.height} x2, K={spp}")
    terrain_renderer = get_terrain_renderer(renderer, **(renderer_options or {}))
    settings = RenderSettings(spp=spp)
    rL = terrain_renderer.render_terrain(mL, setup.terrain, setup.Rt_ref_terrain, settings)
    rR = terrain_renderer.render_terrain(mR, setup.terrain, setup.Rt_ref_terrain, settings)
    tm["render"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    say("rectifying (mrcal)")
    models, models_rect, maps = rectify_setup(setup, oversample=oversample)
    tm["rectification_maps"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    true_range, elev_true, v_ref, o_ref = true_rectified_range(setup, models_rect[0])
    tm["true_range"] = time.perf_counter() - t0

    baseline = float(np.linalg.norm(models_rect[1].Rt_ref_cam()[3]
                                    - models_rect[0].Rt_ref_cam()[3]))
    # LATLON: fx is pixels per radian of azimuth
    px_per_rad = float(models_rect[0].intrinsics()[1][0])
    near = np.nanpercentile(true_range, 0.5) if np.isfinite(true_range).any() else 1.0
    # disparity (px) of the nearest points: the angle the baseline subtends there
    max_disp = px_per_rad * math.atan2(baseline, near) * 1.15 + 8
    # rectified px per raw px at the image centre: the prefilter's scale
    sigma_rect = prefilter_px * px_per_rad / setup.left.photogrammetric().Hs
    Wr, Hr = models_rect[0].imagersize()
    qrect0 = np.ascontiguousarray(np.stack(np.meshgrid(np.arange(Wr, dtype=float),
                                                       np.arange(Hr, dtype=float)), axis=-1))

    def to_range(d):
        # float disparities need qrect0: stereo_range's dense path casts them to uint16
        ok = np.isfinite(d) & (d > 0)
        rng = mrcal.stereo_range(np.where(ok, d, 1.0), models_rect, qrect0=qrect0)
        return np.where(ok & (rng > 0), rng, np.nan)

    rect_clean = tuple(cv2.remap(np.asarray(im, np.float32), mp[..., 0], mp[..., 1],
                                 cv2.INTER_LINEAR) for im, mp in zip((rL.image, rR.image), maps,
                                                                     strict=True))
    status_names = {REFINE_NO_MATCH: "no_sgbm_match", REFINE_OK: "ok",
                    REFINE_DIVERGED: "diverged", REFINE_FLAT: "no_texture",
                    REFINE_EDGE: "image_edge"}
    has_truth = np.isfinite(true_range)
    out = {}
    for k, (name, chain) in enumerate(chains.items()):
        t0 = time.perf_counter()
        say(f"variant {name}: response {chain.names() or 'none'}")
        iL = chain.apply(rL.image, model=mL, seed=seed + 2 * k).image
        iR = chain.apply(rR.image, model=mR, seed=seed + 2 * k + 1).image
        if flat_field:
            # radiometric correction with the known falloff, as ground processing does
            for st in chain.stages:
                if st.name == "vignetting":
                    iL = iL / np.maximum(st.factor(iL.shape, mL), 1e-3).astype(np.float32)
                    iR = iR / np.maximum(st.factor(iR.shape, mR), 1e-3).astype(np.float32)
        t_resp = time.perf_counter() - t0
        t0 = time.perf_counter()
        rect = [cv2.remap(im, mp[..., 0], mp[..., 1], cv2.INTER_LINEAR)
                for im, mp in zip((iL, iR), maps, strict=True)]
        d_sgbm = sgbm(_to_u8(rect[0]), _to_u8(rect[1]), max_disp, block_size=block_size)
        t_match = time.perf_counter() - t0
        t0 = time.perf_counter()
        if refine:
            if sigma_rect > 0:
                rect = [cv2.GaussianBlur(im, (0, 0), sigma_rect) for im in rect]
            d, status = refine_disparity(rect[0], rect[1], d_sgbm, radius=refine_radius,
                                         photometric=photometric)
        else:
            d, status = d_sgbm, None
        t_refine = time.perf_counter() - t0
        rng = to_range(d)
        stats = _error_stats(rng, true_range, setup.look_range_m)
        if status is not None:
            stats["refinement"] = {v: int(np.count_nonzero(status[has_truth] == c))
                                   for c, v in status_names.items()}
        stats_sgbm = _error_stats(to_range(d_sgbm), true_range, setup.look_range_m)
        out[name] = VariantResult(name=name, response=variants[name], range=rng, disparity=d,
                                  stats=stats, stats_sgbm=stats_sgbm,
                                  seconds={"response": t_resp, "rectify_match": t_match,
                                           "refine": t_refine})
    meta = {"render_model": render_model, "spp": spp, "scale": setup.scale,
            "image_size": [mL.width, mL.height],
            "rectified_size": [int(Wr), int(Hr)],
            "rectification": "mrcal LENSMODEL_LATLON from theta=90 models (to_mrcal "
                             "orthogonalise=True)",
            "matcher": ("OpenCV StereoSGBM, then refine_disparity (slanted-window "
                        f"Lucas-Kanade, radius {refine_radius}, Gaussian prefilter "
                        f"{prefilter_px:g} raw px)") if refine else "OpenCV StereoSGBM",
            "theta_deg": [setup.left.photogrammetric().theta_deg,
                          setup.right.photogrammetric().theta_deg],
            "baseline_m": baseline, "pixels_per_deg": px_per_rad * math.pi / 180.0,
            "oversample": oversample, "refine": bool(refine), "refine_radius": refine_radius,
            "prefilter_px": prefilter_px, "photometric": photometric,
            "flat_field": bool(flat_field),
            "num_disparities": int(16 * math.ceil(max_disp / 16)), "block_size": block_size,
            "camera_height_m": setup.camera_height_m, "pitch_deg": setup.pitch_deg,
            "look_range_m": setup.look_range_m, "seconds": tm,
            "terrain": setup.terrain.as_dict(), "renderer": rL.metadata.get("renderer"),
            "renderer_version": rL.metadata.get("version"),
            "mrcal": getattr(mrcal, "__version__", "?"), "opencv": cv2.__version__}
    return StereoResult(setup=setup, images=(rL.image, rR.image), rectified=rect_clean,
                        true_range=true_range, elevation_true=elev_true,
                        models_rectified=models_rect, variants=out, meta=meta)
