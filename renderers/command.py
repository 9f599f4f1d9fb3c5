r'''Bring your own renderer: an external program driven through a request directory

SYNOPSIS

    from renderers.base import get_renderer, RenderSettings

    r = get_renderer("command", command=["python", "examples/external_renderer.py"])
    result = r.render(model, target.pattern(), Rt_cam_board, RenderSettings(spp=4))

    # inside the external program (if it is written in Python):
    from renderers.command import read_request, write_image
    req = read_request(sys.argv[1])      # .model, .pattern, .Rt_cam_board, .settings, .output
    write_image(req.output, image)       # (height, width) in [0,1]: 16-bit PNG or .npy

For each render camval writes a request directory and runs

    COMMAND... REQUEST_DIR/request.json

(or substitutes the argument "{request}" if COMMAND contains it). The
program must write the image to the output path named in the request, exit 0
and leave the image there; camval reads it back. The directory holds:

- request.json: {"protocol": "camval-render-request", "version": 1,
  "camera_file", "scene_file", "width", "height", "spp", "adaptive",
  "options", "output", "output_format" ("png16" or "npy"),
  "pixel_convention"}. Paths are relative to the request directory.
- camera.cahv / camera.cahvor / camera.cahvore: the camera model as a JPL
  model file (reference_models.jpl_files.write_model, full precision).
- scene.json: {"kind": "board", "pattern": {extent, board_value,
  background_value, cells (rows of albedo, null = transparent), cell_origin,
  cell_size, circles ([cx, cy, r] rows), circle_value}, "Rt_cam_board": 4
  rows of 3 (R on top, t last, mrcal's convention), "Rt_ref_cam": the model's
  camera frame in its world frame, "frames": a description}.

The image: (height, width), row 0 at the top, pixel (ix, iy) centred at
q = (ix, iy) (reference_models.conventions), the area average of the albedo
over each pixel with spp x spp samples. As a 16-bit PNG: grey or RGB (the
green channel is read), value / 65535; as .npy: float32 or float64 in [0,1].

Failures (non-zero exit, a missing, unreadable or mis-sized image, values out
of [0,1] or NaN, a timeout) raise RendererError with the tail of the
program's stderr.
'''

import dataclasses
import json
import math
import os
import shlex
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass

import numpy as np

from reference_models.errors import CamvalError

from .base import RendererError, RenderResult, RenderSettings

PROTOCOL = "camval-render-request"
PROTOCOL_VERSION = 1
OUTPUT_FORMATS = {"png16": "image.png", "npy": "image.npy"}
PIXEL_CONVENTION = ("row 0 at the top; the centre of the top-left pixel is q = (0, 0); "
                    "x = column, y = row")
STDERR_TAIL_LINES = 12


class RequestError(CamvalError):
    '''A render request directory that cannot be read (for external renderer programs)'''


# --- the scene as JSON ---------------------------------------------------------------
def pattern_to_dict(pattern):
    cells = None
    if pattern.cells is not None:
        c = np.asarray(pattern.cells, dtype=np.float64)
        cells = [[float(v) if math.isfinite(v) else None for v in row] for row in c]
    circles = None
    if pattern.circles is not None:
        circles = np.asarray(pattern.circles, dtype=np.float64).reshape(-1, 3).tolist()
    return dict(extent=[float(v) for v in pattern.extent],
                board_value=float(pattern.board_value),
                background_value=float(pattern.background_value),
                cells=cells, cell_origin=[float(v) for v in pattern.cell_origin],
                cell_size=float(pattern.cell_size), circles=circles,
                circle_value=float(pattern.circle_value))


def pattern_from_dict(d):
    from targets.pattern import Pattern

    cells = d.get("cells")
    if cells is not None:
        cells = np.array([[np.nan if v is None else v for v in row] for row in cells],
                         dtype=np.float64)
    circles = d.get("circles")
    if circles is not None:
        circles = np.asarray(circles, dtype=np.float64).reshape(-1, 3)
    return Pattern(extent=tuple(d["extent"]), board_value=d["board_value"],
                   background_value=d["background_value"], cells=cells,
                   cell_origin=tuple(d["cell_origin"]), cell_size=d["cell_size"],
                   circles=circles, circle_value=d["circle_value"])


