r'''Corner accuracy of the AprilTag and chessboard detectors against the exact projections

SYNOPSIS

    uv run --frozen python benchmarks/bench_corners.py [--cameras 15,17,8] [--spp 16]
        [--families CAHVOR,CAHVORE] [--poses 6] [--coverage point|area]
        [--images /tmp/cornerbench]
        [--response realistic] [--psf-sigma PX] [--methods camval]
        [--out benchmarks/results]

For each camera (its catalogue model in its own family; --families: in each of those it
can be taken as, a family it cannot be skipped with the reason), target (apriltag,
chessboard) and planned pose, the ray-cast renderer draws the board with --spp x
--spp subsamples per pixel, or with --coverage area in the ray caster's exact
covered-area mode (options coverage = "area": edge pixels integrate the board's
edges exactly); images are kept as .npy in --images and reused. Each image
goes through every method:

- apriltag: pupil_apriltags' corners (refine=False); those polished by cv2.cornerSubPix
  (refine="subpix"); OpenCV's own AprilTag 36h11 detector with its sub-pixel corners
  (detect_aruco); camval's refined corners (targets.corners, refine=True)
- chessboard: cv2.findChessboardCornersSB with CALIB_CB_ACCURACY (+ the orientation by the
  mark, refine=False); cv2.findChessboardCorners (the sector-based search where it fails)
  polished by cv2.cornerSubPix (refine="subpix"); camval's refined corners (the same
  search, then targets.corners)

--response NAME passes every image through that profile of campaigns/response.toml
(renderers.response; seed = the image's index; "blur": the realistic profile's PSF alone)
before detection; --psf-sigma hands camval's
refiner a known blur (px; default: it estimates the blur from the image); --methods keeps
the methods whose name contains one of the comma-separated words.

The truth is targets.centroids.projected_points: the board's corner points projected
through the camera. "raw" is each method's corners against it; camval's rows also give
"fitted": the corners the calibrators fit, i.e. less the bias their bias step subtracts
once it has converged (harness.calibrators.bias.bias_step under the true model and pose,
fed the detection's corner_model, corner_blur_px and corner_spans as
harness.stages.observations_from feeds it: the window's curvature bias, a blurred
chessboard's lines' bias, a blurred AprilTag's tag-edge span and blur bias, tag_edges_bias;
calibrator_bias). A blurred AprilTag's raw corners carry the span bias the detector leaves
to the bias step (detect_apriltags' defer_span_bias), so on blurred images "fitted" is the
figure to compare. Prints the table method x camera (corner error RMS / max px, raw and
fitted, corners found, median seconds per image; the JSON records' error_* and
corrected_error_*), then the
detection time per image of each method and image size (median and max over the images:
the bars are 0.1 s on 1024x1024 and 0.5 s on 5120x3840, issue 16; loaded-machine figures,
the load average is recorded). The times are those a campaign's worker sees: numba's cached
kernels are preloaded first (harness.warmup.load_cached_kernels, as the fork server does;
its CPU time printed apart; --malloc worker, the default: malloc keeps freed memory as the
workers' does, harness.executors.worker_top_pad, recorded as "malloc"), and each camera's
first detection, which carries what the
process does once (imports, a pupil_apriltags detector), is kept apart ('CPU 1st',
first_cpu_seconds) and its image detected again for the median and max. Writes one JSON
document to --out/<UTC stamp>-corners.json (never overwriting). --save-q F.npz keeps
every method's corners per image; --compare-q F.npz (a file --save-q wrote, e.g. before a
change to a detector) prints, per method and camera, the corners lost and gained, the
largest corner move and the largest growth of a corner's error against it (a
corner-by-corner before/after on the same images).
'''

import argparse
import json
import platform
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

METHODS = {
    "apriltag": [("pupil_apriltags", False), ("pupil_apriltags+cornerSubPix", "subpix"),
                 ("cv2.aruco APRILTAG_36h11+SUBPIX", "aruco"), ("camval", True)],
    "chessboard": [("findChessboardCornersSB", False),
                   ("findChessboardCorners(SB)+cornerSubPix", "subpix"), ("camval", True)],
}
FAMILY_ORDER = ("CAHV", "CAHVOR", "CAHVORE")


