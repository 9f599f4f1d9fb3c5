r'''Exact synthetic correspondences for testing calibrators (no rendering)

SYNOPSIS

    from synthetic import default_target, synthetic_poses, exact_observations   # in tests/

    target = default_target()                     # the 10x10 dot grid
    Rts = synthetic_poses(model, target, n=6)          # list of Rt_cam_board (4,3)
    obs = exact_observations(model, target, Rts)  # q = projected dot centres

The poses: the board (10x10, 0.1 m spacing) centred on the rays of the image
centre and of points towards the four corners, at ranges chosen so that it
spans 90% (near) to 45% (far) of the image's smaller side (1.2-2.3 m for a
1024x1024 navcam), tilted by up to 45 deg. targets.poses.plan_poses is the
project's planner; these poses only need to make the exact-correspondence
tests independent of it.
'''

from dataclasses import dataclass

import numpy as np

from harness.calibrators.base import Observations


@dataclass(frozen=True)
class DotGrid:
    r'''A minimal 10x10 dot grid (used only if targets.boards is not available)'''

    n: int = 10
    spacing: float = 0.1
    radius: float = 0.025
    name: str = "dots"
    kind: str = "dots"

    def points(self):
        i, j = np.meshgrid(np.arange(self.n), np.arange(self.n))
        return np.stack((i.ravel() * self.spacing, j.ravel() * self.spacing,
                         np.zeros(self.n * self.n)), axis=-1)

    def point_ids(self):
        return np.arange(self.n * self.n)

    def pattern(self):
        from targets.pattern import Pattern
        p = self.points()
        m = self.spacing
        return Pattern(extent=(-m, (self.n - 1) * m + m, -m, (self.n - 1) * m + m),
                       circles=np.column_stack((p[:, 0], p[:, 1],
                                                np.full(len(p), self.radius))))


def default_target():
    try:
        from targets.boards import load_target
    except ImportError:
        return DotGrid()
    return load_target("dots")


def _rotation(axis, angle):
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def synthetic_poses(model, target, n=6, seed=0):
    r'''n board poses Rt_cam_board (4,3) filling the image of `model`'''
    rng = np.random.default_rng(seed)
    W, H = model.width, model.height
    p = np.asarray(target.points(), dtype=np.float64)
    centre_b = 0.5 * (p.min(axis=0) + p.max(axis=0))
    size = float(np.max(p.max(axis=0) - p.min(axis=0)))
    ph = model.photogrammetric()
    f = 0.5 * (ph.Hs + ph.Vs)
    Rt_ref_cam = model.Rt_ref_cam()
    offsets = [(0, 0), (-0.23, -0.23), (0.23, -0.23), (-0.23, 0.23), (0.23, 0.23), (0.0, 0.1)]
    fracs = [0.85, 0.48, 0.5, 0.46, 0.5, 0.62]
    out = []
    for i in range(n):
        ox, oy = offsets[i % len(offsets)]
        q = np.array([(0.5 + ox) * (W - 1), (0.5 + oy) * (H - 1)])
        frac = fracs[i % len(fracs)]
        rng_m = f * size / (frac * min(W, H))
        o, v = model.unproject(q)
        # ray into the camera frame
        v_cam = Rt_ref_cam[:3].T @ v
        o_cam = Rt_ref_cam[:3].T @ (o - Rt_ref_cam[3])
        centre_cam = o_cam + rng_m * v_cam / v_cam[2]
        tilt = np.radians(45.0 if i else 10.0) * (0.6 + 0.4 * rng.random())
        axis_angle = rng.uniform(0, 2 * np.pi)
        axis = np.array([np.cos(axis_angle), np.sin(axis_angle), 0.0])
        R = _rotation(axis, tilt) @ _rotation([0, 0, 1], rng.uniform(-0.2, 0.2))
        t = centre_cam - R @ centre_b
        out.append(np.vstack((R, t)))
    return out


def compose(Rt_a_b, Rt_b_c):
    R = Rt_a_b[:3] @ Rt_b_c[:3]
    t = Rt_a_b[:3] @ Rt_b_c[3] + Rt_a_b[3]
    return np.vstack((R, t))


