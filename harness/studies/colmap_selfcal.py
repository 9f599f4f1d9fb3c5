r'''COLMAP without a target: self-calibration from a rover's terrain image sequence

SYNOPSIS

    from harness.studies.colmap_selfcal import run_selfcal

    r = run_selfcal(camera=15, colmap_model="OPENCV", n_images=10, workdir="out/selfcal")
    r["selfcal"]["projection_rms_px"]      # target-free: COLMAP SfM intrinsics vs the truth
    r["target"]["projection_rms_px"]       # the same camera calibrated on the dot board

    uv run python -m harness.studies.colmap_selfcal --camera 15 -o out/selfcal

A rover drives over a generated terrain (targets.terrain) in n_images steps
of `step_m` metres, turning and tilting its mast a little between images; the
camera (a catalogue model, true and exact) sees the terrain through the exact
terrain ray caster (K x K supersampled, shadows on). COLMAP (pycolmap) then
extracts SIFT features, matches all pairs and runs incremental mapping with
ONE shared camera of the COLMAP model closest to the truth (OPENCV for CAHVOR:
radial k1, k2 and the tangential p1, p2 that absorb the O tilt;
OPENCV_FISHEYE for wide CAHVORE), refining focal lengths, principal point and
distortion in its bundle adjustments. The recovered camera is compared with
the truth as the calibrators are (harness.compare.projection_difference,
rotation mode, over the whole image at 10 m), next to the target-based result
of the same COLMAP model on the dot board (harness.calibrators colmap, through
the campaign runner's stages).

The scale and pose of the reconstruction are free; only the intrinsics are
compared. Failures (too few features, no initial pair, a reconstruction of
few images) are returned as status "failed" with the reason.
'''

import math
import time
from pathlib import Path

import numpy as np


def _pose_sequence(model, n, step_m, camera_height_m, look_range_m, yaw_deg, pitch_deg):
    r'''Rt_ref_terrain for each image: the rover moves forward along terrain x,
yawing and pitching its mast by a few degrees'''
    from harness.studies.stereo import terrain_pose_for
    from targets.terrain import ground_pose
    _, pitch0 = terrain_pose_for(model, camera_height_m, look_range_m)
    out = []
    for k in range(n):
        yaw = yaw_deg * math.sin(1.3 * k)
        pitch = pitch0 + pitch_deg * math.cos(0.9 * k)
        Rt0 = ground_pose(0.0, pitch_deg=pitch, yaw_deg=yaw)
        c_t = (model.C - Rt0[3]) @ Rt0[:3]
        Rt = ground_pose(camera_height_m - c_t[2], pitch_deg=pitch, yaw_deg=yaw)
        # the rover has driven k steps: the terrain is shifted back under it
        shift = np.array([k * step_m, 0.15 * step_m * math.sin(0.7 * k), 0.0])
        Rt[3] = Rt[3] - Rt[:3] @ shift
        out.append(Rt)
    return out


def closest_colmap_model(model):
    from reference_models.catalogue import field_of_view_deg
    if model.family == "CAHVORE" and max(field_of_view_deg(model)) > 100:
        return "OPENCV_FISHEYE"
    return "OPENCV"


def _compare(truth, family, params):
    from harness import compare as cmp
    from harness.calibrators.colmap_fit import ColmapModel
    fit = ColmapModel(family, params, truth.width, truth.height)
    d = cmp.projection_difference(truth, fit, mode="rotation")
    ph = truth.photogrammetric()
    return {"params": [float(p) for p in params],
            "fx": fit.fx, "fy": fit.fy, "cx": fit.cx, "cy": fit.cy,
            "fx_error_px": fit.fx - ph.Hs, "fy_error_px": fit.fy - ph.Vs,
            "cx_error_px": fit.cx - ph.Hc, "cy_error_px": fit.cy - ph.Vc,
            "projection_rms_px": float(d["rms"]), "projection_max_px": float(d["max"])}