def _pattern_of(scene):
    if hasattr(scene, "extent"):
        return scene
    if hasattr(scene, "pattern"):
        return scene.pattern()
    raise RendererError(f"command renderer: cannot describe a scene of type "
                        f"{type(scene).__name__}; expected a targets.pattern.Pattern")


# --- writing and reading requests ----------------------------------------------------
def write_request(directory, model, scene, Rt_cam_board, settings, output_format="png16"):
    r'''Write a render request into `directory`; returns the path of request.json'''
    from reference_models.jpl_files import write_model

    if output_format not in OUTPUT_FORMATS:
        raise RendererError(f"command renderer: output format {output_format!r} is unknown; "
                            f"known: {', '.join(OUTPUT_FORMATS)}")
    Rt = np.asarray(Rt_cam_board, dtype=np.float64)
    if Rt.shape != (4, 3) or not np.all(np.isfinite(Rt)):
        raise RendererError(f"Rt_cam_board must be a finite (4,3) array; got shape {Rt.shape}")
    os.makedirs(directory, exist_ok=True)
    camera_file = "camera." + model.family.lower()
    write_model(model, os.path.join(directory, camera_file), overwrite=True,
                note="camval render request: the camera to render through")
    scene_doc = dict(kind="board", pattern=pattern_to_dict(_pattern_of(scene)),
                     Rt_cam_board=Rt.tolist(), Rt_ref_cam=model.Rt_ref_cam().tolist(),
                     frames=("board frame: the board in z = 0, seen from z < 0; "
                             "p_cam = R p_board + t with Rt_cam_board = [R; t]; camera frame: "
                             "x = H', y = A x H', z = A, origin C; p_ref = R p_cam + t with "
                             "Rt_ref_cam"))
    with open(os.path.join(directory, "scene.json"), "w") as f:
        json.dump(scene_doc, f, indent=1, allow_nan=False)
    request = dict(protocol=PROTOCOL, version=PROTOCOL_VERSION, camera_file=camera_file,
                   scene_file="scene.json", width=model.width, height=model.height,
                   spp=settings.spp, adaptive=settings.adaptive, options=settings.options,
                   output=OUTPUT_FORMATS[output_format], output_format=output_format,
                   pixel_convention=PIXEL_CONVENTION)
    path = os.path.join(directory, "request.json")
    with open(path, "w") as f:
        json.dump(request, f, indent=1, allow_nan=False)
    return path


@dataclass(frozen=True, eq=False)
class Request:
    model: object
    pattern: object
    Rt_cam_board: np.ndarray
    settings: RenderSettings
    output: str
    output_format: str
    raw: dict


def read_request(path):
    r'''Read a request written by write_request (for external renderers written in Python)

SYNOPSIS

    req = read_request("/tmp/camval-cmd-xyz/request.json")
    # req.model, req.pattern, req.Rt_cam_board (4,3), req.settings, req.output (absolute)
'''
    from reference_models.jpl_files import read_model

    path = os.fspath(path)
    if os.path.isdir(path):
        path = os.path.join(path, "request.json")
    try:
        with open(path) as f:
            raw = json.load(f)
    except (OSError, json.JSONDecodeError) as e:
        raise RequestError(f"'{path}': cannot read the render request: {e}") from None
    if raw.get("protocol") != PROTOCOL or raw.get("version") != PROTOCOL_VERSION:
        raise RequestError(f"'{path}': not a {PROTOCOL} version {PROTOCOL_VERSION} request "
                           f"(protocol {raw.get('protocol')!r}, version {raw.get('version')!r})")
    base = os.path.dirname(os.path.abspath(path))
    model = read_model(os.path.join(base, raw["camera_file"]))
    with open(os.path.join(base, raw["scene_file"])) as f:
        scene = json.load(f)
    if scene.get("kind") != "board":
        raise RequestError(f"'{path}': scene kind {scene.get('kind')!r} is not supported; "
                           "expected 'board'")
    settings = RenderSettings(spp=raw["spp"], adaptive=raw["adaptive"],
                              options=raw.get("options") or {})
    return Request(model=model, pattern=pattern_from_dict(scene["pattern"]),
                   Rt_cam_board=np.asarray(scene["Rt_cam_board"], dtype=np.float64),
                   settings=settings, output=os.path.join(base, raw["output"]),
                   output_format=raw["output_format"], raw=raw)


