r'''Render a calibration target through a catalogue camera, with a JSON sidecar

    camval render CAMERA --target dots|apriltag|chessboard --pose N -o FILE.png
    camval render CAMERA --target dots --poses DIR
    camval render CAMERA -o FILE.png --renderer command --command 'my-renderer --fast' \
        [--setup timeout=60 --setup persistent=true ...]

CAMERA is a catalogue slot id (1-22), an extra's name (e.g. MCAM_Z_LEFT-Z026)
or a camera-model file (.cahv/.cahvor/.cahvore, PDS3 label, .cameramodel).
The board is placed at pose N of the poses planned for the camera
(targets.poses.plan_poses, 6 poses, deterministic for --seed); --poses DIR
writes all 6 as DIR/pose0.png ... pose5.png.

Each image is a 16-bit greyscale PNG (value = round(albedo average * 65535)),
rendered with K x K supersampling per pixel (--spp K, default 16; adaptive
unless --no-adaptive). Beside it, FILE.json holds the truth: the camera model
(every vector, family, CAHVORE type and linearity, image size), the board pose
Rt_cam_board (4x3, mrcal convention, in the camera frame of the model), the
target (name, definition, 3D points and their ids), for each point its exact
projected image position and, for dot targets, the exact expected image
centroid of the dot (area centroid of the projected outline), and the
renderer's metadata (settings, version, seconds, samples). Points that do not
project are null.

Existing files are not overwritten without --force. A camera that cannot see
the target, or whose image cannot fit in this machine's memory
(renderers.memory), prints the reason and exits with status 2.
'''

from pathlib import Path

from . import command_renderer

NPOSES = 6


def add_arguments(parser):
    parser.add_argument("camera", metavar="CAMERA",
                        help="catalogue slot id, an extra's name, or a model file")
    parser.add_argument("--target", default="dots",
                        help="dots, apriltag, chessboard, or a target .toml (default dots)")
    parser.add_argument("--pose", type=int, default=0, metavar="N",
                        help="index of the planned pose (default 0)")
    parser.add_argument("--poses", metavar="DIR", default=None,
                        help=f"write all {NPOSES} planned poses into DIR (pose0.png, ...)")
    parser.add_argument("--renderer", default="raycast", help="renderer (default raycast)")
    command_renderer.add_arguments(parser)
    parser.add_argument("--spp", type=int, default=16, metavar="K",
                        help="K x K samples per pixel (default 16)")
    parser.add_argument("--no-adaptive", action="store_true",
                        help="supersample every pixel (same image, slower)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the pose planner")
    parser.add_argument("-o", "--output", metavar="FILE.png", default=None,
                        help="output image (the sidecar is FILE.json)")
    parser.add_argument("--force", action="store_true", help="overwrite existing files")


def _nullable(a):
    r'''A float array as nested lists with NaN -> None (JSON without NaN)'''
    import numpy as np
    a = np.asarray(a, dtype=np.float64)
    if a.ndim == 1:
        return [None if not np.isfinite(x) else float(x) for x in a]
    if a.ndim == 2:
        return [None if not np.all(np.isfinite(row)) else [float(x) for x in row] for row in a]
    return [_nullable(x) for x in a]


def model_fields(model):
    r'''The camera model as a JSON-able dict (vectors as lists, family, size)'''
    d = {"family": model.family, "C": model.C.tolist(), "A": model.A.tolist(),
         "H": model.H.tolist(), "V": model.V.tolist()}
    if model.family in ("CAHVOR", "CAHVORE"):
        d.update(O=model.O.tolist(), R=model.R.tolist())
    if model.family == "CAHVORE":
        d.update(E=model.E.tolist(), model_type=int(model.model_type),
                 linearity=float(model.linearity))
    d.update(width=int(model.width), height=int(model.height))
    return d


def sidecar(entry, spec, model, target, Rt_cam_board, pose_index, seed, metadata):
    r'''The JSON document written beside a rendered image'''
    from targets.centroids import expected_centroids, projected_points
    doc = {
        "schema": "camval.render/1",
        "camera": {"spec": str(spec), "key": entry.key, "id": entry.id, "name": entry.name,
                   "status": entry.status},
        "model": model_fields(model),
        "Rt_cam_board": Rt_cam_board.tolist(),
        "pose_index": pose_index,
        "seed": seed,
        "target": target.as_dict(),
        "points": target.points().tolist(),
        "point_ids": target.point_ids().tolist(),
        "projected": _nullable(projected_points(model, target, Rt_cam_board)),
    }
    if target.kind == "dots":
        doc["expected_centroids"] = _nullable(expected_centroids(model, target, Rt_cam_board))
    doc["render"] = metadata
    return doc


def _check_free(paths, force):
    from reference_models.errors import CamvalError
    existing = [str(p) for p in paths if p.exists()]
    if existing and not force:
        raise CamvalError(f"'{existing[0]}' exists; pass --force to overwrite")


def run(args):
    import json

    from reference_models.catalogue import load_catalogue
    from reference_models.errors import CamvalError
    from renderers.base import RenderSettings, get_renderer
    from renderers.memory import check_render_memory
    from renderers.png import save_png16
    from targets.boards import load_target
    from targets.poses import plan_poses

    if (args.output is None) == (args.poses is None):
        raise CamvalError("give either -o FILE.png (one pose) or --poses DIR (all poses)")
    if args.pose < 0:
        raise CamvalError(f"--pose must be >= 0; got {args.pose}")
    settings = RenderSettings(spp=args.spp, adaptive=not args.no_adaptive)
    entry = load_catalogue().get(args.camera)
    model = entry.model
    target = load_target(args.target)

    if args.poses is not None:
        outdir = Path(args.poses)
        if outdir.exists() and not outdir.is_dir():
            raise CamvalError(f"'{outdir}' exists and is not a directory")
        indices = list(range(NPOSES))
        outputs = [outdir / f"pose{i}.png" for i in indices]
    else:
        out = Path(args.output)
        if out.suffix.lower() != ".png":
            raise CamvalError(f"output '{out}' must be a .png file")
        if not out.parent.is_dir():
            raise CamvalError(f"the directory of '{out}' does not exist")
        indices = [args.pose]
        outputs = [out]
    _check_free([p for o in outputs for p in (o, o.with_suffix(".json"))], args.force)

    renderer = get_renderer(args.renderer, **command_renderer.renderer_options(args))
    check_render_memory(renderer, model, settings)
    poses = plan_poses(model, target, n=max(NPOSES, max(indices) + 1), seed=args.seed)
    if args.poses is not None:
        outdir.mkdir(parents=True, exist_ok=True)
    for i, out in zip(indices, outputs, strict=True):
        Rt = poses[i]
        result = renderer.render(model, target.pattern(), Rt, settings)
        save_png16(out, result.image)
        doc = sidecar(entry, args.camera, model, target, Rt, i, args.seed, result.metadata)
        out.with_suffix(".json").write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n")
        md = result.metadata
        extra = (f", {100 * md['adaptive_fraction']:.1f}% of pixels supersampled"
                 if "adaptive_fraction" in md else "")
        print(f"{out}: {entry.key} {model.family} {model.width}x{model.height}, "
              f"{target.name} pose {i}, {args.renderer} K={settings.spp}"
              f"{' adaptive' if settings.adaptive else ''}, {md.get('seconds', 0.0):.3f} s{extra}")
    return 0