def render_images(directory, camera, tname, spp, nposes, coverage="point", family=None):
    r'''family, target, [(image, truth (N,2), Rt_cam_board)], model: one camera and target,
rendered once into directory; the camera taken as `family` (None: the richest family its
campaign jobs allow; a family the camera cannot be taken as raises StageFailed)'''
    from harness.campaign import load_campaign
    from harness.jobs import expand_jobs
    from harness.stages import StageFailed, camera_stage, poses_stage, render_stage
    from harness.stages import cached_target as _target
    from targets.centroids import projected_points

    jobs = [j for j in expand_jobs(load_campaign(ROOT / "campaigns" / "quick.toml"))
            if j.camera == str(camera)]
    for other in ("paper.toml", "response-corners.toml", "corners-constructed.toml"):
        if not jobs:
            # a model file's camera by its file name (its key is its path)
            jobs = [j for j in expand_jobs(load_campaign(ROOT / "campaigns" / other))
                    if str(camera) in (j.camera, Path(j.camera).name)]
    if not jobs:
        raise StageFailed("camera", f"camera {camera}: in no campaign this bench reads")
    if family is not None:
        jobs = [j for j in jobs if j.family == family]
        if not jobs:
            raise StageFailed("camera", f"camera {camera}: no campaign job takes it as {family}")
    # the camera's own model: the richest family it can be taken as
    for k, job in enumerate(sorted(jobs, key=lambda j: -FAMILY_ORDER.index(j.family))):
        try:
            _, truth = camera_stage(job)
            break
        except StageFailed:
            if k == len(jobs) - 1:
                raise
    target = _target(tname)
    poses = poses_stage(truth, target, nposes, 0)
    out = []
    directory.mkdir(parents=True, exist_ok=True)
    tag = f"k{spp}" + ("" if coverage == "point" else f"{coverage}")
    name = f"cam{camera}".replace("/", "_") + ("" if family is None else f"-{family}")
    missing = [i for i in range(len(poses))
               if not (directory / f"{name}_{tname}_{tag}_{i}.npy").exists()]
    if missing:
        settings = dict(job.settings, spp=spp)
        if coverage != "point":
            settings["options"] = dict(settings.get("options") or {}, coverage=coverage)
        results, _, _ = render_stage(job.renderer, truth, target,
                                     [poses[i] for i in missing], settings)
        for i, r in zip(missing, results, strict=True):
            np.save(directory / f"{name}_{tname}_{tag}_{i}.npy", np.asarray(r.image))
    for i, Rt in enumerate(poses):
        img = np.load(directory / f"{name}_{tname}_{tag}_{i}.npy")
        out.append((img, projected_points(truth, target, Rt), Rt))
    return job.family, target, out, truth


def detect_aruco(image, target, refine=None, min_found=4):
    r'''OpenCV's own AprilTag detector (cv2.aruco.ArucoDetector, dictionary DICT_APRILTAG_36h11,
cornerRefinementMethod CORNER_REFINE_SUBPIX: the best of its NONE / SUBPIX / APRILTAG
refinements on camera 15's area renders, 0.69 / 0.22 / 0.66 px RMS) as a
targets.detection.Detection of the board's corners: each marker's 4 corners (clockwise from
the marker's top-left) reversed and rolled by 2 are the board's 4 points of that tag
(pupil_apriltags' order); OpenCV's pixel centres are at integers, as camval's'''
    import cv2

    from targets.detection import result, working_image
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    detector = cv2.aruco.ArucoDetector(
        cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11), params)
    corners, ids, _ = detector.detectMarkers(working_image(image)[1])
    index = {int(pid): k for k, pid in enumerate(target.point_ids())}
    q = np.full((target.Npoints, 2), np.nan)
    for c, tag in zip(corners, [] if ids is None else ids.ravel(), strict=True):
        if 4 * int(tag) in index:
            q[[index[4 * int(tag) + k] for k in range(4)]] = np.roll(
                np.asarray(c, dtype=np.float64).reshape(4, 2), 2, axis=0)[::-1]
    return result(target, q, "cv2.aruco", min_found=min_found, corner_model="cv2.aruco")


def calibrator_bias(det, model, target, Rt_cam_board):
    r'''(N,2) px: the bias the calibrators' bias step takes off a detection's corners once it
has converged: harness.calibrators.bias.bias_step under model (the truth) and the pose,
fed the detection's corner_model, corner_blur_px and corner_spans as
harness.stages.observations_from hands them on (0 where the corner model has none, e.g. a
tag-edge corner without a span record)'''
    from harness.calibrators.bias import bias_step
    p = np.asarray(target.points(), dtype=np.float64)
    model_ = None if det.corner_model is None else np.asarray(det.corner_model)[None]
    spans = getattr(det, "corner_spans", None)
    b, _ = bias_step(model, target, np.asarray(Rt_cam_board, dtype=np.float64)[None], p[None],
                     corner_model=model_,
                     corner_blur_px=np.array([float(getattr(det, "corner_blur_px", 0.0))]),
                     corner_spans=None if spans is None else np.asarray(spans)[None])
    return np.zeros((len(p), 2)) if b is None else b[0]