def write_image(path, image):
    r'''Write an image as the protocol wants it: 16-bit grey PNG, or .npy float32'''
    img = np.asarray(image, dtype=np.float64)
    if path.endswith(".npy"):
        np.save(path, img.astype(np.float32))
        return path
    import cv2

    q = np.round(np.clip(img, 0.0, 1.0) * 65535.0).astype(np.uint16)
    if not cv2.imwrite(path, q):
        raise RendererError(f"cannot write the image '{path}'")
    return path


def read_image(path, width, height):
    r'''Read an external renderer's output: float64 (height, width) in [0,1], or raise'''
    if not os.path.exists(path):
        raise RendererError(f"the renderer wrote no image at '{path}'")
    if path.endswith(".npy"):
        try:
            img = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as e:
            raise RendererError(f"cannot read the image '{path}': {e}") from None
        if img.dtype.kind != "f":
            raise RendererError(f"'{path}' holds {img.dtype} values; expected float32 in [0,1]")
        img = img.astype(np.float64)
    else:
        import cv2

        raw = cv2.imread(path, cv2.IMREAD_UNCHANGED)
        if raw is None:
            raise RendererError(f"cannot read the image '{path}' (expected a 16-bit PNG)")
        if raw.ndim == 3:
            raw = raw[..., 1]
        if raw.dtype != np.uint16:
            raise RendererError(f"'{path}' is a {raw.dtype} image; expected a 16-bit PNG")
        img = raw.astype(np.float64) / 65535.0
    if img.shape != (height, width):
        raise RendererError(f"'{path}' has shape {img.shape}; expected (height, width) = "
                            f"{(height, width)}")
    if not np.all(np.isfinite(img)) or img.min() < 0.0 or img.max() > 1.0:
        raise RendererError(f"'{path}' has values outside [0,1] or NaN "
                            f"(min {np.nanmin(img):.6g}, max {np.nanmax(img):.6g})")
    return img


def _tail(text, n=STDERR_TAIL_LINES):
    lines = (text or "").strip().splitlines()
    return "\n".join(lines[-n:]) if lines else "(no output)"