def exact_observations(model, target, Rt_cam_board, centroids=False):
    r'''Observations whose q are the exact projections of the target points

SYNOPSIS

    obs = exact_observations(model, target, Rts)
    # obs.q (Nposes,Npoints,2), obs.Rt_ref_board = Rt_ref_cam(truth) o Rt_cam_board

With centroids=True q are the expected centroids of the dots' outlines (what
a perfect detector sees), i.e. the data carry the centroid bias. Points that
project outside the image are NaN.
'''
    from harness.calibrators.bias import centroid_bias
    p = np.asarray(target.points(), dtype=np.float64)
    Rt_ref_cam = model.Rt_ref_cam()
    Rt_ref_board = np.array([compose(Rt_ref_cam, Rt) for Rt in Rt_cam_board])
    p_ref = np.einsum("fij,nj->fni", Rt_ref_board[:, :3], p) + Rt_ref_board[:, None, 3]
    q = model.project(p_ref)
    if centroids:
        q = q + np.array([centroid_bias(model, target, Rt, p) for Rt in Rt_cam_board])
    W, H = model.width, model.height
    outside = ~((q[..., 0] >= -0.5) & (q[..., 0] <= W - 0.5) &
                (q[..., 1] >= -0.5) & (q[..., 1] <= H - 0.5))
    q[outside] = np.nan
    return Observations(q=q, p_board=p, imagersize=(W, H), Rt_ref_board=Rt_ref_board,
                        point_ids=np.asarray(target.point_ids()))


def centroid_observations(truth, target, poses):
    r'''harness.stages.observations_from with every detection the dots' exact expected
centroids (targets.centroids.expected_centroids: what a perfect detector sees), as the
campaign builds Observations from a detector's output'''
    from harness import stages
    from targets.centroids import expected_centroids

    class Detected:
        def __init__(self, q):
            self.q = q
    return stages.observations_from(truth, target, poses,
                                    [Detected(expected_centroids(truth, target, Rt))
                                     for Rt in poses])


def catalogue_models():
    r'''[(key, model)] of every catalogue camera: the 22 slots, then the extras'''
    from reference_models.catalogue import load_catalogue
    cat = load_catalogue()
    return [(str(e.key), e.model) for e in list(cat.slots()) + list(cat.extras())]


def rendered_observations(truth, target, Rt_cam_board=None, renderer="raycast", spp=16,
                          n=6, seed=0):
    r'''Observations detected in images rendered through `truth`

SYNOPSIS

    obs, info = rendered_observations(truth, target)    # planned poses, ray-cast K=16
    # info: {"render_seconds", "detect_seconds", "n_found": [...], "detections": [...]}

Poses from targets.poses.plan_poses unless given; each image is rendered by
the named renderer (noise-free) and detected with targets.detect.detect. The
sidecar-equivalent survey: Rt_ref_board = truth.Rt_ref_cam() o Rt_cam_board.
'''
    import time

    from renderers.base import RenderSettings, get_renderer
    from targets.detect import detect
    if Rt_cam_board is None:
        from targets.poses import plan_poses
        Rt_cam_board = plan_poses(truth, target, n=n, seed=seed)
    r = get_renderer(renderer)
    qs, dets, t_render, t_detect = [], [], 0.0, 0.0
    for Rt in Rt_cam_board:
        t0 = time.perf_counter()
        image = r.render(truth, target.pattern(), Rt, RenderSettings(spp=spp)).image
        t1 = time.perf_counter()
        det = detect(image, target)
        t_detect += time.perf_counter() - t1
        t_render += t1 - t0
        qs.append(det.q)
        dets.append(det)
    Rt_ref_cam = truth.Rt_ref_cam()
    obs = Observations(q=np.array(qs), p_board=np.asarray(target.points(), dtype=np.float64),
                       imagersize=(truth.width, truth.height),
                       Rt_ref_board=np.array([compose(Rt_ref_cam, Rt) for Rt in Rt_cam_board]),
                       point_ids=np.asarray(target.point_ids()))
    return obs, {"render_seconds": t_render, "detect_seconds": t_detect,
                 "n_found": [int(d.n_found) for d in dets],
                 "detection_status": [d.status for d in dets],
                 "Rt_cam_board": np.array(Rt_cam_board)}
