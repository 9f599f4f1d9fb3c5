r'''camval's external renderer protocol: the request directory, read and written

SYNOPSIS

    # inside an external renderer written in Python (camval installed):
    from renderers.protocol import read_request, write_image, serve

    def render(req):                      # req: Request (see read_request)
        return my_engine(req.model, req.pattern, req.Rt_cam_board, req.settings.spp)
        # (height, width) in [0,1]; raise NotApplicable("why") to decline

    serve(render)                         # one-shot (argv[1] = request.json) or
                                          # persistent (no argument: requests on stdin)

    # camval's side (renderers.command):
    path = write_request(directory, model, pattern, Rt_cam_board, settings, "png16")

The protocol is written down for teams in any language in
docs/README-renderers.md ("The external renderer protocol"). In short:

- A request is a directory: request.json (what to render, which camval wrote
  it), camera.cahv|.cahvor|.cahvore (the JPL model file, full precision),
  scene.json (the board and its pose) and, in "rays" mode, rays files.
- One-shot: camval runs COMMAND... REQUEST_DIR/request.json per image. Exit 0
  with the output written; exit EXIT_NOT_APPLICABLE (10) when the program
  cannot render this camera by design (the last lines of stderr are the
  reason); any other exit is a failure (the tail of stderr is recorded).
- Persistent: camval starts COMMAND... once (no request argument, environment
  CAMVAL_PROTOCOL=persistent) and writes one JSON line per request to its
  stdin, {"request": "/abs/path/request.json"}; the program answers each with
  one JSON line on stdout, {"status": "ok"} | {"status": "not-applicable",
  "reason": ...} | {"status": "failed", "reason": ...}. stdout carries
  answers only: log to stderr.
- Request modes ("mode" in request.json): "image" (render the camera model's
  image), "pinhole" (render the ideal pinhole of request "pinhole"; camval
  warps it), "rays" (return one value per ray of the rays files).
'''

import json
import math
import os
import subprocess
import sys
from dataclasses import dataclass

import numpy as np

from reference_models.errors import CamvalError

from .base import RendererError, RendererNotApplicable, RenderSettings

PROTOCOL = "camval-render-request"
PROTOCOL_VERSION = 2
READABLE_VERSIONS = (1, 2)
MODES = ("image", "pinhole", "rays")
OUTPUT_FORMATS = {"png16": "image.png", "npy": "image.npy"}
PIXEL_CONVENTION = ("row 0 at the top; the centre of the top-left pixel is q = (0, 0); "
                    "x = column, y = row")
# A one-shot program that cannot render this camera or scene by design exits with this
# status; the reason is the tail of its stderr. 10 is outside the codes shells and
# interpreters use for their own failures (1, 2, 126-128+n) and sysexits.h (64-78).
EXIT_NOT_APPLICABLE = 10
# What a record keeps of a program's stderr: its last lines, bounded in lines and bytes
# (a Python traceback's last frames and the exception fit; a runaway log does not).
STDERR_TAIL_LINES = 40
STDERR_TAIL_BYTES = 4096
PERSISTENT_ENV = ("CAMVAL_PROTOCOL", "persistent")
ANSWER_STATUSES = ("ok", "not-applicable", "failed")
# rays mode: the ray files of one request hold at most this many rays (float32 directions:
# 12 bytes a ray, 4.2 M rays = 50 MB; building them here peaks near 0.5 GB); camval asks for
# a larger image in bands of whole rows (5120x3840 at K=4: 315 M rays, 76 requests)
MAX_RAYS_PER_REQUEST = 1 << 22


class RequestError(CamvalError):
    '''A render request directory that cannot be read (for external renderer programs)'''


class NotApplicable(RendererNotApplicable):
    '''Raised by a render function given to serve(): this camera/scene is not applicable'''


# --- which camval wrote a request ----------------------------------------------------------
_IDENTITY = {}


def camval_identity():
    r'''{"version": the installed camval's version, "commit": the source tree's git commit or
None} (computed once per process)'''
    if not _IDENTITY:
        from importlib.metadata import PackageNotFoundError, version
        try:
            v = version("camval")
        except PackageNotFoundError:
            v = None
        commit = None
        src = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        try:
            out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=src, capture_output=True,
                                 text=True, timeout=10)
            if out.returncode == 0:
                commit = out.stdout.strip() or None
        except (OSError, subprocess.SubprocessError):
            pass
        _IDENTITY.update(version=v, commit=commit)
    return dict(_IDENTITY)