def selfcal_colmap(image_dir, workdir, colmap_model, refine_principal_point=True, threads=2):
    r'''pycolmap: SIFT, exhaustive matching, incremental mapping with one shared camera

RETURNED VALUE: dict with status, reason, camera model and params (COLMAP's
convention), registered images, points, mean reprojection error

The pycolmap pipeline runs in a child process of its own: its native code
(SIFT, matching, Ceres) can abort the process, and a calibrator's failure must
be a result, not the end of the caller. (The "corrupted size vs. prev_size" abort
at the exit of test processes, once blamed on it, was pupil_apriltags': see
targets.detect_apriltag._destroy.)
'''
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor
    from concurrent.futures.process import BrokenProcessPool

    with ProcessPoolExecutor(max_workers=1,
                             mp_context=multiprocessing.get_context("spawn")) as pool:
        job = pool.submit(_selfcal_colmap_here, str(image_dir), str(workdir), colmap_model,
                          refine_principal_point, threads)
        try:
            return job.result()
        except BrokenProcessPool as e:
            return {"status": "failed", "reason": f"pycolmap's process died: {e}",
                    "seconds": {}}


def _selfcal_colmap_here(image_dir, workdir, colmap_model, refine_principal_point, threads):
    import pycolmap
    workdir = Path(workdir)
    db = workdir / "database.db"
    if db.exists():
        db.unlink()
    sparse = workdir / "sparse"
    sparse.mkdir(parents=True, exist_ok=True)
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = colmap_model
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.use_gpu = False
    extraction.num_threads = threads
    extraction.sift.max_num_features = 8000
    t0 = time.perf_counter()
    pycolmap.extract_features(db, image_dir, camera_mode=pycolmap.CameraMode.SINGLE,
                              reader_options=reader, extraction_options=extraction,
                              device=pycolmap.Device.cpu)
    matching = pycolmap.FeatureMatchingOptions()
    matching.use_gpu = False
    matching.num_threads = threads
    pycolmap.match_exhaustive(db, matching_options=matching, device=pycolmap.Device.cpu)
    t_match = time.perf_counter() - t0
    opts = pycolmap.IncrementalPipelineOptions()
    opts.ba_refine_focal_length = True
    opts.ba_refine_principal_point = bool(refine_principal_point)
    opts.ba_refine_extra_params = True
    opts.num_threads = threads
    opts.random_seed = 0
    opts.multiple_models = False
    t0 = time.perf_counter()
    recs = pycolmap.incremental_mapping(db, image_dir, sparse, options=opts)
    t_map = time.perf_counter() - t0
    if not recs:
        return {"status": "failed", "reason": "incremental mapping built no reconstruction",
                "seconds": {"features_matching": t_match, "mapping": t_map}}
    rec = max(recs.values(), key=lambda r: r.num_reg_images())
    cam = next(iter(rec.cameras.values()))
    return {"status": "ok", "reason": "", "colmap_model": cam.model.name,
            "params": [float(p) for p in cam.params],
            "registered_images": int(rec.num_reg_images()),
            "points3D": int(rec.num_points3D()),
            "mean_reprojection_error_px": float(rec.compute_mean_reprojection_error()),
            "seconds": {"features_matching": t_match, "mapping": t_map}}


def target_based(camera, colmap_model, spp=8, n_poses=6):
    r'''The same COLMAP model calibrated on the dot board (campaign runner stages),
at the camera's native size'''
    from harness import stages
    try:
        entry = stages.cached_catalogue(None).get(camera)
        truth = entry.model
        target = stages.cached_target("dots")
        poses = stages.poses_stage(truth, target, n_poses, 0)
        renders, _, _ = stages.render_stage("raycast", truth, target, poses,
                                            {"spp": spp, "adaptive": True})
        dets, _ = stages.detect_stage([r.image for r in renders], target)
        obs = stages.observations_from(truth, target, poses, dets)
    except stages.StageFailed as e:
        return {"status": "failed", "stage": e.stage, "reason": e.reason}
    res = stages.calibrate_stage("colmap", obs, target, colmap_model, truth, {})
    if res.status != "ok":
        return {"status": res.status, "reason": res.reason}
    d = _compare(truth, colmap_model, res.model.params)
    return {"status": "ok", **d}


