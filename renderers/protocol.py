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
  scene.json (the board and its pose; or, version 3, a terrain: height field
  and texture as .npy beside it, sun, lighting, pose) and, in "rays" mode,
  rays files. A terrain program reads req.terrain (TerrainScene, plain
  values) and may also write the range and shadow codes (optional outputs).
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

import dataclasses
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
# version 3 added scene kind "terrain"; a request says the lowest version that can describe
# it (a board request is version 2, as before), so a program written for version 2 reads
# every board request and refuses a terrain one by its version
PROTOCOL_VERSION = 3
READABLE_VERSIONS = (1, 2, 3)
SCENE_VERSIONS = {"board": 2, "terrain": 3}
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


# --- terrain scenes (version 3) ------------------------------------------------------------
# the lighting of a terrain render: renderers.base's terrain renderers take these as options
# (raycast_terrain.render_terrain's defaults); in a request they are part of scene.json
TERRAIN_LIGHTING = {"shadows": True, "exposure": 1.0, "sky": 0.0}
TERRAIN_FILES = {"heights": "terrain-heights.npy", "albedo": "terrain-albedo.npy"}
TERRAIN_OUTPUTS = {"range": "range.npy", "shadow": "shadow.npy"}
TERRAIN_FRAMES = ("terrain frame: x, y horizontal, z UP; node (i, j) of the height grid at "
                  "(x0 + i cell, y0 + j cell, heights[j, i]); p_cam = R p_terrain + t with "
                  "Rt_cam_terrain = [R; t]; camera frame: x = H', y = A x H', z = A, origin C; "
                  "p_ref = R p_terrain + t with Rt_ref_terrain (the model's world frame)")
TERRAIN_SURFACE = ("the triangle pair of each grid cell, split along the diagonal from node "
                   "(i, j) to (i+1, j+1); with u = (x - x_i)/cell, v = (y - y_j)/cell and "
                   "hab = heights[j+b, i+a]: u >= v: z = h00 + u (h10 - h00) + v (h11 - h10); "
                   "u < v: z = h00 + v (h01 - h00) + u (h11 - h01); outside the grid: no surface")
TERRAIN_ALBEDO = ("albedo[tj, ti] covers the grid's rectangle [xmin, xmax] x [ymin, ymax], "
                  "texel (ti, tj) centred at (xmin + (ti + 1/2) (xmax - xmin)/Tx, "
                  "ymin + (tj + 1/2) (ymax - ymin)/Ty); sampled bilinearly, clamped at the edge")
TERRAIN_SHADING = ("radiance = exposure * albedo * (ambient + cos_i * lit), clipped to [0, 1]; "
                   "cos_i = n . sun (n: the hit triangle's upward unit normal), lit = 0 when "
                   "cos_i <= 0 or (shadows) when the ray from the hit point towards the sun "
                   "meets the surface, else 1; a ray that misses the surface sees `sky`")
SHADOW_CODES = {"lit": 0, "facing_away": 1, "cast": 2, "sky": 255}


def is_terrain(scene):
    r'''A targets.terrain.Terrain (a height field), as opposed to a board pattern'''
    return hasattr(scene, "heights") and hasattr(scene, "sun")


def terrain_lighting(options):
    r'''The lighting of a terrain request from render options: TERRAIN_LIGHTING updated'''
    out = {k: options.get(k, v) for k, v in TERRAIN_LIGHTING.items()}
    if not isinstance(out["shadows"], bool):
        raise RendererError(f"terrain option shadows={out['shadows']!r}; expected true/false")
    for k in ("exposure", "sky"):
        v = out[k]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise RendererError(f"terrain option {k}={v!r}; expected a finite number")
        out[k] = float(v)
    return out


