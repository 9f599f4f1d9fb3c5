r'''Camera response: composable sensor and optics stages applied after rendering

SYNOPSIS

    from renderers.response import ResponseChain

    chain = ResponseChain.from_config({
        "seed":        7,
        "full_well_e": 20000,               # electrons at image value 1.0
        "vignetting":  {"model": "cos4"},
        "psf":         {"kind": "gaussian", "sigma_px": 0.8},
        "shot_noise":  {},
        "read_noise":  {"sigma_e": 12.0},
        "quantise":    {"bits": 12},
    })
    result = chain.apply(image, model=model)
    # image has shape (H,W), float in [0,1] (a RenderResult.image)
    # result.image has shape (H,W), float32 in [0,1]
    # result.stages: [{"stage": "vignetting", "seconds": ..., "params": {...}}, ...]

The rendered image is an irradiance scaled so that 1.0 fills a pixel's well
(`full_well_e` electrons). Every stage is off unless its key is in the
configuration (a plain dict, as read from a campaign TOML table); the keys of
a stage's table are its parameters. The stages always run in the physical
order of STAGE_ORDER, whatever the order of the keys:

    optics:   vignetting -> psf -> motion_blur
    exposure: global_gain (exposure / analogue gain on the signal)
    charge:   shot_noise -> dark_current -> hot_pixels / dead_pixels -> saturation
    readout:  read_noise -> encoding -> quantise

and the result is clipped to [0,1] (the analogue-to-digital range). The
conversion gain is implied: with quantise.bits = b, one DN is
full_well_e / (2^b - 1) electrons (e.g. 20000 e- and 12 bits: 4.88 e-/DN);
global_gain scales the signal before the charge stages (exposure or analogue
gain), so its noise is that of the amplified signal. The noise
stages draw from one numpy Generator seeded by `seed` (override per image with
apply(..., seed=)); the hot/dead pixel positions come from their own
`pattern_seed`, so they stay fixed from image to image like a real sensor's.

Each stage's docstring states its model; tests/test_response.py checks each
against its expected statistics. An unknown stage or parameter is a
ResponseConfigError naming the choices.
'''

import math
import time
from dataclasses import dataclass, field

import numpy as np

from reference_models.errors import CamvalError


class ResponseConfigError(CamvalError):
    '''A camera-response configuration with an unknown or invalid entry.'''


@dataclass(frozen=True, eq=False)
class ResponseResult:
    image: np.ndarray   # (H,W) float32 in [0,1]
    stages: list = field(default_factory=list)  # [{"stage", "seconds", "params"}]

    def cost(self):
        return float(sum(s["seconds"] for s in self.stages))


# ---------------------------------------------------------------------------
# helpers
def _number(stage, name, value, lo=None, hi=None, integer=False):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ResponseConfigError(f"{stage}.{name} must be a number; got {value!r}")
    if integer and not float(value).is_integer():
        raise ResponseConfigError(f"{stage}.{name} must be an integer; got {value!r}")
    if (not math.isfinite(value) or (lo is not None and value < lo)
            or (hi is not None and value > hi)):
        rng = f"[{lo if lo is not None else '-inf'}, {hi if hi is not None else 'inf'}]"
        raise ResponseConfigError(f"{stage}.{name} = {value!r} is outside {rng}")
    return int(value) if integer else float(value)


def _import_convolution():
    r'''Import scipy.signal and scipy.ndimage when a convolution stage is configured
(seconds under load), so that the stage's recorded seconds measure the
convolution, not the import'''
    import scipy.ndimage  # noqa: F401
    import scipy.signal  # noqa: F401


def _convolve_same(image, kernel):
    r'''Zero-padded 2-D convolution: light falling off the sensor is lost, none is made up'''
    from scipy.signal import fftconvolve
    return fftconvolve(image, kernel, mode="same")