def run_selfcal(camera=15, colmap_model=None, n_images=10, step_m=0.25, spp=2,
                camera_height_m=None, look_range_m=5.0, yaw_deg=15.0, pitch_deg=6.0,
                relief_m=0.5, refine_principal_point=True, workdir="selfcal", seed=0,
                with_target=True, scale=1.0, progress=None):
    r'''Render the sequence, self-calibrate with COLMAP, compare (see the module docstring)'''
    import cv2

    from harness.studies.stereo import default_geometry
    from reference_models.catalogue import load_catalogue
    from renderers.raycast_terrain import render_terrain
    from targets.terrain import Sun, make_terrain
    say = progress or (lambda s: None)
    entry = load_catalogue().get(camera)
    truth = entry.model
    if scale != 1.0:
        from harness.studies.stereo import scale_model
        truth = scale_model(truth, scale)
    colmap_model = colmap_model or closest_colmap_model(truth)
    h = camera_height_m if camera_height_m is not None else default_geometry(entry.role)[0]
    workdir = Path(workdir)
    image_dir = workdir / "images"
    image_dir.mkdir(parents=True, exist_ok=True)
    for old in image_dir.glob("*.png"):
        old.unlink()
    span = n_images * step_m
    terrain = make_terrain(extent=(-1.0, 20.0 + span, -20.0, 20.0), cell=0.05, texel=0.01,
                           seed=seed, relief_m=relief_m, relief_wavelength_m=4.0,
                           sun=Sun(azimuth_deg=140, elevation_deg=40))
    poses = _pose_sequence(truth, n_images, step_m, h, look_range_m, yaw_deg, pitch_deg)
    t0 = time.perf_counter()
    for k, Rt in enumerate(poses):
        say(f"rendering image {k + 1}/{n_images}")
        r = render_terrain(truth, terrain, Rt, spp=spp)
        cv2.imwrite(str(image_dir / f"img{k:03d}.png"),
                    np.clip(np.round(r.image * 255.0), 0, 255).astype(np.uint8))
    t_render = time.perf_counter() - t0
    say(f"COLMAP {colmap_model}: features, matching, incremental mapping")
    try:
        sc = selfcal_colmap(image_dir, workdir, colmap_model,
                            refine_principal_point=refine_principal_point)
    except Exception as e:   # pycolmap failing is a result of this method, not a crash
        sc = {"status": "failed", "reason": f"{type(e).__name__}: {e}"}
    if sc["status"] == "ok":
        sc.update(_compare(truth, sc["colmap_model"], sc["params"]))
    out = {"camera": entry.key, "camera_label": f"{entry.rover} {entry.role} {entry.side}",
           "truth_family": truth.family, "colmap_model": colmap_model,
           "n_images": n_images, "step_m": step_m, "spp": spp, "camera_height_m": h,
           "yaw_deg": yaw_deg, "pitch_deg": pitch_deg, "relief_m": relief_m,
           "refine_principal_point": refine_principal_point,
           "render_seconds": t_render, "terrain": terrain.as_dict(), "selfcal": sc}
    out["scale"] = scale
    if with_target:
        say("target-based COLMAP calibration on the dot board")
        out["target"] = target_based(camera, colmap_model)
    return out


def main(argv=None):
    import argparse
    import json
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--camera", default="15")
    ap.add_argument("--colmap-model", default=None)
    ap.add_argument("--images", type=int, default=10)
    ap.add_argument("--spp", type=int, default=2)
    ap.add_argument("--relief", type=float, default=0.5, help="terrain relief std, m")
    ap.add_argument("--yaw", type=float, default=15.0, help="mast yaw amplitude, deg")
    ap.add_argument("--fix-principal-point", action="store_true",
                    help="keep the principal point at the image centre (COLMAP's default)")
    ap.add_argument("-o", "--out", default="selfcal")
    ap.add_argument("--no-target", action="store_true")
    a = ap.parse_args(argv)
    r = run_selfcal(a.camera, a.colmap_model, n_images=a.images, spp=a.spp, workdir=a.out,
                    relief_m=a.relief, yaw_deg=a.yaw,
                    refine_principal_point=not a.fix_principal_point,
                    with_target=not a.no_target, progress=lambda s: print(f"  {s}", flush=True))
    Path(a.out, "selfcal.json").write_text(json.dumps(r, indent=1, allow_nan=False))
    for k in ("selfcal", "target"):
        if k in r:
            v = r[k]
            print(f"{k:8s} {v['status']:6s} " + (
                f"projection {v['projection_rms_px']:.3f} px RMS ({v['projection_max_px']:.3f} "
                f"max); fx err {v['fx_error_px']:+.2f} px, cx err {v['cx_error_px']:+.2f}, "
                f"cy err {v['cy_error_px']:+.2f}" if v["status"] == "ok" else v.get("reason", "")))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
