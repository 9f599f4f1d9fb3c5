#!/usr/bin/env python3
r'''An external renderer with one geometric fault, for testing camval's gate

    python examples/fault_renderer.py --fault NAME REQUEST.json   # one-shot
    python examples/fault_renderer.py --fault NAME                # persistent (stdin)
    python examples/fault_renderer.py --list                      # the faults

A separate program speaking camval's request protocol (renderers/protocol.py,
docs/README-renderers.md), as examples/external_renderer.py does: it reads the
camera model of each request (the JPL file camval wrote), applies one named
fault to it and renders the faulty camera with camval's exact ray caster. The
fault reaches camval only through the images, as a simulator's bug would:
camval's records compare the fits of those images with the truth and with the
fit of the exact observations of the true camera.

The fault is named by --fault or, without it, by the environment variable
CAMVAL_FAULT (a campaign's setup.env); "none" renders the true camera (the
clean control). In a campaign, label each fault so its records are distinct
(setup is not part of a record's name):

    [[renderer]]
    name = "command"
    label = "fault-r1_scale"
    spp = [16]
    setup = { command = ["python", "examples/fault_renderer.py", "--fault", "r1_scale"],
              persistent = true }

The faults (FAULTS; the sizes are the smallest ones camval's issue 14 asks
the gate to flag on real cameras):

  hc_shift      Hc + 0.01 px (H += 0.01 A: the image moves 0.01 px in x;
                renderers.legacy.shift_001)
  focal_scale   Hs, Vs x (1 + 1e-5)
  theta90       theta forced to 90 deg (V' := A x H'; OpenGL and mrcal have no skew)
  half_pixel    the pixel-centre convention slipped half a pixel in x and y
                (renderers.legacy.half_pixel)
  r1_scale      R1 x 0.99 (CAHVOR, CAHVORE)
  r2_scale      R2 x 0.99 (CAHVOR, CAHVORE)
  drop_e        E dropped (E := 0; CAHVORE; renderers.legacy.ignore_e)
  o_tilt        O tilted 0.01 deg away from A (CAHVOR, CAHVORE)
  round_centre  Hc, Vc rounded to the nearest half pixel (renderers.legacy.round_centre)
  none          no fault

A fault on a model family without its parameter (R2 on CAHV, E on CAHVOR) is
declined as not applicable (the record says why); a fault that leaves the
camera unchanged (theta90 on a camera whose theta is 90 deg) renders it as it is.
'''

import argparse
import os
import sys

import numpy as np

FAULT_ENV = "CAMVAL_FAULT"
FOCAL_SCALE = 1e-5
R_SCALE = 0.99
O_TILT_DEG = 0.01


class FaultNotApplicable(Exception):
    '''The fault means nothing for this model family'''


def _needs(model, families, fault):
    if model.family not in families:
        raise FaultNotApplicable(f"fault {fault!r} needs a {' or '.join(families)} model "
                                 f"(it changes a parameter {model.family} does not have)")


def hc_shift(model):
    from renderers.legacy import shift_001  # H += SHIFT_PX A, SHIFT_PX = 0.01 px
    return shift_001(model)


def focal_scale(model):
    import dataclasses
    ph = model.photogrammetric()
    return model.with_photogrammetric(dataclasses.replace(
        ph, Hs=ph.Hs * (1.0 + FOCAL_SCALE), Vs=ph.Vs * (1.0 + FOCAL_SCALE)))


def theta90(model):
    return model.with_theta_90()


def half_pixel(model):
    from renderers.legacy import half_pixel as fault
    return fault(model)


def _scale_R(model, i, fault):
    _needs(model, ("CAHVOR", "CAHVORE"), fault)
    R = np.array(model.R, dtype=np.float64)
    R[i] *= R_SCALE
    return model.replace(R=R)


def r1_scale(model):
    return _scale_R(model, 1, "r1_scale")


def r2_scale(model):
    return _scale_R(model, 2, "r2_scale")


def drop_e(model):
    from renderers.legacy import ignore_e
    _needs(model, ("CAHVORE",), "drop_e")
    return ignore_e(model)


def o_tilt(model):
    r'''O rotated by O_TILT_DEG about the axis perpendicular to A and O (away from A), or
about H' when O = A'''
    _needs(model, ("CAHVOR", "CAHVORE"), "o_tilt")
    O = np.array(model.O, dtype=np.float64)
    k = np.cross(model.A, O)
    if np.linalg.norm(k) < 1e-9:
        k = model.photogrammetric().Hp
    k = k / np.linalg.norm(k)
    t = np.radians(O_TILT_DEG)
    # Rodrigues: O cos t + (k x O) sin t + k (k.O)(1 - cos t)
    O2 = O * np.cos(t) + np.cross(k, O) * np.sin(t) + k * (k @ O) * (1.0 - np.cos(t))
    return model.replace(O=O2)


def round_centre(model):
    from renderers.legacy import round_centre as fault
    return fault(model)


def none(model):
    return model


FAULTS = {
    "hc_shift": hc_shift,
    "focal_scale": focal_scale,
    "theta90": theta90,
    "half_pixel": half_pixel,
    "r1_scale": r1_scale,
    "r2_scale": r2_scale,
    "drop_e": drop_e,
    "o_tilt": o_tilt,
    "round_centre": round_centre,
    "none": none,
}


def faulty_model(model, fault):
    r'''The camera as the faulty renderer renders it; raises FaultNotApplicable'''
    if fault not in FAULTS:
        raise KeyError(f"unknown fault {fault!r}; known: {', '.join(FAULTS)}")
    return FAULTS[fault](model)


def make_render(fault):
    def render(req):
        from renderers.protocol import NotApplicable
        from renderers.raycast import RaycastRenderer

        if req.mode != "image":
            raise NotApplicable(f"fault_renderer renders image requests only; got "
                                f"{req.mode!r}")
        try:
            model = faulty_model(req.model, fault)
        except FaultNotApplicable as e:
            raise NotApplicable(str(e)) from None
        return RaycastRenderer().render(model, req.pattern, req.Rt_cam_board,
                                        req.settings).image
    return render


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--fault", default=os.environ.get(FAULT_ENV))
    ap.add_argument("--list", action="store_true")
    ap.add_argument("request", nargs="?")
    args = ap.parse_args(argv)
    if args.list:
        print("\n".join(FAULTS))
        return 0
    if args.fault not in FAULTS:
        print(f"fault_renderer: fault {args.fault!r} is unknown (--fault or {FAULT_ENV}); "
              f"known: {', '.join(FAULTS)}", file=sys.stderr)
        return 2
    from renderers.protocol import serve
    return serve(make_render(args.fault), argv=["fault_renderer"] +
                 ([args.request] if args.request else []))


if __name__ == "__main__":
    sys.exit(main())