class CommandRenderer:
    r'''An external renderer program (see the module docstring for the protocol)

ARGUMENTS

- command: the program and its arguments, a list (or a string, split as a shell
  would); "{request}" is replaced by the request path, else it is appended.
  May instead be given per render as the option "command" (campaigns construct
  renderers without arguments); options "output_format" and "timeout" too.
  Other options are passed to the program in request.json.
- output_format: "png16" (default) or "npy"
- timeout: seconds before the program is killed (None: no limit)
- keep_dir: write requests into this directory and keep them (default: a
  temporary directory, removed after each render)
- env: extra environment variables for the program
- name: the name recorded in metadata (default "command")
- version_command: a command that prints the program's version (optional)
'''

    def __init__(self, command=None, output_format="png16", timeout=None, keep_dir=None,
                 env=None, name="command", version_command=None):
        self.command = None if command is None else self._check_command(command)
        self.output_format = self._check_format(output_format)
        self.timeout = timeout
        self.keep_dir = keep_dir
        self.env = dict(env or {})
        self.name = name
        self.version_command = version_command
        self._version = None

    @staticmethod
    def _check_command(command):
        if not isinstance(command, (str, list, tuple)) or not command:
            raise RendererError("renderer 'command' needs command=[program, args...]: the "
                                f"external renderer to run with the request path; got {command!r}")
        cmd = shlex.split(command) if isinstance(command, str) else [str(c) for c in command]
        if shutil.which(cmd[0]) is None and not os.path.exists(cmd[0]):
            raise RendererError(f"renderer 'command': program {cmd[0]!r} not found "
                                "(not on PATH and not a file)")
        return cmd

    @staticmethod
    def _check_format(output_format):
        if output_format not in OUTPUT_FORMATS:
            raise RendererError(f"command renderer: output format {output_format!r} is "
                                f"unknown; known: {', '.join(OUTPUT_FORMATS)}")
        return output_format

    def version(self):
        if self._version is None:
            v = "external: " + (" ".join(shlex.quote(c) for c in self.command)
                                if self.command else "(command given per render)")
            if self.version_command:
                vc = (shlex.split(self.version_command) if isinstance(self.version_command, str)
                      else list(self.version_command))
                try:
                    out = subprocess.run(vc, capture_output=True, text=True, timeout=60)
                    v += f" ({out.stdout.strip() or out.stderr.strip()})"
                except (OSError, subprocess.SubprocessError) as e:
                    v += f" (version query failed: {e})"
            self._version = v
        return self._version

    def render(self, model, scene, Rt_cam_board, settings=None):
        settings = RenderSettings() if settings is None else settings
        opts = dict(settings.options)
        command = (self._check_command(opts.pop("command")) if "command" in opts
                   else self.command)
        if command is None:
            raise RendererError("renderer 'command' needs a command: construct it with "
                                "command=[program, args...] or give the render option "
                                "'command' (campaign: options = { command = [...] })")
        output_format = self._check_format(opts.pop("output_format", self.output_format))
        timeout = opts.pop("timeout", self.timeout)
        # the program sees its own options only
        settings = dataclasses.replace(settings, options=opts)
        t0 = time.perf_counter()
        if self.keep_dir:
            os.makedirs(self.keep_dir, exist_ok=True)
            workdir = tempfile.mkdtemp(prefix="request-", dir=self.keep_dir)
        else:
            workdir = tempfile.mkdtemp(prefix="camval-command-")
        try:
            req = write_request(workdir, model, scene, Rt_cam_board, settings, output_format)
            if any("{request}" in c for c in command):
                cmd = [c.replace("{request}", req) for c in command]
            else:
                cmd = command + [req]
            env = dict(os.environ, **self.env)
            try:
                proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout,
                                      env=env)
            except subprocess.TimeoutExpired as e:
                raise RendererError(
                    f"external renderer {cmd[0]!r} timed out after {timeout} s; stderr: "
                    f"{_tail(e.stderr if isinstance(e.stderr, str) else '')}") from None
            except OSError as e:
                raise RendererError(f"cannot run external renderer {cmd[0]!r}: {e}") from None
            if proc.returncode != 0:
                raise RendererError(f"external renderer {cmd[0]!r} failed (exit "
                                    f"{proc.returncode}); stderr:\n{_tail(proc.stderr)}")
            out = os.path.join(workdir, OUTPUT_FORMATS[output_format])
            try:
                img = read_image(out, model.width, model.height)
            except RendererError as e:
                raise RendererError(f"external renderer {cmd[0]!r}: {e}; stderr:\n"
                                    f"{_tail(proc.stderr)}") from None
        finally:
            if not self.keep_dir:
                shutil.rmtree(workdir, ignore_errors=True)
        meta = dict(renderer=self.name, version=self.version(), settings=settings.as_dict(),
                    seconds=time.perf_counter() - t0, samples=settings.spp ** 2,
                    command=command, output_format=output_format)
        if self.keep_dir:
            meta["request_dir"] = workdir
        return RenderResult(image=img.astype(np.float32), metadata=meta)