def _pixel_gaussian_1d(sigma):
    r'''A Gaussian of std sigma integrated over unit pixels, truncated at 5 sigma'''
    from scipy.special import ndtr
    n = max(1, int(math.ceil(5.0 * sigma + 0.5)))
    x = np.arange(-n, n + 1, dtype=np.float64)
    k = ndtr((x + 0.5) / sigma) - ndtr((x - 0.5) / sigma)
    return k / k.sum()


def _disc_kernel(radius, oversample=16):
    r'''Fraction of each pixel covered by a disc of the radius centred on a pixel centre'''
    n = int(math.ceil(radius + 0.5))
    sub = (np.arange(oversample) + 0.5) / oversample - 0.5
    x = np.arange(-n, n + 1, dtype=np.float64)
    xs = (x[:, None] + sub[None, :]).ravel()
    inside = (xs[:, None] ** 2 + xs[None, :] ** 2) <= radius * radius
    k = inside.reshape(2 * n + 1, oversample, 2 * n + 1, oversample).mean(axis=(1, 3))
    return k / k.sum()


def _segment_kernel(vx, vy, samples_per_px=64):
    r'''A uniform line segment from -v/2 to +v/2, splatted bilinearly onto pixels'''
    length = math.hypot(vx, vy)
    n = max(2, int(math.ceil(length * samples_per_px)) + 1)
    t = (np.arange(n) + 0.5) / n - 0.5
    xs, ys = t * vx, t * vy
    r = int(math.ceil(max(abs(vx), abs(vy)) / 2.0)) + 1
    k = np.zeros((2 * r + 1, 2 * r + 1))
    x0 = np.floor(xs).astype(int)
    y0 = np.floor(ys).astype(int)
    fx, fy = xs - x0, ys - y0
    for dy, wy in ((0, 1 - fy), (1, fy)):
        for dx, wx in ((0, 1 - fx), (1, fx)):
            np.add.at(k, (y0 + dy + r, x0 + dx + r), wy * wx)
    return k / k.sum()


# ---------------------------------------------------------------------------
# stages. Each takes (signal, ctx) where signal is float64 (H,W) in the stage's
# units (optics and exposure: fraction of full well; charge and readout:
# electrons) and returns the new signal.
class _Stage:
    name = None
    params = {}      # name -> default (None: required)

    def __init__(self, cfg):
        if not isinstance(cfg, dict):
            raise ResponseConfigError(
                f"response stage {self.name!r} needs a table of parameters; got {cfg!r}")
        unknown = sorted(set(cfg) - set(self.params))
        if unknown:
            raise ResponseConfigError(
                f"unknown parameter {unknown[0]!r} of response stage {self.name!r}; "
                f"known: {', '.join(sorted(self.params)) or '(none)'}")
        missing = [k for k, v in self.params.items() if v is None and k not in cfg]
        if missing:
            raise ResponseConfigError(f"response stage {self.name!r} needs {missing[0]!r}")
        self.cfg = {**self.params, **cfg}
        self.setup()

    def setup(self):
        pass

    def describe(self):
        return {k: v for k, v in self.cfg.items()}


