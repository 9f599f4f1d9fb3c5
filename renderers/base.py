r'''The renderer adapter interface shared by every renderer, and its registry

SYNOPSIS

    from renderers.base import get_renderer, get_terrain_renderer, RenderSettings

    r = get_renderer("raycast")
    result = r.render(model, target.pattern(), Rt_cam_board, RenderSettings(spp=16))
    # result.image has shape (height,width), float32 in [0,1]
    # result.metadata: renderer, version, settings, seconds, samples

    t = get_terrain_renderer("raycast_terrain")      # or povray_terrain, osmesa_terrain
    r = t.render_terrain(model, terrain, Rt_ref_terrain, RenderSettings(spp=2))
    # r.image (H,W) float32 in [0,1]; r.range, r.shadow (H,W) or None; r.metadata

A renderer declares the scene kinds it renders in its class attribute
`scenes` (SCENE_KINDS; a renderer without one renders boards), and has the
shape of the protocol of each kind (typing.Protocol: subclassing is
optional). `model` is a reference_models camera model.

- "board" (Renderer): the scene is a targets.pattern.Pattern; Rt_cam_board
  (4,3) places the board in the model's camera frame (model.Rt_ref_cam()), so
  board points map to the model's world frame by
  Rt_ref_board = compose(model.Rt_ref_cam(), Rt_cam_board).
- "terrain" (TerrainRenderer): the scene is a targets.terrain.Terrain;
  Rt_ref_terrain (4,3) places the terrain (z up) in the model's frame
  (targets.terrain.ground_pose; identity if None). The result is a
  TerrainRender.

Both take RenderSettings: spp = K (K x K samples per pixel) and options that
override the renderer's constructor defaults (merged_options).

The registry is a dict of lazy specs "module:Class", one for boards and
terrain alike: a backend (POV-Ray, OSMesa) is imported only when chosen.
Python packages add renderers under the entry-point group "camval.renderers".
A backend that cannot work on this machine raises RendererUnavailableError at
construction, with the fix.
'''

import dataclasses
import importlib
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

from reference_models.errors import CamvalError

ENTRY_POINT_GROUP = "camval.renderers"

# name -> "module:Class"
BUILTIN_RENDERERS = {
    "raycast": "renderers.raycast:RaycastRenderer",
    "povray": "renderers.povray:PovrayRenderer",
    "osmesa": "renderers.osmesa:OSMesaRenderer",
    "command": "renderers.command:CommandRenderer",
    "faulty": "renderers.legacy:FaultyRenderer",
    "raycast_terrain": "renderers.raycast_terrain:RaycastTerrainRenderer",
    "povray_terrain": "renderers.povray_terrain:PovrayTerrainRenderer",
    "osmesa_terrain": "renderers.osmesa_terrain:OSMesaTerrainRenderer",
}
# options a built-in renderer applies when a render's settings leave them out, where they
# change its images: harness.records.renderer_key names them in every record's fullname, so
# a record made under another default (a baseline of the ray caster's point sampling, its
# default until area coverage) never joins these records
DEFAULT_OPTIONS = {"raycast": {"coverage": "area"}}
# the scenes a renderer can declare in its class attribute `scenes`; without one: boards
SCENE_KINDS = ("board", "terrain")
DEFAULT_SCENES = ("board",)


class RendererError(CamvalError):
    '''A renderer that failed on a job (recorded as a failed result by campaigns).'''


class UnknownRendererError(CamvalError):
    pass


class RendererNotApplicable(RendererError):
    '''The renderer cannot render this camera or scene by design (a field of view no pinhole
covers, a defect that needs another model family): campaigns record "not-applicable".'''


class RendererUnavailableError(RendererError):
    '''A renderer whose backend is missing on this machine; the message says the fix.'''


@dataclass(frozen=True)
class RenderSettings:
    r'''How to render

spp:      K, the renderer samples K x K points per pixel (area-coverage anti-aliasing)
adaptive: supersample only the pixels where the scene changes (same result as full)
options:  renderer-specific settings (e.g. a camera path, legacy defects)
'''

    spp: int = 16
    adaptive: bool = True
    options: dict = field(default_factory=dict)

    def __post_init__(self):
        if isinstance(self.spp, bool) or not isinstance(self.spp, int) or self.spp < 1:
            raise CamvalError(f"supersampling K must be a positive integer; got {self.spp!r}")

    def as_dict(self):
        return dataclasses.asdict(self)