def timing_rows(rows):
    r'''[{target, method, shape "WxH", images, seconds_median, seconds_max, cpu_seconds_median,
cpu_seconds_max, first_cpu_seconds_max}]: the detection time per image of each method,
pooled over the cameras of one image size: the steady times (each camera's first image
timed again), and the largest first detection of a camera (a record's first_cpu_seconds:
what the process did once on top)'''
    groups = {}
    for r in rows:
        h, w = r["shape"][:2]
        g = groups.setdefault((r["target"], r["method"], f"{w}x{h}"), ([], [], []))
        g[0].extend(r["seconds"])
        g[1].extend(r["cpu_seconds"])
        g[2].append(r.get("first_cpu_seconds", np.nan))
    return [{"target": t, "method": m, "shape": shape, "images": len(v),
             "seconds_median": float(np.median(v)), "seconds_max": float(np.max(v)),
             "cpu_seconds_median": float(np.median(c)), "cpu_seconds_max": float(np.max(c)),
             "first_cpu_seconds_max": float(np.max(f))}
            for (t, m, shape), (v, c, f) in sorted(groups.items(), key=lambda kv: (
                kv[0][0], kv[0][1], int(kv[0][2].split("x")[0]) * int(kv[0][2].split("x")[1])))]


def _keep_freed_memory(mode, current, pixels):
    r'''This process's malloc as a campaign's local worker has it (mode "worker"): the top
pad of the largest image so far (harness.executors.keep_freed_memory, worker_top_pad), set
again when an image is larger -> what the detections run with: {"top_pad": bytes},
{"environment": the MALLOC_* variables set here, kept}, or {"glibc": "default"}'''
    from harness.executors import keep_freed_memory, malloc_environment, worker_top_pad
    env = malloc_environment()
    if env:
        return {"environment": env}
    pad = worker_top_pad(pixels)
    if mode != "worker" or pad is None or (current or {}).get("top_pad", 0) >= pad:
        return current if current is not None else {"glibc": "default"}
    got = keep_freed_memory(pad)
    return {"top_pad": got} if got else {"glibc": "default (no mallopt here)"}