def write_terrain_scene(directory, model, terrain, Rt_ref_terrain, settings, extra):
    r'''The terrain's side files and scene.json document -> (scene dict, outputs dict)'''
    from reference_models.poseutils import compose_Rt, invert_Rt

    heights = np.ascontiguousarray(terrain.heights, dtype=np.float64)
    albedo = np.ascontiguousarray(terrain.albedo, dtype=np.float32)
    np.save(os.path.join(directory, TERRAIN_FILES["heights"]), heights)
    np.save(os.path.join(directory, TERRAIN_FILES["albedo"]), albedo)
    Rt_cam_terrain = compose_Rt(invert_Rt(model.Rt_ref_cam()), Rt_ref_terrain)
    light = terrain_lighting(settings.options)
    doc = dict(kind="terrain",
               heights=dict(file=TERRAIN_FILES["heights"], dtype="float64",
                            shape=list(heights.shape)),
               cell=float(terrain.cell), origin=[float(v) for v in terrain.origin],
               extent=[float(v) for v in terrain.extent()],
               albedo=dict(file=TERRAIN_FILES["albedo"], dtype="float32",
                           shape=list(albedo.shape)),
               sun=dict(azimuth_deg=float(terrain.sun.azimuth_deg),
                        elevation_deg=float(terrain.sun.elevation_deg),
                        direction=[float(v) for v in terrain.sun.direction()]),
               ambient=float(terrain.ambient), **light,
               Rt_cam_terrain=Rt_cam_terrain.tolist(),
               Rt_ref_terrain=np.asarray(Rt_ref_terrain, np.float64).tolist(),
               Rt_ref_cam=model.Rt_ref_cam().tolist(), frames=TERRAIN_FRAMES,
               surface=TERRAIN_SURFACE, albedo_sampling=TERRAIN_ALBEDO,
               shading=TERRAIN_SHADING, shadow_codes=SHADOW_CODES,
               description=str(terrain.description))
    required = bool((extra or {}).get("shadow_required"))
    outputs = {"range": {"file": TERRAIN_OUTPUTS["range"], "required": False},
               "shadow": {"file": TERRAIN_OUTPUTS["shadow"], "required": required}}
    return doc, outputs


@dataclass(frozen=True, eq=False)
class TerrainScene:
    r'''A terrain request's scene as plain values (read_request: req.terrain)

heights:        (Ny, Nx) float64 node heights (m, z up); node (i, j) at
                (x0 + i cell, y0 + j cell)
cell:           node spacing (m); origin: (x0, y0)
albedo:         (Ty, Tx) float32 in [0, 1] over the grid's rectangle (TERRAIN_ALBEDO)
sun_direction:  (3,) unit vector towards the sun, terrain frame
sun_azimuth_deg, sun_elevation_deg: the same as angles (from +x towards +y; above the plane)
ambient, shadows, exposure, sky: the lighting (TERRAIN_SHADING)
Rt_cam_terrain: (4,3) the terrain in the camera frame (p_cam = R p_terrain + t)
Rt_ref_terrain: (4,3) the terrain in the model's world frame
description:    free text
'''
    heights: np.ndarray
    cell: float
    origin: tuple
    albedo: np.ndarray
    sun_direction: np.ndarray
    sun_azimuth_deg: float
    sun_elevation_deg: float
    ambient: float
    shadows: bool
    exposure: float
    sky: float
    Rt_cam_terrain: np.ndarray
    Rt_ref_terrain: np.ndarray
    description: str = ""

    def extent(self):
        ny, nx = self.heights.shape
        x0, y0 = self.origin
        return (x0, x0 + (nx - 1) * self.cell, y0, y0 + (ny - 1) * self.cell)

    def to_terrain(self):
        r'''As a targets.terrain.Terrain (for programs that use camval's own renderers)'''
        from targets.terrain import Sun, Terrain
        return Terrain(heights=self.heights, cell=self.cell, origin=self.origin,
                       albedo=self.albedo,
                       sun=Sun(azimuth_deg=self.sun_azimuth_deg,
                               elevation_deg=self.sun_elevation_deg),
                       ambient=self.ambient, description=self.description)

    def lighting(self):
        r'''{"shadows", "exposure", "sky"}: the options of camval's terrain renderers'''
        return {"shadows": self.shadows, "exposure": self.exposure, "sky": self.sky}


def _pose(doc, key, where):
    try:
        Rt = np.asarray(doc[key], dtype=np.float64)
    except KeyError:
        raise RequestError(f"{where}: no {key}") from None
    except (TypeError, ValueError):
        raise RequestError(f"{where}: {key} is not numeric") from None
    if Rt.shape != (4, 3) or not np.all(np.isfinite(Rt)):
        raise RequestError(f"{where}: {key} must be a finite (4,3) array (R on top, t last); "
                           f"got shape {Rt.shape}")
    err = float(np.max(np.abs(Rt[:3].T @ Rt[:3] - np.eye(3))))
    det = float(np.linalg.det(Rt[:3]))
    if err > 1e-9 or det < 0:
        raise RequestError(f"{where}: {key}'s first 3 rows are not a rotation "
                           f"(|R'R - I| = {err:.3g}, det {det:.3g})")
    return Rt


