r'''Calibrate a camera from the target images rendered into a directory

    camval calibrate DIR --calibrator jpl|mrcal|opencv|colmap --model CAHVOR

DIR holds what `camval render CAMERA --poses DIR` writes: poseN.png images
with poseN.json sidecars. From each sidecar the calibrator uses ONLY the
surveyed 3D geometry (the target name and the board pose Rt_cam_board, i.e.
where each target point was in the world); the camera model in the sidecar is
the truth and is used only to place the survey in the world frame
(Rt_ref_board = Rt_ref_cam o Rt_cam_board), to fix the CAHVORE type and
linearity, and to compare the result with. The target is detected in each
image with targets.detect.detect.

Models: jpl CAHV|CAHVOR|CAHVORE; mrcal CAHV|CAHVOR|CAHVORE|OPENCV8|SPLINED;
opencv OPENCV5|RATIONAL|FISHEYE; colmap OPENCV|FULL_OPENCV|OPENCV_FISHEYE.

Writes into OUT (default DIR/calibration-CALIBRATOR-MODEL): the fitted model
(fitted.cahv/.cahvor/.cahvore for JPL families, fitted.cameramodel for mrcal's
other lens models, fitted.json for OpenCV and COLMAP) and summary.json (status,
residual statistics per point, parameter errors and projection differences
against the truth, detections). Existing output is not overwritten without
--force. Exit status: 0 when the calibration is ok, 1 when it failed or is not
applicable (the summary says why), 2 on bad input.
'''

import re
from pathlib import Path


def add_arguments(parser):
    parser.add_argument("dir", metavar="DIR", help="directory of poseN.png + poseN.json")
    parser.add_argument("--calibrator", default="jpl",
                        choices=("jpl", "mrcal", "opencv", "colmap"))
    parser.add_argument("--model", default=None,
                        help="model to fit (default: the truth's family for jpl/mrcal, "
                             "OPENCV5 for opencv, OPENCV for colmap)")
    parser.add_argument("--no-bias-correction", action="store_true",
                        help="skip the dot-centroid bias correction (second pass)")
    parser.add_argument("--known-poses", action="store_true",
                        help="mrcal: hold the boards at the surveyed poses")
    parser.add_argument("-o", "--output", default=None, metavar="OUT",
                        help="output directory")
    parser.add_argument("--force", action="store_true", help="overwrite existing output")


def _pose_files(d):
    from reference_models.errors import CamvalError
    if not d.is_dir():
        raise CamvalError(f"'{d}' is not a directory; expected the output of "
                          "`camval render CAMERA --poses DIR`")
    pairs = []
    for js in d.glob("pose*.json"):
        m = re.fullmatch(r"pose(\d+)\.json", js.name)
        png = js.with_suffix(".png")
        if m and png.exists():
            pairs.append((int(m.group(1)), png, js))
    if not pairs:
        raise CamvalError(f"'{d}' has no poseN.png + poseN.json pairs; expected the output "
                          "of `camval render CAMERA --poses DIR`")
    return [p[1:] for p in sorted(pairs)]


def _find_model_fields(x, depth=0):
    r'''The first dict (depth-first, "model"-like keys first) holding C, A, H, V, width, height'''
    if depth > 4:
        return None
    if isinstance(x, dict):
        if all(k in x for k in ("C", "A", "H", "V", "width", "height")):
            return x
        keys = sorted(x, key=lambda k: (0 if "model" in str(k) or k in ("truth", "camera")
                                        else 1))
        for k in keys:
            found = _find_model_fields(x[k], depth + 1)
            if found is not None:
                return found
    return None


def _model_from_sidecar(side, path):
    from reference_models.catalogue import model_from_fields
    from reference_models.errors import CamvalError
    from reference_models.jpl_files import parse_model_text
    fields = _find_model_fields(side)
    if fields is not None:
        return model_from_fields(fields, where=f"'{path}'")
    for key in ("model", "camera_model", "model_text", "truth", "camera"):
        v = side.get(key)
        if isinstance(v, dict):
            v = v.get("text")
        if isinstance(v, str) and ("C =" in v or "C=" in v):
            return parse_model_text(v, path=str(path))
    raise CamvalError(f"'{path}': no camera model found; expected a 'model' entry with "
                      "C, A, H, V, width, height (as `camval render` writes)")


def _target_from_sidecar(side, path):
    from reference_models.errors import CamvalError
    from targets.boards import load_target, target_from_dict
    t = side.get("target")
    if isinstance(t, str):
        return load_target(t)
    if isinstance(t, dict):
        if "spec" in t and isinstance(t["spec"], dict):
            return target_from_dict(t["spec"], source=str(path))
        if "name" in t:
            return load_target(t["name"])
    raise CamvalError(f"'{path}': no target found; expected 'target' (a name or a dict)")


def _Rt_from_sidecar(side, path):
    import numpy as np

    from reference_models.errors import CamvalError
    Rt = np.asarray(side.get("Rt_cam_board"), dtype=np.float64)
    if Rt.shape != (4, 3) or not np.all(np.isfinite(Rt)):
        raise CamvalError(f"'{path}': Rt_cam_board must be a finite 4x3 array; got "
                          f"shape {Rt.shape}")
    return Rt