class Vignetting(_Stage):
    r'''Vignetting: the signal times a falloff factor per pixel

model = "cos4": factor cos^4(alpha), alpha the angle between the pixel's ray
(model.unproject of the pixel centre) and the camera axis A; the natural
falloff of an ideal lens. Needs the camera model.
model = "profile": factor np.interp(r, radius_px, factor), r the distance of
the pixel centre from (Hc, Vc) (the image centre if no model is given), from a
measured radial profile.
'''
    name = "vignetting"
    params = {"model": "cos4", "radius_px": [], "factor": []}

    def setup(self):
        m = self.cfg["model"]
        if m not in ("cos4", "profile"):
            raise ResponseConfigError(
                f"vignetting.model = {m!r} is unknown; known: cos4, profile")
        if m == "profile":
            r = np.asarray(self.cfg["radius_px"], dtype=np.float64)
            f = np.asarray(self.cfg["factor"], dtype=np.float64)
            if r.ndim != 1 or r.shape != f.shape or r.size < 2 or np.any(np.diff(r) <= 0):
                raise ResponseConfigError(
                    "vignetting profile needs radius_px (increasing) and factor lists "
                    "of the same length >= 2")
            self._r, self._f = r, f

    def factor(self, shape, model):
        Hh, Ww = shape
        if model is not None and (model.width, model.height) != (Ww, Hh):
            raise ResponseConfigError(
                f"vignetting: the image is {Ww}x{Hh} but the camera model is "
                f"{model.width}x{model.height}")
        if self.cfg["model"] == "cos4":
            if model is None:
                raise ResponseConfigError("vignetting model 'cos4' needs the camera model "
                                          "(apply(image, model=...))")
            from reference_models.conventions import pixel_centres
            _, v = model.unproject(pixel_centres(Ww, Hh))
            c = np.clip(v @ model.A, 0.0, 1.0)
            return np.nan_to_num(c ** 4, nan=0.0)
        if model is not None:
            ph = model.photogrammetric()
            cx, cy = ph.Hc, ph.Vc
        else:
            cx, cy = (Ww - 1) / 2.0, (Hh - 1) / 2.0
        y, x = np.mgrid[0:Hh, 0:Ww].astype(np.float64)
        return np.interp(np.hypot(x - cx, y - cy), self._r, self._f)

    def __call__(self, s, ctx):
        return s * self.factor(s.shape, ctx["model"])


class PSF(_Stage):
    r'''Defocus / lens point-spread function: a normalised convolution

kind = "gaussian": a Gaussian of std sigma_px integrated over each pixel (the
kernel has variance sigma_px^2 + 1/12 px^2 per axis; applied to an area-sampled
render, whose pixels already integrate a box, a point's image has sigma_px^2 + 1/6).
kind = "disc": a uniform disc of radius radius_px (defocus of a circular
aperture), the kernel being each pixel's covered area.
The kernel sums to 1 and the image is zero-padded, so total light is kept
except what spreads past the sensor's edge.
'''
    name = "psf"
    params = {"kind": "gaussian", "sigma_px": 1.0, "radius_px": 1.5}

    def setup(self):
        k = self.cfg["kind"]
        if k == "gaussian":
            s = _number(self.name, "sigma_px", self.cfg["sigma_px"], lo=1e-3, hi=100)
            g = _pixel_gaussian_1d(s)
            self.kernel = np.outer(g, g)
            self.separable = g
        elif k == "disc":
            r = _number(self.name, "radius_px", self.cfg["radius_px"], lo=1e-3, hi=100)
            self.kernel = _disc_kernel(r)
        else:
            raise ResponseConfigError(f"psf.kind = {k!r} is unknown; known: gaussian, disc")
        _import_convolution()

    def describe(self):
        k = self.cfg["kind"]
        return {"kind": k, **({"sigma_px": self.cfg["sigma_px"]} if k == "gaussian"
                              else {"radius_px": self.cfg["radius_px"]})}

    def __call__(self, s, ctx):
        g = getattr(self, "separable", None)
        if g is not None and len(g) <= 64:
            # the Gaussian kernel is an outer product: two 1-D passes, a few times faster
            # than the 2-D FFT on a 1024x1024 image, the same up to rounding
            from scipy.ndimage import convolve1d
            s = convolve1d(np.asarray(s, dtype=np.float64), g, axis=0, mode="constant")
            return convolve1d(s, g, axis=1, mode="constant")
        return _convolve_same(s, self.kernel)


class MotionBlur(_Stage):
    r'''Motion blur: the image moves by velocity_px = (vx, vy) pixels during the exposure

The rendered image is the scene at mid-exposure; the result averages it over
displacements uniformly spread from -v/2 to +v/2 (a centred line-segment
kernel, so the centroid of a blob does not move; its variance along v grows by
|v|^2/12). Light is conserved except at the sensor's edge.
'''
    name = "motion_blur"
    params = {"velocity_px": None}

    def setup(self):
        v = self.cfg["velocity_px"]
        if not isinstance(v, (list, tuple)) or len(v) != 2:
            raise ResponseConfigError(f"motion_blur.velocity_px must be [vx, vy]; got {v!r}")
        vx = _number(self.name, "velocity_px[0]", v[0], lo=-500, hi=500)
        vy = _number(self.name, "velocity_px[1]", v[1], lo=-500, hi=500)
        self.kernel = _segment_kernel(vx, vy)
        _import_convolution()

    def __call__(self, s, ctx):
        return _convolve_same(s, self.kernel)