def _side_array(base, spec, what, where):
    if not isinstance(spec, dict) or not isinstance(spec.get("file"), str):
        raise RequestError(f"{where}: {what} must be {{\"file\": ..., \"shape\": [...]}}; "
                           f"got {spec!r}")
    path = os.path.join(base, spec["file"])
    try:
        a = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as e:
        raise RequestError(f"{where}: cannot read the {what} '{path}': {e}") from None
    if a.dtype.kind != "f" or a.ndim != 2:
        raise RequestError(f"{where}: the {what} '{path}' is {a.dtype} of shape {a.shape}; "
                           "expected a 2-D float array")
    if spec.get("shape") is not None and list(a.shape) != list(spec["shape"]):
        raise RequestError(f"{where}: the {what} '{path}' has shape {list(a.shape)}; "
                           f"scene.json says {spec['shape']}")
    return a


def read_terrain_scene(base, scene, where):
    r'''scene.json of kind "terrain" (and its side files) -> TerrainScene, or RequestError'''
    from targets.terrain import TerrainError

    missing = [k for k in ("heights", "cell", "origin", "albedo", "sun", "ambient",
                           "Rt_cam_terrain", "Rt_ref_terrain") if k not in scene]
    if missing:
        raise RequestError(f"{where}: a terrain scene needs {', '.join(missing)}")
    heights = _side_array(base, scene["heights"], "height field", where)
    albedo = _side_array(base, scene["albedo"], "albedo texture", where)
    sun = scene["sun"]
    try:
        az, el = float(sun["azimuth_deg"]), float(sun["elevation_deg"])
        cell = float(scene["cell"])
        origin = tuple(float(v) for v in scene["origin"])
        ambient = float(scene["ambient"])
    except (KeyError, TypeError, ValueError) as e:
        raise RequestError(f"{where}: terrain cell, origin, ambient or sun "
                           f"(azimuth_deg, elevation_deg) unreadable: {e!r}") from None
    if len(origin) != 2:
        raise RequestError(f"{where}: terrain origin must be [x0, y0]; got {scene['origin']!r}")
    try:
        light = terrain_lighting({k: scene[k] for k in TERRAIN_LIGHTING if k in scene})
    except RendererError as e:
        raise RequestError(f"{where}: {e}") from None
    ts = TerrainScene(heights=heights.astype(np.float64), cell=cell, origin=origin,
                      albedo=albedo.astype(np.float32), sun_direction=np.zeros(3),
                      sun_azimuth_deg=az, sun_elevation_deg=el, ambient=ambient, **light,
                      Rt_cam_terrain=_pose(scene, "Rt_cam_terrain", where),
                      Rt_ref_terrain=_pose(scene, "Rt_ref_terrain", where),
                      description=str(scene.get("description", "")))
    try:
        # targets.terrain checks the grid, the texture, the sun and the ambient level
        t = ts.to_terrain()
    except TerrainError as e:
        raise RequestError(f"{where}: not a usable terrain: {e}") from None
    d = t.sun.direction()
    given = sun.get("direction")
    if given is not None and (np.shape(given) != (3,) or
                              not np.allclose(np.asarray(given, np.float64), d, atol=1e-9)):
        raise RequestError(f"{where}: sun direction {given!r} disagrees with azimuth {az:g} "
                           f"deg, elevation {el:g} deg ({d.tolist()})")
    return dataclasses.replace(ts, heights=t.heights, albedo=t.albedo, sun_direction=d)


FRAMES = ("board frame: the board in z = 0, seen from z < 0; p_cam = R p_board + t with "
          "Rt_cam_board = [R; t]; camera frame: x = H', y = A x H', z = A, origin C; "
          "p_ref = R p_cam + t with Rt_ref_cam")