def _load_image(path):
    import numpy as np
    try:
        from renderers.png import load_png
        return load_png(path)
    except ImportError:
        import cv2
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED | cv2.IMREAD_ANYDEPTH)
        if img is None:
            from reference_models.errors import CamvalError
            raise CamvalError(f"'{path}': cannot read the image") from None
        if img.ndim == 3:
            img = img[..., 0]
        return img.astype(np.float32) / float(np.iinfo(img.dtype).max)


DEFAULT_MODEL = {"opencv": "OPENCV5", "colmap": "OPENCV"}


def run(args):
    import json

    from harness.calibrators import calibrate, calibrator_module, models_of
    from harness.calibrators.base import jsonable
    from harness.compare import compare
    from harness.stages import observations_from
    from reference_models.errors import CamvalError
    from targets.detect import detect

    d = Path(args.dir)
    pairs = _pose_files(d)
    sides = [(json.loads(js.read_text()), js) for _, js in pairs]
    truth = _model_from_sidecar(*sides[0])
    target = _target_from_sidecar(*sides[0])
    model_name = args.model or DEFAULT_MODEL.get(args.calibrator, truth.family)
    canonical = getattr(calibrator_module(args.calibrator), "canonical_model", str.upper)
    if canonical(model_name) not in models_of(args.calibrator):
        raise CamvalError(f"calibrator {args.calibrator} cannot fit {model_name!r}; it fits "
                          f"{', '.join(models_of(args.calibrator))}")
    out = Path(args.output) if args.output else d / f"calibration-{args.calibrator}-{model_name}"
    if out.exists() and any(out.iterdir()) and not args.force:
        raise CamvalError(f"'{out}' exists and is not empty; use --force to overwrite")

    Rts, dets, detections = [], [], []
    for (png, _), (side, js) in zip(pairs, sides, strict=True):
        Rts.append(_Rt_from_sidecar(side, js))
        det = detect(_load_image(png), target)
        detections.append({"image": png.name, "status": det.status, "reason": det.reason,
                           "n_found": int(det.n_found), "n_expected": int(det.n_expected),
                           "corner_models": _corner_model_counts(det)})
        dets.append(det)
    # the campaign's observations: the survey in the world frame and each corner's model,
    # which decides the bias step's correction (issue 16: the window model's corner_bias
    # applies to window corners only, not to blurred tags' edge corners)
    obs = observations_from(truth, target, Rts, dets)
    options = {"bias_correction": not args.no_bias_correction}
    if args.known_poses:
        options["known_poses"] = True
    result = calibrate(args.calibrator, obs, target, model_name, truth=truth, **options)

    out.mkdir(parents=True, exist_ok=True)
    written = _write_model(result, out, args.force)
    summary = compare(result, truth)
    summary.update({"dir": str(d), "images": [p.name for p, _ in pairs],
                    "target": target.name, "truth_family": truth.family,
                    "detections": detections, "options": options, "fitted_model": written,
                    "iterations": result.iterations, "seconds": result.seconds,
                    "library": result.library, "library_version": result.library_version,
                    "info": {k: v for k, v in result.info.items() if k != "cameramodel"}})
    (out / "summary.json").write_text(json.dumps(jsonable(summary), indent=2,
                                                 allow_nan=False) + "\n")
    _print(summary, out)
    return 0 if result.ok else 1


def _corner_model_counts(det):
    r'''{corner model: number of found points} of a Detection; {} when it records none (dots)'''
    import numpy as np
    if det.corner_model is None:
        return {}
    names, counts = np.unique(det.corner_model[det.found], return_counts=True)
    return {str(k): int(n) for k, n in zip(names, counts, strict=True)}


def _write_model(result, out, force):
    import json

    from harness.calibrators.base import jsonable
    if not result.ok:
        return None
    m = result.model
    fam = getattr(m, "family", "")
    from reference_models.cahvore import FAMILIES
    if fam in FAMILIES:
        from reference_models.jpl_files import write_model
        path = out / f"fitted.{fam.lower()}"
        write_model(m, path, overwrite=force,
                    note=f"fitted by camval calibrate ({result.calibrator})")
        return path.name
    cm = result.info.get("cameramodel")
    if cm is not None:
        path = out / "fitted.cameramodel"
        if path.exists() and force:
            path.unlink()
        cm.write(str(path))
        return path.name
    path = out / "fitted.json"
    d = {"family": fam, "fx": m.fx, "fy": m.fy, "cx": m.cx, "cy": m.cy,
         "pixel_convention": "centre of the top-left pixel at (0,0)",
         "coefficients": getattr(m, "dist", getattr(m, "params", None))}
    path.write_text(json.dumps(jsonable(d), indent=2, allow_nan=False) + "\n")
    return path.name


def _print(s, out):
    res = s.get("residuals") or {}
    line = f"{s['calibrator']} {s['model_name']}: {s['status']}"
    if s.get("reason"):
        line += f" ({s['reason']})"
    print(line)
    if res.get("n"):
        print(f"  residuals per point: rms {res['rms']:.4f} px, max {res['max']:.4f} px, "
              f"min {res['min']:.4f} px over {res['n']} points")
    p = s.get("parameters") or {}
    for k in ("Hc", "Vc", "Hs", "Vs", "theta_deg", "C_mm"):
        v = p.get(k)
        print(f"  {k:10s} error {'not estimated' if v is None else f'{v:.6g}'}")
    for mode, d in (s.get("projection") or {}).items():
        print(f"  projection difference ({mode}): rms {d['rms']:.4f} px, max {d['max']:.4f} px")
    print(f"  written to {out}")