class GlobalGain(_Stage):
    r'''Global gain: the signal times `gain` (exposure time or analogue gain error)'''
    name = "global_gain"
    params = {"gain": None}

    def setup(self):
        self.g = _number(self.name, "gain", self.cfg["gain"], lo=0.0, hi=1e6)

    def __call__(self, s, ctx):
        return s * self.g


class DarkCurrent(_Stage):
    r'''Dark current: rate_e_per_s * exposure_s electrons per pixel, Poisson distributed

Adds mean D = rate * exposure electrons and variance D (its shot noise).
'''
    name = "dark_current"
    params = {"rate_e_per_s": None, "exposure_s": 1.0}

    def setup(self):
        r = _number(self.name, "rate_e_per_s", self.cfg["rate_e_per_s"], lo=0.0)
        t = _number(self.name, "exposure_s", self.cfg["exposure_s"], lo=0.0)
        self.dark = r * t

    def __call__(self, e, ctx):
        return e + ctx["rng"].poisson(self.dark, size=e.shape)


class ShotNoise(_Stage):
    r'''Photon shot noise: the electron count of each pixel is Poisson(mean = signal)

Variance equals the mean in electrons. It runs before dark current, which
draws the dark charge's own Poisson noise. Negative signals are treated as 0.
'''
    name = "shot_noise"
    params = {}

    def __call__(self, e, ctx):
        return ctx["rng"].poisson(np.clip(e, 0.0, None)).astype(np.float64)


class HotPixels(_Stage):
    r'''Permanent hot pixels: a fixed `fraction` of pixels gain `charge_e` extra electrons

Positions come from `pattern_seed`, not the noise seed, so they are the same in
every image of a sensor; their number is round(fraction * pixels).
'''
    name = "hot_pixels"
    params = {"fraction": None, "charge_e": None, "pattern_seed": 1}

    def setup(self):
        self.fraction = _number(self.name, "fraction", self.cfg["fraction"], lo=0.0, hi=1.0)
        self.charge = _number(self.name, "charge_e", self.cfg["charge_e"], lo=0.0)
        self.seed = _number(self.name, "pattern_seed", self.cfg["pattern_seed"], integer=True)

    def positions(self, shape, salt):
        n = int(round(self.fraction * shape[0] * shape[1]))
        rng = np.random.default_rng([self.seed, salt])
        return rng.choice(shape[0] * shape[1], size=n, replace=False)

    def __call__(self, e, ctx):
        out = e.copy()
        out.flat[self.positions(e.shape, 0)] += self.charge
        return out


class DeadPixels(HotPixels):
    r'''Dead pixels: a fixed `fraction` of pixels collect no charge (0 electrons)

Positions come from `pattern_seed` (a different stream from hot pixels').
'''
    name = "dead_pixels"
    params = {"fraction": None, "pattern_seed": 2}

    def setup(self):
        self.fraction = _number(self.name, "fraction", self.cfg["fraction"], lo=0.0, hi=1.0)
        self.seed = _number(self.name, "pattern_seed", self.cfg["pattern_seed"], integer=True)

    def __call__(self, e, ctx):
        out = e.copy()
        out.flat[self.positions(e.shape, 1)] = 0.0
        return out