# --- writing and reading requests ----------------------------------------------------------
def write_request(directory, model, scene, Rt_cam_board, settings, output_format="png16",
                  mode="image", extra=None):
    r'''Write a render request into `directory`; returns the path of request.json

mode: "image" | "pinhole" | "rays"; extra: more request.json entries (the
pinhole of a pinhole request, the rays of a rays request).

scene: a targets.pattern.Pattern (a board; Rt_cam_board as named) or a
targets.terrain.Terrain (then Rt_cam_board is Rt_ref_terrain, the terrain in
the model's frame as in renderers.base's terrain protocol, None: identity;
settings.options shadows, exposure, sky are its lighting and go into
scene.json). A terrain request is version 3 and names the optional outputs
range.npy and shadow.npy ("outputs"); extra {"shadow_required": True} makes
the shadow codes required.
'''
    from reference_models.jpl_files import write_model

    if output_format not in OUTPUT_FORMATS:
        raise RendererError(f"command renderer: output format {output_format!r} is unknown; "
                            f"known: {', '.join(OUTPUT_FORMATS)}")
    if mode not in MODES:
        raise RendererError(f"command renderer: request mode {mode!r} is unknown; "
                            f"known: {', '.join(MODES)}")
    if Rt_cam_board is None and is_terrain(scene):
        Rt_cam_board = np.vstack((np.eye(3), np.zeros(3)))
    Rt = np.asarray(Rt_cam_board, dtype=np.float64)
    if Rt.shape != (4, 3) or not np.all(np.isfinite(Rt)):
        what = "Rt_ref_terrain" if is_terrain(scene) else "Rt_cam_board"
        raise RendererError(f"{what} must be a finite (4,3) array; got shape {Rt.shape}")
    os.makedirs(directory, exist_ok=True)
    camera_file = "camera." + model.family.lower()
    write_model(model, os.path.join(directory, camera_file), overwrite=True,
                note="camval render request: the camera to render through")
    if is_terrain(scene):
        kind = "terrain"
        scene_doc, outputs = write_terrain_scene(directory, model, scene, Rt, settings, extra)
    else:
        kind = "board"
        scene_doc = dict(kind="board", pattern=pattern_to_dict(pattern_of(scene)),
                         Rt_cam_board=Rt.tolist(), Rt_ref_cam=model.Rt_ref_cam().tolist(),
                         frames=FRAMES)
        outputs = None
    with open(os.path.join(directory, "scene.json"), "w") as f:
        json.dump(scene_doc, f, indent=1, allow_nan=False)
    width, height = model.width, model.height
    if mode == "pinhole":
        width, height = extra["pinhole"]["width"], extra["pinhole"]["height"]
    output = OUTPUT_FORMATS[output_format] if mode != "rays" else "values.npy"
    options = settings.options
    if kind == "terrain":      # the lighting options went into scene.json
        options = {k: v for k, v in options.items() if k not in TERRAIN_LIGHTING}
    extra = {k: v for k, v in (extra or {}).items() if k != "shadow_required"}
    request = dict(protocol=PROTOCOL, version=SCENE_VERSIONS[kind], camval=camval_identity(),
                   mode=mode, camera_file=camera_file, scene_file="scene.json",
                   scene_kind=kind, width=width, height=height, spp=settings.spp,
                   adaptive=settings.adaptive, options=options, output=output,
                   output_format=output_format if mode != "rays" else "npy",
                   pixel_convention=PIXEL_CONVENTION, **extra)
    if outputs:
        request["outputs"] = outputs
    path = os.path.join(directory, "request.json")
    with open(path, "w") as f:
        json.dump(request, f, indent=1, allow_nan=False)
    return path