def _load():
    import os
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return None


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cameras", default="15,17,8")
    ap.add_argument("--families", default=None,
                    help="comma-separated families (CAHVOR,CAHVORE) each camera is taken as, "
                    "where it can be (default: its own, the richest)")
    ap.add_argument("--targets", default="apriltag,chessboard")
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--poses", type=int, default=6)
    ap.add_argument("--coverage", choices=("point", "area"), default="point",
                    help="ray-cast coverage: point sampling (spp x spp) or exact covered area")
    ap.add_argument("--images", type=Path, default=Path("/tmp/cornerbench"))
    ap.add_argument("--response", default=None,
                    help="a profile of campaigns/response.toml applied to every image")
    ap.add_argument("--psf-sigma", type=float, default=None,
                    help="the blur (px) handed to camval's refiner (default: estimated)")
    ap.add_argument("--methods", default=None, help="comma-separated words: keep the methods "
                    "whose name contains one")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    ap.add_argument("--malloc", choices=("worker", "glibc"), default="worker",
                    help="worker: this process's malloc keeps freed memory as a campaign's "
                         "workers do (harness.executors.worker_top_pad of the largest image "
                         "so far); glibc: as glibc starts it (a MALLOC_* variable in the "
                         "environment is kept either way)")
    ap.add_argument("--save-q", type=Path, default=None,
                    help="write every method's corners per image to this .npz")
    ap.add_argument("--compare-q", type=Path, default=None,
                    help="a --save-q file: print each method's corner changes against it")
    args = ap.parse_args()
    saved = {}
    before = dict(np.load(args.compare_q)) if args.compare_q else None
    chain = None
    if args.response:
        import tomllib

        from renderers.response import ResponseChain
        doc = tomllib.loads((ROOT / "campaigns" / "response.toml").read_text())
        # "blur": the realistic profile's PSF alone (no noise: the corner models' own error)
        doc["response"].setdefault("blur", {"psf": doc["response"]["realistic"]["psf"]})
        chain = ResponseChain.from_config(doc["response"][args.response])

    from harness.records import git_commit
    from harness.stages import StageFailed
    from harness.warmup import load_cached_kernels
    from targets.detect import detect

    # what a campaign's worker has before its first job (harness.executors' fork server
    # preloads it): numba's cached kernels in memory; its CPU time is reported, not timed
    # into any detection
    c0 = time.process_time()
    preload = {"kernels": load_cached_kernels(), "cpu_seconds": time.process_time() - c0}
    print(f"preloaded {preload['kernels']} cached kernel signatures "
          f"({preload['cpu_seconds']:.3f} CPU s, harness.warmup.load_cached_kernels)")
    rows = []
    malloc = _keep_freed_memory(args.malloc, None, 0)
    families = [None] if args.families is None else args.families.split(",")
    for cam, fam, tname in [(c, f, t) for c in args.cameras.split(",") for f in families
                            for t in args.targets.split(",")]:
        try:
            family, target, images, camera_model = render_images(
                args.images, cam, tname, args.spp, args.poses, args.coverage, fam)
        except StageFailed as e:
            print(f"{cam:>3s} {fam or '':8s} {tname:10s} skipped: {e.reason}")
            continue
        if chain is not None:
            images = [(chain.apply(img, seed=i).image, truth, Rt)
                      for i, (img, truth, Rt) in enumerate(images)]
        malloc = _keep_freed_memory(args.malloc, malloc, images[0][0].size)
        for method, refine in METHODS[tname]:
            if args.methods and not any(w in method for w in args.methods.split(",")):
                continue
            errs, cerrs, secs, cpus, found, dropped, sig = [], [], [], [], 0, {}, []
            changes, first = [], None
            for n_img, (img, truth, Rt) in enumerate(images):
                opts = {}
                if refine is True and args.psf_sigma is not None:
                    opts["psf_sigma_px"] = args.psf_sigma
                detector = detect_aruco if refine == "aruco" else detect
                t0, c0 = time.perf_counter(), time.process_time()
                det = detector(img, target, refine=refine, min_found=4, **opts)
                secs.append(time.perf_counter() - t0)
                cpus.append(time.process_time() - c0)
                if n_img == 0:
                    # the group's first detection carries what a process does once
                    # (imports, pupil_apriltags' detector for a new decimation, kernels
                    # not preloaded): kept apart, the same image detected again is
                    # its steady time
                    first = {"seconds": secs.pop(), "cpu_seconds": cpus.pop()}
                    t0, c0 = time.perf_counter(), time.process_time()
                    detector(img, target, refine=refine, min_found=4, **opts)
                    secs.append(time.perf_counter() - t0)
                    cpus.append(time.process_time() - c0)
                e = np.linalg.norm(det.q - truth, axis=-1)
                errs.append(e[np.isfinite(e)])
                key = (f"{cam}/{tname}/{method}/{n_img}" if fam is None
                       else f"{cam}/{fam}/{tname}/{method}/{n_img}")
                saved[key] = det.q
                if before is not None and key in before:
                    _compare_q(before[key], det.q, truth, changes)
                # the corners the calibrators fit: less their bias step's bias
                b = calibrator_bias(det, camera_model, target, Rt)
                ec = np.linalg.norm(det.q - b - truth, axis=-1)
                cerrs.append(ec[np.isfinite(ec)])
                found += int(det.n_found)
                if "psf_sigma_px" in det.info:
                    sig.append(det.info["psf_sigma_px"])
                for k, v in det.info.get("corners_dropped", {}).items():
                    dropped[k] = dropped.get(k, 0) + v
            e = np.concatenate(errs)
            ec = np.concatenate(cerrs)
            row = {"fullname": f"{cam}/{family}/{tname}/{method}", "camera": cam,
                   "family": family, "target": tname, "method": method,
                   "spp": args.spp, "coverage": args.coverage, "images": len(images),
                   "response": args.response, "psf_sigma_given": args.psf_sigma,
                   "psf_sigma_px": [float(x) for x in sig],
                   "shape": list(images[0][0].shape),
                   "corners_expected": int(target.Npoints * len(images)),
                   "corners_found": found, "corners_dropped": dropped,
                   "error_rms_px": float(np.sqrt(np.mean(e ** 2))) if len(e) else None,
                   "error_max_px": float(e.max()) if len(e) else None,
                   "corrected_error_rms_px": float(np.sqrt(np.mean(ec ** 2)))
                   if len(ec) else None,
                   "corrected_error_max_px": float(ec.max()) if len(ec) else None,
                   "seconds_median": float(np.median(secs)),
                   "seconds": [float(x) for x in secs],
                   "cpu_seconds": [float(x) for x in cpus],
                   "first_seconds": float(first["seconds"]),
                   "first_cpu_seconds": float(first["cpu_seconds"])}
            rows.append(row)
            print(f"{cam:>3s} {family:8s} {tname:10s} {method:38s} "
                  f"raw rms {row['error_rms_px']:.5f} max {row['error_max_px']:.4f} px  "
                  + (f"fitted (bias off) rms {row['corrected_error_rms_px']:.5f} max "
                     f"{row['corrected_error_max_px']:.4f}  " if refine is True else "")
                  +
                  f"{found:4d}/{row['corners_expected']} found  "
                  f"{row['seconds_median']:.3f} s/image"
                  + (f"  blur {np.median(sig):.3f} px" if sig else "")
                  + (f"  dropped {dropped}" if dropped else ""), flush=True)
            if changes:
                c = np.array(changes)
                row["against_saved_q"] = {
                    "lost": int(c[:, 0].sum()), "gained": int(c[:, 1].sum()),
                    "max_move_px": float(c[:, 2].max()),
                    "max_error_growth_px": float(c[:, 3].max())}
                print(f"    against {args.compare_q.name}: {row['against_saved_q']}")
    timing = timing_rows(rows)
    print(f"\ndetection seconds per image, wall and CPU of this process (median / max over "
          f"the images, each camera's first image timed again; the 1024x1024 bar is 0.1 s, "
          f"the 5120x3840 one 0.5 s; load average {_load()}: under load the wall time is the "
          f"CPU time stretched); 'CPU 1st': the largest first detection of a camera, with "
          f"what the process does once (imports, a pupil_apriltags detector for a new "
          f"decimation; numba's cached kernels preloaded as a campaign worker has them); "
          f"malloc: {malloc}")
    print(f"{'target':10s} {'method':38s} {'image':>10s} {'images':>6s} {'wall med':>9s} "
          f"{'wall max':>9s} {'CPU med':>8s} {'CPU max':>8s} {'CPU 1st':>8s}")
    for t in timing:
        print(f"{t['target']:10s} {t['method']:38s} {t['shape']:>10s} {t['images']:6d} "
              f"{t['seconds_median']:9.3f} {t['seconds_max']:9.3f} "
              f"{t['cpu_seconds_median']:8.3f} {t['cpu_seconds_max']:8.3f} "
              f"{t['first_cpu_seconds_max']:8.3f}")
    doc = {"schema": 1, "date": datetime.now(UTC).isoformat(timespec="seconds"),
           "commit": git_commit()["commit"], "python": platform.python_version(),
           "machine": platform.machine(), "renderer": "raycast", "spp": args.spp,
           "coverage": args.coverage, "response": args.response,
           "truth": "targets.centroids.projected_points", "load_average": _load(),
           "families": args.families, "kernels_preloaded": preload, "malloc": malloc,
           "records": rows,
           "timing": timing}
    args.out.mkdir(parents=True, exist_ok=True)
    stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")
    path = args.out / f"{stamp}-corners.json"
    k = 1
    while path.exists():
        path = args.out / f"{stamp}-{k}-corners.json"
        k += 1
    path.write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n")
    print("wrote", path)
    if args.save_q:
        np.savez(args.save_q, **saved)
        print("wrote", args.save_q)


def _compare_q(q0, q1, truth, changes):
    r'''Append (corners lost, corners gained, largest move px, largest error growth px) of
one image's corners q1 against the saved q0 (same truth)'''
    f0, f1 = np.isfinite(q0[:, 0]), np.isfinite(q1[:, 0])
    both = f0 & f1
    move = np.linalg.norm(q1[both] - q0[both], axis=-1)
    grow = (np.linalg.norm(q1[both] - truth[both], axis=-1)
            - np.linalg.norm(q0[both] - truth[both], axis=-1))
    changes.append((int((f0 & ~f1).sum()), int((f1 & ~f0).sum()),
                    float(move.max()) if len(move) else 0.0,
                    float(grow.max()) if len(grow) else 0.0))


if __name__ == "__main__":
    main()