def _bloom_columns(e, full_well):
    from numba import njit

    global _bloom_kernel
    if _bloom_kernel is None:
        @njit(cache=True)
        def kernel(e, fw):
            Hh, Ww = e.shape
            for ix in range(Ww):
                for iy in range(Hh):
                    excess = e[iy, ix] - fw
                    if excess <= 0.0:
                        continue
                    e[iy, ix] = fw
                    # spill half up, half down; each side fills its neighbours in
                    # turn, and what passes the column's end drains away
                    for direction in (-1, 1):
                        rest = 0.5 * excess
                        j = iy + direction
                        while rest > 0.0 and 0 <= j < Hh:
                            room = fw - e[j, ix]
                            if room > 0.0:
                                take = min(room, rest)
                                e[j, ix] += take
                                rest -= take
                            j += direction
            return e
        _bloom_kernel = kernel
    return _bloom_kernel(e, full_well)


_bloom_kernel = None


class Saturation(_Stage):
    r'''Saturation and blooming: a pixel holds at most the full well

With blooming = false, charge above `full_well_e` is lost (clipped). With
blooming = true, the excess spills along its column (CCD blooming): half
upwards and half downwards, each half filling the nearest unsaturated pixels
in turn; charge that reaches the end of the column drains away. Total charge
is kept otherwise.
'''
    name = "saturation"
    params = {"blooming": False}

    def setup(self):
        if not isinstance(self.cfg["blooming"], bool):
            raise ResponseConfigError(
                f"saturation.blooming must be true or false; got {self.cfg['blooming']!r}")

    def __call__(self, e, ctx):
        fw = ctx["full_well_e"]
        if self.cfg["blooming"]:
            return _bloom_columns(np.ascontiguousarray(e, dtype=np.float64).copy(), fw)
        return np.minimum(e, fw)


class ReadNoise(_Stage):
    r'''Read noise: Gaussian, std sigma_e electrons, added at readout'''
    name = "read_noise"
    params = {"sigma_e": None}

    def setup(self):
        self.sigma = _number(self.name, "sigma_e", self.cfg["sigma_e"], lo=0.0)

    def __call__(self, e, ctx):
        return e + ctx["rng"].normal(0.0, self.sigma, size=e.shape)


class Quantise(_Stage):
    r'''Analogue-to-digital conversion to `bits` bits (8, 10, 12 or 16)

The signal (fraction of full well) is clipped to [0,1] and rounded to one of
the 2^bits levels k / (2^bits - 1); the rounding error is uniform with
variance 1/12 of a level squared.
'''
    name = "quantise"
    params = {"bits": None}

    def setup(self):
        b = self.cfg["bits"]
        if b not in (8, 10, 12, 14, 16) or isinstance(b, bool):
            raise ResponseConfigError(f"quantise.bits = {b!r}; known: 8, 10, 12, 14, 16")
        self.levels = (1 << b) - 1

    def __call__(self, s, ctx):
        return np.round(np.clip(s, 0.0, 1.0) * self.levels) / self.levels


class Encoding(_Stage):
    '''A non-linear encoding of the signal before conversion (a camera's tone curve, the
gamma of an 8-bit image file)

kind = "gamma": s -> s^(1/gamma) (gamma 2.2: the classic display encoding).
kind = "srgb": the sRGB transfer function (IEC 61966-2-1): 12.92 s up to s = 0.0031308,
1.055 s^(1/2.4) - 0.055 above.
The signal is clipped to [0,1] first (the converter's range). The image's values are then
no longer proportional to the light: a detector that weights pixels by their darkness
measures a blob's area centroid only up to this curve's bend.'''
    name = "encoding"
    params = {"kind": "srgb", "gamma": 2.2}

    def setup(self):
        k = self.cfg["kind"]
        if k not in ("gamma", "srgb"):
            raise ResponseConfigError(f"encoding.kind = {k!r} is unknown; known: gamma, srgb")
        self.gamma = _number(self.name, "gamma", self.cfg["gamma"], lo=0.1, hi=10.0)

    def describe(self):
        return {"kind": "gamma", "gamma": self.gamma} if self.cfg["kind"] == "gamma" else \
            {"kind": "srgb"}

    def __call__(self, s, ctx):
        s = np.clip(s, 0.0, 1.0)
        if self.cfg["kind"] == "gamma":
            return s ** (1.0 / self.gamma)
        return np.where(s <= 0.0031308, 12.92 * s, 1.055 * s ** (1.0 / 2.4) - 0.055)


