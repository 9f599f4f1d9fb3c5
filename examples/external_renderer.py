#!/usr/bin/env python3
r'''A worked example of an external renderer speaking camval's request protocol

    python examples/external_renderer.py REQUEST.json     # one-shot: one image, exit
    python examples/external_renderer.py                  # persistent: requests on stdin

camval's "command" renderer (renderers/command.py) writes a request directory
(camera model as a JPL file, the board and its pose as scene.json, image size
and sampling in request.json) and runs this program with the path of
request.json; or, with setup persistent = true, starts it once and sends one
JSON line {"request": PATH} per image on stdin, reading one JSON answer line
per request on stdout. The program renders and writes its output where the
request says. Anything it prints to stderr is recorded when it fails. The
protocol: docs/README-renderers.md.

This example renders with camval's own exact ray caster (image mode), with a
CAHV pinhole through the ray caster (pinhole mode) and by intersecting each
ray with the board plane (rays mode), so a campaign run through it gives the
same records as the built-in "raycast" renderer in image mode.

Terrain requests (scene kind "terrain", protocol version 3: req.terrain holds
the height field, texture, sun and lighting as plain values) it renders with
camval's terrain ray caster (renderers.raycast_terrain) as the stand-in
engine: image mode the model's image plus the optional range and shadow
outputs, pinhole mode the pinhole as a CAHV, rays mode each given ray
(trace_rays) with its range and shadow code, which is also how it answers the
shadow check. `camval stereo 12 11 --renderer command --command "python
examples/external_renderer.py" --setup persistent=true` runs the stereo range
check on it.

A board campaign through it:

    [[renderer]]
    name = "command"
    label = "example"
    spp = [4]
    setup = { command = ["python", "examples/external_renderer.py"], persistent = true }

It imports camval's request reader from the installed camval
(renderers.protocol); a program in another language reads the JSON and the
JPL model file itself (examples/rays_renderer.c does, in C).

A simulator team replaces render() by a call into its renderer.
Options (request.json "options"): "fail": fail with a message (used by the
tests of the failure paths); "wrong_size": write a 1x1 image; "not_applicable":
decline the camera with this reason; "sleep": seconds to wait first.
'''

import sys
import time

import numpy as np

from renderers.protocol import NotApplicable, serve


def pinhole_as_cahv(ph):
    r'''The ideal pinhole of a pinhole request as a CAHV model in the camera frame (C = 0,
A = z): x = H', y = A x H', so board poses mean the same for it'''
    from reference_models.cahvore import CAHV
    A = np.array([0.0, 0.0, 1.0])
    return CAHV(C=np.zeros(3), A=A, H=ph["fx"] * np.array([1.0, 0, 0]) + ph["cx"] * A,
                V=ph["fy"] * np.array([0, 1.0, 0]) + ph["cy"] * A,
                width=int(ph["width"]), height=int(ph["height"]))


def ray_values(req):
    r'''rays mode: the albedo each ray sees (the board plane z = 0 of the board frame)'''
    origins, dirs = req.rays()
    Rt = req.Rt_cam_board
    R, t = Rt[:3], Rt[3]
    # board frame: p_board = R^T (p_cam - t)
    o = (np.asarray(origins, dtype=np.float64) - t) @ R
    d = np.asarray(dirs, dtype=np.float64) @ R
    with np.errstate(divide="ignore", invalid="ignore"):
        s = -o[:, 2] / d[:, 2]
    hit = np.isfinite(s) & (s > 0)
    x = np.where(hit, o[:, 0] + s * d[:, 0], np.inf)
    y = np.where(hit, o[:, 1] + s * d[:, 1], np.inf)
    out = np.full(len(d), req.pattern.background_value, dtype=np.float64)
    out[hit] = req.pattern.albedo(x[hit], y[hit])
    return out


def terrain_render(req):
    r'''A terrain request: the image (or ray values) with range and shadow codes'''
    from renderers.raycast_terrain import render_terrain, trace_rays

    t = req.terrain
    terrain = t.to_terrain()          # camval's Terrain: the stand-in engine's scene
    light = t.lighting()              # shadows, exposure, sky
    if req.mode == "rays":
        origins, dirs = req.rays()
        value, rng, code = trace_rays(terrain, origins, dirs, Rt_ref_terrain=t.Rt_cam_terrain,
                                      **light)
        # each ray's radiance clipped to [0,1] (the protocol's range of values)
        return {"values": np.clip(value, 0.0, 1.0), "range": rng, "shadow": code}
    if req.mode == "pinhole":
        # the pinhole sits at C in the model's camera frame: the terrain's pose there
        r = render_terrain(pinhole_as_cahv(req.pinhole), terrain, t.Rt_cam_terrain,
                           spp=req.settings.spp, **light)
        return r.image
    r = render_terrain(req.model, terrain, t.Rt_ref_terrain, spp=req.settings.spp, **light)
    return {"image": r.image, "range": r.range, "shadow": r.shadow}


def render(req):
    opts = req.settings.options
    if opts.get("sleep"):
        time.sleep(float(opts["sleep"]))
    if opts.get("fail"):
        print("external_renderer: a log line before the failure", file=sys.stderr)
        raise RuntimeError(f"asked to fail ({opts['fail']})")
    if opts.get("not_applicable"):
        raise NotApplicable(opts["not_applicable"])
    if opts.get("wrong_size"):
        return np.zeros((1, 1))
    if req.terrain is not None:
        return terrain_render(req)
    if req.mode == "rays":
        return ray_values(req)
    from renderers.raycast import RaycastRenderer
    model = pinhole_as_cahv(req.pinhole) if req.mode == "pinhole" else req.model
    return RaycastRenderer().render(model, req.pattern, req.Rt_cam_board, req.settings).image


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] in ("-h", "--help"):
        print(__doc__)
        sys.exit(0)
    sys.exit(serve(render))