# --- the scene as JSON ---------------------------------------------------------------------
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


def pattern_of(scene):
    if hasattr(scene, "extent"):
        return scene
    if hasattr(scene, "pattern"):
        return scene.pattern()
    raise RendererError(f"command renderer: cannot describe a scene of type "
                        f"{type(scene).__name__}; expected a targets.pattern.Pattern")


FRAMES = ("board frame: the board in z = 0, seen from z < 0; p_cam = R p_board + t with "
          "Rt_cam_board = [R; t]; camera frame: x = H', y = A x H', z = A, origin C; "
          "p_ref = R p_cam + t with Rt_ref_cam")


# --- writing and reading requests ----------------------------------------------------------
def write_request(directory, model, scene, Rt_cam_board, settings, output_format="png16",
                  mode="image", extra=None):
    r'''Write a render request into `directory`; returns the path of request.json

mode: "image" | "pinhole" | "rays"; extra: more request.json entries (the
pinhole of a pinhole request, the rays of a rays request).
'''
    from reference_models.jpl_files import write_model

    if output_format not in OUTPUT_FORMATS:
        raise RendererError(f"command renderer: output format {output_format!r} is unknown; "
                            f"known: {', '.join(OUTPUT_FORMATS)}")
    if mode not in MODES:
        raise RendererError(f"command renderer: request mode {mode!r} is unknown; "
                            f"known: {', '.join(MODES)}")
    Rt = np.asarray(Rt_cam_board, dtype=np.float64)
    if Rt.shape != (4, 3) or not np.all(np.isfinite(Rt)):
        raise RendererError(f"Rt_cam_board must be a finite (4,3) array; got shape {Rt.shape}")
    os.makedirs(directory, exist_ok=True)
    camera_file = "camera." + model.family.lower()
    write_model(model, os.path.join(directory, camera_file), overwrite=True,
                note="camval render request: the camera to render through")
    scene_doc = dict(kind="board", pattern=pattern_to_dict(pattern_of(scene)),
                     Rt_cam_board=Rt.tolist(), Rt_ref_cam=model.Rt_ref_cam().tolist(),
                     frames=FRAMES)
    with open(os.path.join(directory, "scene.json"), "w") as f:
        json.dump(scene_doc, f, indent=1, allow_nan=False)
    width, height = model.width, model.height
    if mode == "pinhole":
        width, height = extra["pinhole"]["width"], extra["pinhole"]["height"]
    output = OUTPUT_FORMATS[output_format] if mode != "rays" else "values.npy"
    request = dict(protocol=PROTOCOL, version=PROTOCOL_VERSION, camval=camval_identity(),
                   mode=mode, camera_file=camera_file, scene_file="scene.json",
                   width=width, height=height, spp=settings.spp, adaptive=settings.adaptive,
                   options=settings.options, output=output,
                   output_format=output_format if mode != "rays" else "npy",
                   pixel_convention=PIXEL_CONVENTION, **(extra or {}))
    path = os.path.join(directory, "request.json")
    with open(path, "w") as f:
        json.dump(request, f, indent=1, allow_nan=False)
    return path


@dataclass(frozen=True, eq=False)
class Request:
    r'''A request as read by read_request

model:         the camera model (reference_models: CAHV, CAHVOR, CAHVORE)
pattern:       targets.pattern.Pattern (the board)
Rt_cam_board:  (4,3) the board in the model's camera frame
settings:      RenderSettings (spp = K, adaptive, the program's own options)
output:        absolute path of the file to write
output_format: "png16" | "npy"
mode:          "image" | "pinhole" | "rays"
pinhole:       pinhole mode: {"fx", "fy", "cx", "cy", "width", "height"}, else None
directory:     the request directory
raw:           request.json as read
'''
    model: object
    pattern: object
    Rt_cam_board: np.ndarray
    settings: RenderSettings
    output: str
    output_format: str
    raw: dict
    mode: str = "image"
    pinhole: dict = None
    directory: str = ""

    def rays(self, mmap=True):
        r'''rays mode: (origins, directions), float64/float32 arrays of shape (N, 3) in the
camera frame of the model (origins broadcast from (1, 3) for a central camera)'''
        r = self.raw["rays"]
        d = np.load(os.path.join(self.directory, r["directions"]),
                    mmap_mode="r" if mmap else None)
        if r.get("origins"):
            o = np.load(os.path.join(self.directory, r["origins"]),
                        mmap_mode="r" if mmap else None)
        else:
            o = np.asarray(r["origin"], dtype=np.float64).reshape(1, 3)
        return o, d