@dataclass(frozen=True, eq=False)
class RenderResult:
    image: Any  # np.ndarray float32 (height, width) in [0,1]
    metadata: dict


@dataclass(frozen=True, eq=False)
class TerrainRender:
    r'''What a terrain renderer returns

image:    (H,W) float32 in [0,1]
range:    (H,W) float64, metres along the pixel-centre ray from its origin, NaN for
          sky; None when the renderer gives none
shadow:   (H,W) uint8: 0 lit, 1 self-shadowed (facing away from the sun), 2 cast
          shadow, 255 sky; None when the renderer gives none
metadata: renderer, version, settings, timings (JSON-able)
'''

    image: Any
    range: Any
    shadow: Any
    metadata: dict


@runtime_checkable
class Renderer(Protocol):
    r'''A renderer of boards (scene kind "board")'''
    name: str

    def version(self) -> str: ...

    def render(self, model, scene, Rt_cam_board, settings: RenderSettings) -> RenderResult: ...


@runtime_checkable
class TerrainRenderer(Protocol):
    r'''A renderer of terrain scenes (scenes = ("terrain",))'''
    name: str
    scenes: tuple

    def version(self) -> str: ...

    def render_terrain(self, model, terrain, Rt_ref_terrain,
                       settings: RenderSettings) -> TerrainRender: ...


def _entry_point_renderers():
    from importlib.metadata import entry_points
    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def known_renderers():
    r'''{name: source} of every renderer: built-in ones and entry-point plugins'''
    out = {name: f"built-in ({spec})" for name, spec in BUILTIN_RENDERERS.items()}
    for name, ep in _entry_point_renderers().items():
        out.setdefault(name, f"plugin ({ep.value}, package {ep.dist.name if ep.dist else '?'})")
    return out


def renderer_class(name):
    if name in BUILTIN_RENDERERS:
        modname, clsname = BUILTIN_RENDERERS[name].split(":")
        try:
            mod = importlib.import_module(modname)
        except ModuleNotFoundError as e:
            if e.name == modname:
                raise RendererUnavailableError(
                    f"renderer {name!r} is not implemented in this version of camval") from None
            raise
        return getattr(mod, clsname)
    plugins = _entry_point_renderers()
    if name in plugins:
        return plugins[name].load()
    raise UnknownRendererError(
        f"unknown renderer {name!r}; known renderers: {', '.join(sorted(known_renderers()))}")


def get_renderer(name, **options):
    r'''Construct the renderer called `name` (raises RendererUnavailableError with the fix
when its backend is missing here)'''
    return renderer_class(name)(**options)


def renderer_scenes(name):
    r'''The scene kinds (SCENE_KINDS) the renderer called `name` renders'''
    return tuple(getattr(renderer_class(name), "scenes", DEFAULT_SCENES))


def get_terrain_renderer(name, **options):
    r'''Construct the renderer called `name` for terrain scenes

A renderer that does not render terrain is a RendererError naming the ones
that do (as get_renderer otherwise).
'''
    if "terrain" not in renderer_scenes(name):
        terrain = [n for n in sorted(known_renderers()) if _renders(n, "terrain")]
        raise RendererError(f"renderer {name!r} does not render terrain scenes; terrain "
                            f"renderers: {', '.join(terrain)}")
    return get_renderer(name, **options)


def _renders(name, scene):
    try:
        return scene in renderer_scenes(name)
    except Exception:   # a broken or unavailable backend must not hide the others
        return False


def merged_options(renderer_name, defaults, settings):
    r'''A renderer's default options updated with settings.options

An option the renderer does not know is a RendererError naming the known ones.
'''
    unknown = set(settings.options) - set(defaults)
    if unknown:
        raise RendererError(f"{renderer_name}: unknown option(s) {', '.join(sorted(unknown))}; "
                            f"known: {', '.join(sorted(defaults))}")
    return {**defaults, **settings.options}
