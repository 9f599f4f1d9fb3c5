r'''The paper's ROAMS defects, and renderer faults for the mutation suite, as options

SYNOPSIS

    from renderers.legacy import FAULTS, LEGACY_DEFECTS, legacy_model, FaultyRenderer

    bad = legacy_model(model)                      # all four ROAMS defects
    bad = FAULTS["half_pixel"](model)              # one injected fault
    r = FaultyRenderer("raycast", fault="r1_sign") # any renderer, rendering the faulty model
    r = get_renderer("povray", legacy=True)        # warp renderers take legacy= / fault=

Every defect and fault is a function model -> defective model: rendering the
defective model exactly is the same image as a renderer with that bug
rendering the true model. The defects of "Camera Response Simulation for
Planetary Exploration" (ROAMS, section 4.3):

- round_centre: (Hc, Vc) rounded to the nearest half pixel (ROAMS cropped
  its oversized CAHV render at the rounded centre and never corrected it).
- rounded_aspect: the horizontal field of view comes from a rounded aspect
  ratio: Hs = Vs round(Hs/Vs, 2) (OpenGL's gluPerspective takes the vertical
  field of view and an aspect ratio; ROAMS rounded the ratio to 2 decimals).
- theta90: under CAHV, V' replaced by A x H' (theta = 90 deg; OpenGL has no
  skew). CAHVOR/CAHVORE keep theta (ROAMS's warp undid it).
- float32: every vector of the model rounded to float32 (ROAMS's camera code
  was single precision).

Faults for the mutation suite (each must be caught by the gate):

- half_pixel: the pixel-centre convention slipped by half a pixel
  (H -= A/2, V -= A/2: every projection moves by (-0.5, -0.5) px)
- swap_hv: H and V swapped
- r1_sign: the sign of R1 flipped (CAHVOR, CAHVORE)
- ignore_e: E ignored (CAHVORE)
- focal_scale: focal lengths Hs, Vs scaled by 1 + 1e-4
- shift_001: the image shifted by 0.01 px in x (H += 0.01 A)
- and the four defects above, each alone.

A fault that does not apply to a model's family (r1_sign on CAHV, ignore_e
on CAHVOR) raises FaultNotApplicableError.
'''

import dataclasses
import time

import numpy as np

from reference_models.errors import CamvalError

from .base import RendererNotApplicable, RenderResult, RenderSettings, get_renderer

HALF_PIXEL = 0.5
ASPECT_DECIMALS = 2
FOCAL_SCALE = 1e-4
SHIFT_PX = 0.01


class FaultNotApplicableError(RendererNotApplicable):
    '''A fault that means nothing for this camera model family (campaigns: not-applicable)'''


class UnknownFaultError(CamvalError):
    pass


def _round_half(x):
    return round(2.0 * x) / 2.0


def round_centre(model):
    ph = model.photogrammetric()
    return model.with_photogrammetric(
        dataclasses.replace(ph, Hc=_round_half(ph.Hc), Vc=_round_half(ph.Vc)))


def rounded_aspect(model):
    ph = model.photogrammetric()
    aspect = round(ph.Hs / ph.Vs, ASPECT_DECIMALS)
    return model.with_photogrammetric(dataclasses.replace(ph, Hs=ph.Vs * aspect))


def theta90(model):
    if model.family != "CAHV":
        return model
    return model.with_theta_90()


def float32(model):
    changes = {}
    for name in ("C", "A", "H", "V", "O", "R", "E"):
        v = getattr(model, name, None)
        if v is not None:
            changes[name] = np.asarray(v, dtype=np.float32).astype(np.float64)
    return model.replace(**changes)


def half_pixel(model):
    return model.replace(H=model.H - HALF_PIXEL * model.A, V=model.V - HALF_PIXEL * model.A)


def swap_hv(model):
    return model.replace(H=model.V.copy(), V=model.H.copy())


def r1_sign(model):
    if model.family == "CAHV":
        raise FaultNotApplicableError("fault 'r1_sign' needs a CAHVOR or CAHVORE model; got CAHV")
    R = model.R.copy()
    R[1] = -R[1]
    return model.replace(R=R)


def ignore_e(model):
    if model.family != "CAHVORE":
        raise FaultNotApplicableError(
            f"fault 'ignore_e' needs a CAHVORE model; got {model.family}")
    return model.replace(E=np.zeros(3))


def focal_scale(model):
    ph = model.photogrammetric()
    return model.with_photogrammetric(dataclasses.replace(
        ph, Hs=ph.Hs * (1.0 + FOCAL_SCALE), Vs=ph.Vs * (1.0 + FOCAL_SCALE)))


def shift_001(model):
    return model.replace(H=model.H + SHIFT_PX * model.A)


LEGACY_DEFECTS = {
    "round_centre": round_centre,
    "rounded_aspect": rounded_aspect,
    "theta90": theta90,
    "float32": float32,
}