@dataclass(frozen=True, eq=False)
class Request:
    r'''A request as read by read_request

model:         the camera model (reference_models: CAHV, CAHVOR, CAHVORE)
scene_kind:    "board" | "terrain"
pattern:       targets.pattern.Pattern (the board); None for terrain
Rt_cam_board:  (4,3) the board in the model's camera frame; None for terrain
terrain:       TerrainScene (heights, cell, origin, albedo, sun, lighting, poses) or None
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
    scene_kind: str = "board"
    terrain: TerrainScene = None

    def output_path(self, name):
        r'''Terrain requests: the path of the optional output "range" or "shadow" (None
when the request names none)'''
        o = (self.raw.get("outputs") or {}).get(name)
        return os.path.join(self.directory, o["file"]) if o else None

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
    kind = scene.get("kind")
    if kind not in SCENE_VERSIONS:
        raise RequestError(f"'{path}': scene kind {kind!r} is not supported; expected one of "
                           f"{', '.join(SCENE_VERSIONS)}")
    if raw["version"] < SCENE_VERSIONS[kind]:
        raise RequestError(f"'{path}': scene kind {kind!r} needs request version "
                           f"{SCENE_VERSIONS[kind]}; the request says {raw['version']}")
    settings = RenderSettings(spp=raw["spp"], adaptive=raw["adaptive"],
                              options=raw.get("options") or {})
    common = dict(model=model, settings=settings, output=os.path.join(base, raw["output"]),
                  output_format=raw["output_format"], raw=raw, mode=raw.get("mode", "image"),
                  pinhole=raw.get("pinhole"), directory=base, scene_kind=kind)
    if kind == "terrain":
        terrain = read_terrain_scene(base, scene, f"'{os.path.join(base, raw['scene_file'])}'")
        return Request(pattern=None, Rt_cam_board=None, terrain=terrain, **common)
    return Request(pattern=pattern_from_dict(scene["pattern"]),
                   Rt_cam_board=np.asarray(scene["Rt_cam_board"], dtype=np.float64), **common)


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


def load_output(path, what):
    r'''np.load of a .npy file the program wrote (an image, values, a terrain output),
or RendererError naming what could not be read'''
    try:
        return np.load(path, allow_pickle=False)
    except (OSError, ValueError) as e:
        raise RendererError(f"cannot read the {what} '{path}': {e}") from None


def read_image(path, width, height):
    r'''Read an external renderer's output: float64 (height, width) in [0,1], or raise'''
    if not os.path.exists(path):
        raise RendererError(f"the renderer wrote no image at '{path}'")
    if path.endswith(".npy"):
        img = load_output(path, "image")
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


def read_terrain_output(path, name, size, required=False):
    r'''An optional output of a terrain request ("range" or "shadow"), checked -> a flat
array of `size` values (range float64, NaN for sky; shadow uint8 codes) or None when
the program wrote none (a RendererError if it was required)'''
    if not os.path.exists(path):
        if required:
            raise RendererError(f"the renderer wrote no {name} output at '{path}' (the "
                                "request requires it)")
        return None
    v = load_output(path, f"{name} output")
    if v.size != size:
        raise RendererError(f"'{path}' has {v.size} values; expected {size}")
    v = v.reshape(-1)
    if name == "range":
        if v.dtype.kind != "f":
            raise RendererError(f"'{path}' holds {v.dtype}; expected float ranges (NaN: sky)")
        v = v.astype(np.float64)
        if np.any(v[np.isfinite(v)] < 0) or np.any(np.isinf(v)):
            raise RendererError(f"'{path}' has negative or infinite ranges")
        return v
    if v.dtype.kind not in "iu":
        raise RendererError(f"'{path}' holds {v.dtype}; expected integer shadow codes")
    bad = ~np.isin(v, list(SHADOW_CODES.values()))
    if np.any(bad):
        raise RendererError(f"'{path}' has shadow codes {sorted(set(v[bad].tolist()))[:5]}; "
                            f"known: {SHADOW_CODES}")
    return v.astype(np.uint8)


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
        more = {}
        if isinstance(out, dict):      # terrain: {"image" or "values", "range", "shadow"}
            more = {k: out[k] for k in TERRAIN_OUTPUTS if out.get(k) is not None}
            out = out.get("values", out.get("image"))
        if out is not None:
            if req.mode == "rays":
                np.save(req.output, np.asarray(out, dtype=np.float32))
            else:
                write_image(req.output, out)
        for k, v in more.items():
            path = req.output_path(k)
            if path is None:
                raise RequestError(f"the request names no {k} output (a board request?)")
            np.save(path, np.asarray(v, dtype=np.uint8 if k == "shadow" else np.float64))
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
NotApplicable("reason") to decline a camera or scene. For a terrain request
(req.terrain) it may return a dict {"image" (or "values"), "range",
"shadow"}: range and shadow codes per pixel centre (image mode) or per ray
(rays mode) are written to the request's optional outputs.

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