# name -> (class, domain) in the physical order they run
STAGE_ORDER = (
    (Vignetting, "signal"),
    (PSF, "signal"),
    (MotionBlur, "signal"),
    (GlobalGain, "signal"),
    (ShotNoise, "electrons"),
    (DarkCurrent, "electrons"),
    (HotPixels, "electrons"),
    (DeadPixels, "electrons"),
    (Saturation, "electrons"),
    (ReadNoise, "electrons"),
    (Encoding, "signal"),
    (Quantise, "signal"),
)
STAGES = {cls.name: cls for cls, _ in STAGE_ORDER}
GLOBAL_KEYS = {"seed": 0, "full_well_e": 20000.0}


class ResponseChain:
    r'''The configured response stages, applied in physical order

SYNOPSIS

    chain = ResponseChain.from_config({"shot_noise": {}, "quantise": {"bits": 8}})
    chain.names()                 # ["shot_noise", "quantise"]
    r = chain.apply(image, model=model, seed=3)
    r.image, r.stages, r.cost()

An empty chain returns the image (as float32, clipped to [0,1]) unchanged.
'''

    def __init__(self, stages, seed=0, full_well_e=20000.0):
        self.stages = list(stages)
        self.seed = seed
        self.full_well_e = full_well_e

    @classmethod
    def from_config(cls, config):
        if config is None:
            config = {}
        if not isinstance(config, dict):
            raise ResponseConfigError(f"a response configuration is a table; got {config!r}")
        known = set(STAGES) | set(GLOBAL_KEYS)
        for key in config:
            if key not in known:
                raise ResponseConfigError(
                    f"unknown response stage {key!r}; known stages: "
                    f"{', '.join(c.name for c, _ in STAGE_ORDER)}; "
                    f"settings: {', '.join(GLOBAL_KEYS)}")
        seed = _number("response", "seed", config.get("seed", GLOBAL_KEYS["seed"]), integer=True)
        fw = _number("response", "full_well_e",
                     config.get("full_well_e", GLOBAL_KEYS["full_well_e"]), lo=1.0)
        stages = [c(config[c.name]) for c, _ in STAGE_ORDER if c.name in config]
        return cls(stages, seed=seed, full_well_e=fw)

    def names(self):
        return [s.name for s in self.stages]

    def as_dict(self):
        return {"seed": self.seed, "full_well_e": self.full_well_e,
                **{s.name: s.describe() for s in self.stages}}

    def apply(self, image, model=None, seed=None):
        r'''Apply the stages to an image

SYNOPSIS

    r = chain.apply(image, model=None, seed=None)
    # image (H,W) float in [0,1]; r.image (H,W) float32 in [0,1]

model: the camera model (needed by vignetting "cos4").
seed: the noise seed for this image (default: the chain's `seed`).
'''
        img = np.asarray(image, dtype=np.float64)
        if img.ndim != 2:
            raise ResponseConfigError(f"camera response needs a (H,W) image; got shape {img.shape}")
        domains = dict((c.name, d) for c, d in STAGE_ORDER)
        ctx = {"model": model, "full_well_e": self.full_well_e,
               "rng": np.random.default_rng(self.seed if seed is None else seed)}
        record = []
        s = img
        in_electrons = False
        for st in self.stages:
            t0 = time.perf_counter()
            want = domains[st.name] == "electrons"
            if want and not in_electrons:
                s = s * self.full_well_e
                in_electrons = True
            elif not want and in_electrons:
                s = s / self.full_well_e
                in_electrons = False
            s = st(s, ctx)
            record.append({"stage": st.name, "seconds": time.perf_counter() - t0,
                           "params": st.describe()})
        if in_electrons:
            s = s / self.full_well_e
        return ResponseResult(image=np.clip(s, 0.0, 1.0).astype(np.float32), stages=record)