def read_request(path):
    r'''Read a request written by write_request

SYNOPSIS

    req = read_request("/tmp/camval-cmd-xyz/request.json")    # or the directory
    # req.model, req.pattern, req.Rt_cam_board (4,3), req.settings, req.output (absolute),
    # req.mode, req.pinhole, req.rays()
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
    if raw.get("protocol") != PROTOCOL or raw.get("version") not in READABLE_VERSIONS:
        raise RequestError(f"'{path}': not a {PROTOCOL} request of version "
                           f"{' or '.join(map(str, READABLE_VERSIONS))} (protocol "
                           f"{raw.get('protocol')!r}, version {raw.get('version')!r})")
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
                   output_format=raw["output_format"], raw=raw,
                   mode=raw.get("mode", "image"), pinhole=raw.get("pinhole"), directory=base)


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
    check_values(path, img)
    return img


def check_values(path, values):
    if not np.all(np.isfinite(values)) or values.min() < 0.0 or values.max() > 1.0:
        raise RendererError(f"'{path}' has values outside [0,1] or NaN "
                            f"(min {np.nanmin(values):.6g}, max {np.nanmax(values):.6g})")


def tail(text, lines=STDERR_TAIL_LINES, nbytes=STDERR_TAIL_BYTES):
    r'''The last `lines` lines of text, at most `nbytes` bytes of them (UTF-8), with a note
of what was cut; "(no output)" for none'''
    all_lines = (text or "").rstrip().splitlines()
    while all_lines and not all_lines[0].strip():
        all_lines.pop(0)
    if not all_lines:
        return "(no output)"
    kept = all_lines[-lines:]
    out = "\n".join(kept)
    b = out.encode("utf-8", "replace")
    if len(b) > nbytes:
        out = b[-nbytes:].decode("utf-8", "ignore")
        out = out.split("\n", 1)[1] if "\n" in out else out
        kept = out.splitlines()
    cut = len(all_lines) - len(kept)
    return (f"[{cut} earlier lines cut]\n" if cut > 0 else "") + out


# --- the program's side: one-shot and persistent loops ------------------------------------
def answer_request(render, request_path):
    r'''Run render(Request) for one request and write its output -> the answer dict'''
    try:
        req = read_request(request_path)
        out = render(req)
        if out is not None:
            if req.mode == "rays":
                np.save(req.output, np.asarray(out, dtype=np.float32))
            else:
                write_image(req.output, out)
        return {"status": "ok"}
    except RendererNotApplicable as e:
        return {"status": "not-applicable", "reason": str(e) or type(e).__name__}
    except Exception as e:
        import traceback
        traceback.print_exc(file=sys.stderr)
        return {"status": "failed", "reason": f"{type(e).__name__}: {e}"}


def serve(render, argv=None, stdin=None, stdout=None):
    r'''The main loop of an external renderer written in Python

SYNOPSIS

    sys.exit(serve(render))

render(req) gets a Request and returns the image (mode "image": (height,
width); "pinhole": (pinhole height, width)) or the ray values (mode "rays":
(N,) or (N, K*K)), or writes req.output itself and returns None. Raise
NotApplicable("reason") to decline a camera.

With a request path in argv[1]: one-shot; returns the exit status (0,
EXIT_NOT_APPLICABLE, 1). Without: persistent; answers the JSON lines of stdin
until it closes, returns 0.
'''
    argv = sys.argv if argv is None else argv
    stdin = sys.stdin if stdin is None else stdin
    stdout = sys.stdout if stdout is None else stdout
    if len(argv) >= 2:
        a = answer_request(render, argv[1])
        if a["status"] != "ok":
            print(a["reason"], file=sys.stderr)
        return {"ok": 0, "not-applicable": EXIT_NOT_APPLICABLE}.get(a["status"], 1)
    for line in stdin:
        line = line.strip()
        if not line:
            continue
        try:
            path = json.loads(line)["request"]
        except (ValueError, KeyError, TypeError) as e:
            a = {"status": "failed", "reason": f"not a request line ({e}): {line[:200]}"}
        else:
            a = answer_request(render, path)
        stdout.write(json.dumps(a) + "\n")
        stdout.flush()
    return 0