FAULTS = {
    **LEGACY_DEFECTS,
    "half_pixel": half_pixel,
    "swap_hv": swap_hv,
    "r1_sign": r1_sign,
    "ignore_e": ignore_e,
    "focal_scale": focal_scale,
    "shift_001": shift_001,
}

# the parameter each fault moves, for gate messages and the mutation suite
FAULT_PARAMETERS = {
    "round_centre": "Hc, Vc",
    "rounded_aspect": "Hs",
    "theta90": "theta",
    "float32": "C, A, H, V (float32 rounding)",
    "half_pixel": "Hc, Vc",
    "swap_hv": "H, V",
    "r1_sign": "R1",
    "ignore_e": "E",
    "focal_scale": "Hs, Vs",
    "shift_001": "Hc",
}


def legacy_model(model, defects=None):
    r'''The model as ROAMS rendered it: `defects` (default all four) applied in order

SYNOPSIS

    bad = legacy_model(model)                                # all of LEGACY_DEFECTS
    bad = legacy_model(model, ["round_centre", "theta90"])
'''
    names = list(LEGACY_DEFECTS) if defects is None else list(defects)
    for name in names:
        if name not in LEGACY_DEFECTS:
            raise UnknownFaultError(f"unknown legacy defect {name!r}; "
                                    f"known: {', '.join(LEGACY_DEFECTS)}")
    # float32 last: ROAMS computed in single precision from the rounded numbers
    for name in sorted(names, key=lambda n: n == "float32"):
        model = LEGACY_DEFECTS[name](model)
    return model


def apply_fault(model, fault):
    if fault not in FAULTS:
        raise UnknownFaultError(f"unknown fault {fault!r}; known: {', '.join(FAULTS)}")
    return FAULTS[fault](model)


def apply_defects(model, legacy=None, fault=None):
    r'''(defective model, list of applied names) for renderer options legacy= and fault=

legacy: None/False (none), True (all four ROAMS defects) or a list of names;
fault: None or one name of FAULTS (or a list of names).
'''
    applied = []
    if legacy:
        names = None if legacy is True else ([legacy] if isinstance(legacy, str) else legacy)
        model = legacy_model(model, names)
        applied += list(LEGACY_DEFECTS) if names is None else list(names)
    if fault:
        for name in [fault] if isinstance(fault, str) else fault:
            model = apply_fault(model, name)
            applied.append(name)
    return model, applied


class FaultyRenderer:
    r'''A renderer with a fault injected: renders the defective model with `inner`

SYNOPSIS

    r = FaultyRenderer("raycast", fault="half_pixel")
    r = FaultyRenderer(get_renderer("osmesa"), fault=["round_centre", "theta90"])
    r = FaultyRenderer("raycast", legacy=True)      # the ROAMS defects

ARGUMENTS

- inner: a renderer, or the name of one (constructed with inner_options)
- fault: a FAULTS name or list of names (None: no fault)
- legacy: as for apply_defects
- inner_options: options for constructing `inner` by name

render() also accepts RenderSettings.options "fault", "legacy" and "inner"
(a renderer name; they override the constructor's), so a campaign selects a
fault with the renderer name "faulty" and options {"fault": "half_pixel"};
other options go to the inner renderer.
'''

    name = "faulty"

    def __init__(self, inner="raycast", fault=None, legacy=None, inner_options=None):
        if isinstance(inner, str):
            inner = get_renderer(inner, **(inner_options or {}))
        self.inner = inner
        self.fault = fault
        self.legacy = legacy
        self._inners = {}
        # fail early on unknown names
        for name in ([fault] if isinstance(fault, str) else (fault or [])):
            if name not in FAULTS:
                raise UnknownFaultError(f"unknown fault {name!r}; known: {', '.join(FAULTS)}")

    def version(self):
        return f"faulty({self.inner.name} {self.inner.version()})"

    def render(self, model, scene, Rt_cam_board, settings=None):
        settings = RenderSettings() if settings is None else settings
        opts = dict(settings.options)
        fault = opts.pop("fault", self.fault)
        legacy = opts.pop("legacy", self.legacy)
        renderer = self.inner
        inner_name = opts.pop("inner", None)
        if inner_name is not None and inner_name != self.inner.name:
            renderer = self._inners.get(inner_name)
            if renderer is None:
                renderer = self._inners[inner_name] = get_renderer(inner_name)
        bad, applied = apply_defects(model, legacy, fault)
        t0 = time.perf_counter()
        inner = renderer.render(bad, scene, Rt_cam_board,
                                dataclasses.replace(settings, options=opts))
        meta = dict(inner.metadata)
        meta.update(renderer=f"faulty:{renderer.name}", defects=applied,
                    fault_parameters={n: FAULT_PARAMETERS[n] for n in applied},
                    seconds=time.perf_counter() - t0)
        return RenderResult(image=inner.image, metadata=meta)
