r'''Campaign files: which cameras, models, targets, renderers and calibrators to run

SYNOPSIS

    from harness.campaign import load_campaign

    c = load_campaign("campaigns/quick.toml")
    c.cameras        # ("15", "17", "5"): slot ids, extras' names, model-file paths
    c.models         # ("CAHV", "CAHVOR", "CAHVORE")
    c.renderers[0].settings()   # [{"spp": 16, "adaptive": True, "options": {}}]
    c.responses                 # (ResponseSpec("clean", {}), ...): camera-response profiles
    c.validate()     # names checked against the catalogue and the registries

A campaign is a TOML file (tomllib):

    name = "quick"
    description = "a few cameras, for tests and CI"
    cameras = [15, 17, 5, "supercam", "my/own.cahvor"]  # relative paths: from this file
    models = ["CAHV", "CAHVOR", "CAHVORE"]   # each derived from the camera by truncation
    targets = ["dots"]
    keep_images = false      # keep the rendered images (images/ in the run dir)
    keep_maps = true         # keep downsampled projection-difference maps (maps/)
    share_identical_cameras = true   # render once the cameras that are one camera
                                     # (harness.jobs.group_twins)
    catalogue = "overlay.toml"   # optional catalogue overlay (user models in slots)
    verdict_modes = ["rotation"]   # the projection-difference modes of each record's
                                   # verdict.floor and verdict.renderer (VERDICT_MODES)

    seed = 0                 # the campaign's noise seed (camera-response stages)

    [target_models]          # optional: the model families a target renders under
    apriltag = ["own"]       # (default: every one of models); "own" = the camera's own
                             # catalogue family, so each camera is seen once by that target

    [poses]
    n = 6
    seed = 0
    cover = "corners"        # poses beyond the first six: "corners" (reach the image
                             # corners and edges) or "paper" (cycle the six templates)

    [[renderer]]
    name = "raycast"
    spp = [4, 16]            # an int or a list: one job per value
    adaptive = true          # a bool or a list
    options = {}             # renderer-specific settings (they name the records)
    label = "mine"           # optional: the renderer's part of the records' fullnames
                             # (default: name), mine[spp=4,adaptive]/...
    setup = {}               # optional: how to run the renderer, not what it renders
                             # (the command renderer's command, timeout, env, ...):
                             # recorded in each record's settings, never in its fullname
    response = ["clean", "realistic"]   # optional: the [response.*] profiles to run
                                        # (default: every profile, in file order)

    [[calibrator]]
    name = "jpl"
    models = ["family"]      # "family" = the job's model family; "best" = per camera the
                             # simplest model within options.best_tolerance px (0.01) of
                             # the truth (harness.model_benchmark); or named models
    options = {}
    poses = 30               # optional: its own pose count (default: [poses] n); the job
                             # renders the most any calibrator asks for, and each
                             # calibrator fits the first N (the first six are the paper's)
    targets = ["dots"]       # optional: the campaign's targets it fits (default: all);
                             # every target needs at least one calibrator

    [response.clean]         # a profile with no stages: the rendered image as it is

    [response.realistic]     # camera response applied after rendering, before detection
    full_well_e = 20000      # electrons at image value 1.0
    seed = 0                 # optional: the profile's own noise seed
    psf = {kind = "gaussian", sigma_px = 0.7}
    shot_noise = {}
    read_noise = {sigma_e = 12.0}
    quantise = {bits = 12}

A job is camera x model family x target x renderer setting x response
profile; every calibrator runs on each job's detections. A family richer than
the camera (CAHVORE from a CAHVOR camera) is recorded as not-applicable, not
an error. Every mistake in the file (unknown key, missing camera, unknown
renderer, unknown response stage or parameter) is a CamvalError of one line
naming the key and the choices.

Camera response. Each [response.NAME] table is one profile: the stages of
renderers/response.py (vignetting, psf, motion_blur, global_gain, shot_noise,
dark_current, hot_pixels, dead_pixels, saturation, read_noise, quantise), each
a table of its parameters ({} for the defaults), plus full_well_e and seed.
Every stage is off unless named; the stages run in their physical order
whatever the order in the file. Without a [response] table every job renders
clean, as before. A profile with no stages is the clean render and leaves the
fullname unchanged; any other profile adds ",response=NAME" to the renderer
settings of the fullname (15/CAHVOR/dots/raycast[spp=16,adaptive,coverage=area,
response=realistic]/jpl[CAHVOR]), so the same camera with and without noise
are distinct records. The noise of image i of a job is drawn from
numpy.random.default_rng([seed, profile seed, sha256(job key) as four 32-bit
words, i]): reproducible bit for bit, and different for every job.
'''

import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from reference_models.cahvore import FAMILIES
from reference_models.errors import CamvalError

from .compare import PROJECTION_MODES

JOB_FAMILY = "family"
# [target_models]: the camera's own catalogue family
OWN_FAMILY = "own"

# [poses] cover: how the poses beyond the first six are planned
# (targets.poses.plan_poses): "corners" reaches the image's corners and edges, which a
# calibrator given more poses than the campaign's n (calibrator poses = N) needs for a
# rich model; the first six, the paper's, are the same either way
POSES_COVER = "corners"
POSES_COVERS = ("paper", "corners")

# verdict_modes: the projection-difference modes (harness.compare.PROJECTION_MODES) that
# the verdict's floor and renderer comparisons compute (harness.verdict.assess); the
# record's own projection (the total) always has every mode. By default only "rotation",
# the headline the gate, the report and the sigma read: nothing in camval reads the floor's
# and renderer's "intrinsics" and "world", which cost ~7% of the verdict's CPU
# (benchmarks/bench_verdict.py on 52 captured paper records: 1.26-1.29 s with them,
# 1.18-1.19 s without, load 12-15; issue 14: the verdict's extra work within 10% of a
# campaign). A run written before the key existed
# computed all three (Campaign.from_dict).
VERDICT_MODES = ("rotation",)

TOP_KEYS = ("name", "description", "cameras", "models", "targets", "target_models",
            "keep_images", "keep_maps", "verdict_modes",
            "share_identical_cameras", "catalogue", "seed", "poses", "renderer", "calibrator",
            "response")
POSE_KEYS = ("n", "seed", "cover")
RENDERER_KEYS = ("name", "spp", "adaptive", "options", "response", "label", "setup")
LABEL = re.compile(r"^[A-Za-z0-9_.-]+$")
PROFILE_NAME = re.compile(r"^[A-Za-z0-9_-]+$")
CALIBRATOR_KEYS = ("name", "models", "options", "poses", "targets")


class CampaignError(CamvalError):
    '''A campaign file that is malformed or names things that do not exist.'''


def _where(source, key):
    return f"{source}: {key}" if source else key


def _unknown(source, section, d, known):
    for k in d:
        if k not in known:
            raise CampaignError(f"{_where(source, section + k)}: unknown key; known keys: "
                                f"{', '.join(known)}")


def _list_of(source, key, value, types, what):
    if isinstance(value, types) and not isinstance(value, list):
        value = [value]
    if not isinstance(value, list) or not value:
        raise CampaignError(f"{_where(source, key)}: expected a non-empty list of {what}; "
                            f"got {value!r}")
    for v in value:
        if isinstance(v, bool) and bool not in types or not isinstance(v, types):
            raise CampaignError(f"{_where(source, key)}: expected {what}; got {v!r}")
    if len(set(map(repr, value))) != len(value):
        raise CampaignError(f"{_where(source, key)}: repeated entries in {value!r}")
    return value


def _bool(source, key, value):
    if not isinstance(value, bool):
        raise CampaignError(f"{_where(source, key)}: expected true or false; got {value!r}")
    return value


def _int(source, key, value, minimum):
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise CampaignError(f"{_where(source, key)}: expected an integer >= {minimum}; "
                            f"got {value!r}")
    return value


@dataclass(frozen=True)
class ResponseSpec:
    r'''A camera-response profile: a name and its renderers.response configuration

config: {"full_well_e": ..., "seed": ..., stage name: {parameter: value}} as in
the campaign file (checked by renderers.response.ResponseChain.from_config).
A profile without stages is the clean render.
'''
    name: str
    config: dict = field(default_factory=dict)

    def stages(self):
        from renderers.response import STAGES
        return [k for k in self.config if k in STAGES]

    @property
    def clean(self):
        return not self.stages()

    def label(self):
        r'''The profile's part of the renderer settings: None for a clean profile'''
        return None if self.clean else self.name

    def as_dict(self):
        return {"name": self.name, "config": _plain(self.config)}


def _plain(x):
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    return x


@dataclass(frozen=True)
class RendererSpec:
    name: str
    spp: tuple = (16,)
    adaptive: tuple = (True,)
    options: dict = field(default_factory=dict)
    response: tuple = None     # profile names to run (None: every profile of the campaign)
    label: str = None          # names the records (None: the renderer's name)
    setup: dict = field(default_factory=dict)   # recorded, never in a fullname

    def settings(self, responses=()):
        r'''[{"spp", "adaptive", "options"[, "response"]}, ...]: one per job, in file order

responses: the campaign's ResponseSpecs; the settings of a job with a
profile that has stages carry "response": its name.
'''
        chosen = [r for r in responses if self.response is None or r.name in self.response]
        if self.response is not None:
            chosen.sort(key=lambda r: self.response.index(r.name))
        out = []
        for k in self.spp:
            for a in self.adaptive:
                for prof in chosen or [None]:
                    s = {"spp": k, "adaptive": a, "options": dict(self.options)}
                    if self.label is not None:
                        s["label"] = self.label
                    if self.setup:
                        s["setup"] = _plain(self.setup)
                    if prof is not None and prof.label() is not None:
                        s["response"] = prof.label()
                    out.append(s)
        return out

    def profiles(self, responses=()):
        r'''The ResponseSpecs of settings(responses), in the same order (None: no response)'''
        chosen = [r for r in responses if self.response is None or r.name in self.response]
        if self.response is not None:
            chosen.sort(key=lambda r: self.response.index(r.name))
        return [p for _ in self.spp for _ in self.adaptive for p in (chosen or [None])]

    def as_dict(self):
        d = {"name": self.name, "spp": list(self.spp), "adaptive": list(self.adaptive),
             "options": dict(self.options)}
        if self.response is not None:
            d["response"] = list(self.response)
        if self.label is not None:
            d["label"] = self.label
        if self.setup:
            d["setup"] = _plain(self.setup)
        return d


@dataclass(frozen=True)
class CalibratorSpec:
    name: str
    models: tuple = (JOB_FAMILY,)
    options: dict = field(default_factory=dict)
    poses: int = None      # its own pose count (None: the campaign's [poses] n)
    targets: tuple = None  # the campaign's targets it fits (None: all)

    def fits(self, target):
        r'''Whether the calibrator runs on the jobs of this target'''
        return self.targets is None or target in self.targets

    def models_for(self, family):
        r'''The calibrator's models for a job of this family ("family" -> the family;
"best" stays: models_and_options() resolves it per camera)'''
        return [family if m == JOB_FAMILY else m for m in self.models]

    def models_and_options(self, family, camera_model=None):
        r'''[(model, options)] for a job of this family on this camera

SYNOPSIS

    spec.models_and_options("CAHVORE", entry.model)
    # [("SPLINED", {..., "model_choice": "simplest mrcal model with max floor ..."})]

"best" becomes the calibrator's simplest model whose floor on the job's truth (the camera
truncated to the family) is within the option best_tolerance px (default 0.01; see
harness.model_benchmark); options[MODEL_CHOICE] says which and why (the record keeps it
in info; the calibrator never sees it). A family richer than the camera, or no camera
given: the family.
'''
        out = []
        base = {k: v for k, v in self.options.items() if k != BEST_TOLERANCE}
        for m in self.models_for(family):
            if m != BEST:
                out.append((m, dict(base)))
                continue
            name, why = _best_model(self.name, family, camera_model,
                                    self.options.get(BEST_TOLERANCE))
            out.append((name, dict(base, **{MODEL_CHOICE: why})))
        return out

    def as_dict(self):
        d = {"name": self.name, "models": list(self.models), "options": dict(self.options)}
        if self.poses is not None:
            d["poses"] = self.poses
        if self.targets is not None:
            d["targets"] = list(self.targets)
        return d


@dataclass(frozen=True)
class Campaign:
    name: str
    cameras: tuple
    models: tuple = FAMILIES
    targets: tuple = ("dots",)
    renderers: tuple = (RendererSpec("raycast"),)
    calibrators: tuple = (CalibratorSpec("jpl"),)
    poses_n: int = 6
    poses_seed: int = 0
    poses_cover: str = POSES_COVER
    keep_images: bool = False
    keep_maps: bool = True
    catalogue: str = None
    description: str = ""
    source: str = ""
    seed: int = 0
    responses: tuple = ()
    share_identical_cameras: bool = True
    target_models: tuple = ()     # ((target, (family or OWN_FAMILY, ...)), ...)
    verdict_modes: tuple = VERDICT_MODES

    def renders(self, target, family, own_family):
        r'''Whether the target is rendered under this model family ([target_models])'''
        for t, fams in self.target_models:
            if t == target:
                return family in fams or (OWN_FAMILY in fams and family == own_family)
        return True

    def response(self, name):
        r'''The ResponseSpec called name (KeyError if there is none)'''
        for r in self.responses:
            if r.name == name:
                return r
        raise KeyError(name)

    def as_dict(self):
        r'''The campaign as plain JSON (what a run stores, and what resume re-reads)'''
        return {"name": self.name, "description": self.description, "source": self.source,
                "cameras": list(self.cameras), "models": list(self.models),
                "targets": list(self.targets),
                "renderers": [r.as_dict() for r in self.renderers],
                "calibrators": [c.as_dict() for c in self.calibrators],
                "poses": dict({"n": self.poses_n, "seed": self.poses_seed},
                              **({} if self.poses_cover == POSES_COVER
                                 else {"cover": self.poses_cover})),
                "keep_images": self.keep_images, "keep_maps": self.keep_maps,
                "catalogue": self.catalogue, "seed": self.seed,
                "response": [r.as_dict() for r in self.responses],
                "share_identical_cameras": self.share_identical_cameras,
                "verdict_modes": list(self.verdict_modes),
                **({"target_models": {t: list(f) for t, f in self.target_models}}
                   if self.target_models else {})}

    @classmethod
    def from_dict(cls, d):
        return cls(name=d["name"], description=d.get("description", ""),
                   source=d.get("source", ""),
                   cameras=tuple(d["cameras"]), models=tuple(d["models"]),
                   targets=tuple(d["targets"]),
                   renderers=tuple(RendererSpec(r["name"], tuple(r["spp"]),
                                                tuple(r["adaptive"]), dict(r["options"]),
                                                tuple(r["response"]) if "response" in r
                                                else None, r.get("label"),
                                                dict(r.get("setup") or {}))
                                   for r in d["renderers"]),
                   calibrators=tuple(CalibratorSpec(c["name"], tuple(c["models"]),
                                                    dict(c["options"]), c.get("poses"),
                                                    tuple(c["targets"]) if "targets" in c
                                                    else None)
                                     for c in d["calibrators"]),
                   poses_n=d["poses"]["n"], poses_seed=d["poses"]["seed"],
                   poses_cover=d["poses"].get("cover", POSES_COVER),
                   keep_images=d["keep_images"], keep_maps=d["keep_maps"],
                   catalogue=d.get("catalogue"), seed=d.get("seed", 0),
                   responses=tuple(ResponseSpec(r["name"], r["config"])
                                   for r in d.get("response", ())),
                   share_identical_cameras=d.get("share_identical_cameras", True),
                   target_models=tuple((t, tuple(f)) for t, f
                                       in (d.get("target_models") or {}).items()),
                   # a run written before verdict_modes computed every mode
                   verdict_modes=tuple(d.get("verdict_modes", PROJECTION_MODES)))

    def replace(self, **kw):
        import dataclasses
        return dataclasses.replace(self, **kw)

    def load_catalogue(self):
        from reference_models.catalogue import load_catalogue
        return load_catalogue(overlay=self.catalogue) if self.catalogue else load_catalogue()

    def validate(self, catalogue=None):
        r'''Check every name against the catalogue and the registries (CampaignError if not)

Returns {camera spec: CatalogueEntry}.
'''
        src = self.source
        if catalogue is None:
            catalogue = self.load_catalogue()
        entries = {}
        for i, spec in enumerate(self.cameras):
            try:
                entries[spec] = catalogue.get(spec)
            except CamvalError as e:
                raise CampaignError(f"{_where(src, f'cameras[{i}]')}: {e}") from None
        from renderers.base import known_renderers, renderer_scenes
        known = known_renderers()
        for i, r in enumerate(self.renderers):
            if r.name not in known:
                raise CampaignError(f"{_where(src, f'renderer[{i}].name')}: unknown renderer "
                                    f"{r.name!r}; known renderers: {', '.join(sorted(known))}")
            try:
                scenes = renderer_scenes(r.name)
            except Exception:   # an unavailable backend fails in its own records
                scenes = ("board",)
            if "board" not in scenes:
                raise CampaignError(f"{_where(src, f'renderer[{i}].name')}: renderer {r.name!r} "
                                    f"renders {', '.join(scenes)} scenes, not the boards of a "
                                    f"campaign")
            _check_setup_not_in_options(src, i, r)
        from harness.calibrators import CalibratorError, calibrator_module, known_calibrators
        cal_known = known_calibrators()
        for i, c in enumerate(self.calibrators):
            if c.name not in cal_known:
                raise CampaignError(f"{_where(src, f'calibrator[{i}].name')}: unknown "
                                    f"calibrator {c.name!r}; known calibrators: "
                                    f"{', '.join(sorted(cal_known))}")
            try:
                cal = calibrator_module(c.name)
            except ImportError:
                # not installed here: its models are not checked; running it gives failed
                # records with the reason
                continue
            except CalibratorError as e:   # a plugin that is not a calibrator
                raise CampaignError(f"{_where(src, f'calibrator[{i}].name')}: {e}") from None
            for m in c.models:
                if m not in (JOB_FAMILY, BEST) and not _calibrator_has_model(cal, m):
                    raise CampaignError(f"{_where(src, f'calibrator[{i}].models')}: calibrator "
                                        f"{c.name!r} has no model {m!r}; its models: "
                                        f"{', '.join((JOB_FAMILY,) + tuple(cal.MODELS))} "
                                        f"(or {BEST})")
        return entries


def _check_setup_not_in_options(src, i, spec):
    r"""A renderer's setup (its class's SETUP_KEYS: how to run it) given among its options
would name the records: a CampaignError that says to move it to setup"""
    from renderers.base import RendererError, renderer_class
    try:
        keys = tuple(getattr(renderer_class(spec.name), "SETUP_KEYS", ()))
    except (ImportError, RendererError):
        return
    unknown = sorted(set(spec.setup) - set(keys))
    if unknown:
        raise CampaignError(f"{_where(src, f'renderer[{i}].setup')}: {', '.join(unknown)} "
                            f"unknown to {spec.name!r}; its setup: "
                            f"{', '.join(keys) or '(none)'}")
    misplaced = sorted(set(spec.options) & set(keys))
    if misplaced:
        raise CampaignError(f"{_where(src, f'renderer[{i}].options')}: "
                            f"{', '.join(misplaced)} say how to run {spec.name!r}, not what "
                            f"it renders; move them to setup = {{ ... }} (options name the "
                            f"records, setup does not)")


# "best": per camera, the calibrator's simplest model within tolerance (harness.model_benchmark)
BEST = "best"
BEST_TOLERANCE = "best_tolerance"
MODEL_CHOICE = "model_choice"
# a calibrator's own pose count (CalibratorSpec.poses), among the options of a job's
# calibrator (harness.jobs.expand_jobs); the record keeps it in info["poses"], the
# calibrator never sees it
POSE_COUNT = "pose_count"


def _best_model(calibrator, family, camera_model, tolerance):
    from reference_models.cahvore import truncate
    from reference_models.errors import ModelError
    if camera_model is None:
        return family, f"no camera to benchmark: the job's family {family}"
    try:
        truth = truncate(camera_model, family)
    except ModelError:
        return family, f"the camera has no {family}: the job's family"
    from harness.model_benchmark import DEFAULT_TOLERANCE, best_model
    name, why = best_model(truth, calibrator,
                           DEFAULT_TOLERANCE if tolerance is None else float(tolerance))
    if name is None:
        return family, f"{why}: the job's family {family}"
    return name, why


def resolve_best(campaign, entries, progress=None):
    r'''Choose every "best" model of the campaign now, one camera, family and calibrator
at a time, with progress (harness.progress.Progress): harness.jobs.expand_jobs then finds
them chosen (harness.model_benchmark.best_model keeps its choices per process and on
disk, keyed on the camera's parameters). Returns [(camera, family, calibrator, model,
why, seconds)].

A benchmark takes 0.2-15 s per camera and family on a loaded 2-core machine (the mrcal
splined model is the slow one); a choice kept on disk takes milliseconds.
'''
    import time

    from harness.model_benchmark import cached_choice
    todo = [(spec, family, c) for spec in campaign.cameras for family in campaign.models
            for c in campaign.calibrators if BEST in c.models]
    if not todo:
        return []
    if progress is not None:
        progress.stage("best models", total=len(todo))
    out = []
    for spec, family, c in todo:
        tol = c.options.get(BEST_TOLERANCE)
        what = f"camera {spec} {family} {c.name}"
        t0 = time.perf_counter()
        if progress is not None:
            progress.note(f"{what}: model benchmark")
        cached = cached_choice(entries[spec].model, family, c.name, tol)
        name, why = _best_model(c.name, family, entries[spec].model, tol)
        dt = time.perf_counter() - t0
        out.append((spec, family, c.name, name, why, dt))
        if progress is not None:
            progress.advance(f"{what}: {name} ({'kept from an earlier run, ' if cached else ''}"
                             f"{dt:.1f} s)")
    return out


def _calibrator_has_model(cal, model):
    canonical = cal.canonical_model(model) if hasattr(cal, "canonical_model") else model
    return canonical in tuple(cal.MODELS)


def parse_responses(source, doc):
    r'''The [response.NAME] tables of a campaign -> (ResponseSpec, ...) in file order

Checks the profile names, the stage names and each stage's parameter names
here (so the messages name the campaign key) and the values through
renderers.response.ResponseChain.from_config.
'''
    from renderers.response import GLOBAL_KEYS, STAGE_ORDER, STAGES, ResponseChain

    if doc is None:
        return ()
    if not isinstance(doc, dict):
        raise CampaignError(f"{_where(source, 'response')}: expected tables "
                            f"[response.NAME], one per camera-response profile")
    known = tuple(GLOBAL_KEYS) + tuple(c.name for c, _ in STAGE_ORDER)
    out = []
    for name, cfg in doc.items():
        key = f"response.{name}"
        if not isinstance(cfg, dict):
            raise CampaignError(f"{_where(source, key)}: expected a table [response.{name}] "
                                f"of response stages; got {cfg!r}")
        if name in known:
            raise CampaignError(f"{_where(source, key)}: a profile named like a response "
                                f"setting; put the stages in a profile table "
                                f"[response.NAME], e.g. [response.noisy]")
        if not PROFILE_NAME.match(name):
            raise CampaignError(f"{_where(source, key)}: a profile name may hold only "
                                f"letters, digits, '_' and '-'")
        _unknown(source, key + ".", cfg, known)
        for stage, params in cfg.items():
            if stage in GLOBAL_KEYS:
                continue
            if not isinstance(params, dict):
                raise CampaignError(f"{_where(source, key + '.' + stage)}: expected a table "
                                    f"of the stage's parameters ({{}} for its defaults); "
                                    f"got {params!r}")
            _unknown(source, f"{key}.{stage}.", params, tuple(STAGES[stage].params))
        if "seed" in cfg:
            _int(source, key + ".seed", cfg["seed"], 0)
        try:
            ResponseChain.from_config(cfg)
        except CamvalError as e:
            raise CampaignError(f"{_where(source, key)}: {e}") from None
        out.append(ResponseSpec(name, _plain(cfg)))
    clean = [r.name for r in out if r.clean]
    if len(clean) > 1:
        raise CampaignError(f"{_where(source, 'response')}: profiles {clean[0]!r} and "
                            f"{clean[1]!r} both have no stages (the clean render); keep one")
    return tuple(out)


def parse_campaign(doc, source="", base_dir=None):
    r'''Validate the structure of a parsed campaign TOML (dict) -> Campaign

Names are checked by Campaign.validate(); this checks keys and types.
Relative model-file paths among the cameras are taken from base_dir.
'''
    if not isinstance(doc, dict):
        raise CampaignError(f"{source or 'campaign'}: expected a TOML table")
    _unknown(source, "", doc, TOP_KEYS)
    if "cameras" not in doc:
        raise CampaignError(f"{_where(source, 'cameras')}: missing; expected a list of slot "
                            f"ids, extras' names or model files")
    cams = _list_of(source, "cameras", doc["cameras"], (int, str), "slot ids (int) or names")
    cameras = []
    for c in cams:
        if isinstance(c, bool):
            raise CampaignError(f"{_where(source, 'cameras')}: expected a slot id or a name; "
                                f"got {c!r}")
        c = str(c)
        if base_dir is not None and ("/" in c or "." in c) and not Path(c).is_absolute():
            p = Path(base_dir) / c
            if p.exists():
                c = str(p)
        cameras.append(c)
    models = tuple(_list_of(source, "models", doc.get("models", list(FAMILIES)), (str,),
                            "model families"))
    for m in models:
        if m not in FAMILIES:
            raise CampaignError(f"{_where(source, 'models')}: unknown model family {m!r}; "
                                f"known: {', '.join(FAMILIES)}")
    targets = tuple(_list_of(source, "targets", doc.get("targets", ["dots"]), (str,),
                             "target names"))
    from targets.boards import known_targets
    known = known_targets()
    for t in targets:
        if t not in known and not Path(t).suffix == ".toml":
            raise CampaignError(f"{_where(source, 'targets')}: unknown target {t!r}; known: "
                                f"{', '.join(known)} or a target .toml file (its key "
                                f"detector names any registered detector, plug-ins too)")
    target_models = _target_models(source, doc.get("target_models", {}), targets)
    poses = doc.get("poses", {})
    if not isinstance(poses, dict):
        raise CampaignError(f"{_where(source, 'poses')}: expected a table with n and seed")
    _unknown(source, "poses.", poses, POSE_KEYS)
    n = _int(source, "poses.n", poses.get("n", 6), 1)
    seed = _int(source, "poses.seed", poses.get("seed", 0), 0)
    cover = poses.get("cover", POSES_COVER)
    if cover not in POSES_COVERS:
        raise CampaignError(f"{_where(source, 'poses.cover')}: expected one of "
                            f"{', '.join(repr(c) for c in POSES_COVERS)}; got {cover!r}")
    noise_seed = _int(source, "seed", doc.get("seed", 0), 0)
    responses = parse_responses(source, doc.get("response"))

    rend = doc.get("renderer", [{"name": "raycast"}])
    if not isinstance(rend, list) or not rend:
        raise CampaignError(f"{_where(source, 'renderer')}: expected one or more [[renderer]] "
                            f"tables")
    renderers = []
    for i, r in enumerate(rend):
        key = f"renderer[{i}]"
        if not isinstance(r, dict):
            raise CampaignError(f"{_where(source, key)}: expected a table")
        _unknown(source, key + ".", r, RENDERER_KEYS)
        if not isinstance(r.get("name"), str):
            raise CampaignError(f"{_where(source, key + '.name')}: missing; expected a "
                                f"renderer name")
        spp = _list_of(source, key + ".spp", r.get("spp", 16), (int,), "integers K >= 1")
        for k in spp:
            _int(source, key + ".spp", k, 1)
        ad = _list_of(source, key + ".adaptive", r.get("adaptive", True), (bool,),
                      "true or false")
        opts = r.get("options", {})
        if not isinstance(opts, dict):
            raise CampaignError(f"{_where(source, key + '.options')}: expected a table")
        chosen = None
        if "response" in r:
            chosen = tuple(_list_of(source, key + ".response", r["response"], (str,),
                                    "response profile names"))
            names_known = [p.name for p in responses]
            for c in chosen:
                if c not in names_known:
                    raise CampaignError(
                        f"{_where(source, key + '.response')}: unknown response profile "
                        f"{c!r}; known profiles: "
                        f"{', '.join(names_known) or '(none: add [response.NAME] tables)'}")
        label = r.get("label")
        if label is not None and not (isinstance(label, str) and LABEL.match(label)):
            raise CampaignError(f"{_where(source, key + '.label')}: expected a name of "
                                f"letters, digits, '_', '.' and '-'; got {label!r}")
        setup = r.get("setup", {})
        if not isinstance(setup, dict):
            raise CampaignError(f"{_where(source, key + '.setup')}: expected a table")
        renderers.append(RendererSpec(r["name"], tuple(spp), tuple(ad), dict(opts), chosen,
                                      label, dict(setup)))
    names = [(r.label or r.name, r.spp, r.adaptive, tuple(sorted(r.options.items(), key=str)),
              r.response) for r in renderers]
    if len(set(map(repr, names))) != len(names):
        raise CampaignError(f"{_where(source, 'renderer')}: two [[renderer]] tables name the "
                            f"same records; give them distinct labels (label = \"...\")")

    cal = doc.get("calibrator", [{"name": "jpl"}])
    if not isinstance(cal, list) or not cal:
        raise CampaignError(f"{_where(source, 'calibrator')}: expected one or more "
                            f"[[calibrator]] tables")
    calibrators = []
    for i, c in enumerate(cal):
        key = f"calibrator[{i}]"
        if not isinstance(c, dict):
            raise CampaignError(f"{_where(source, key)}: expected a table")
        _unknown(source, key + ".", c, CALIBRATOR_KEYS)
        if not isinstance(c.get("name"), str):
            raise CampaignError(f"{_where(source, key + '.name')}: missing; expected a "
                                f"calibrator name")
        ms = _list_of(source, key + ".models", c.get("models", [JOB_FAMILY]), (str,),
                      "model names")
        opts = c.get("options", {})
        if not isinstance(opts, dict):
            raise CampaignError(f"{_where(source, key + '.options')}: expected a table")
        own = _int(source, key + ".poses", c["poses"], 1) if "poses" in c else None
        fits = None
        if "targets" in c:
            fits = tuple(_list_of(source, key + ".targets", c["targets"], (str,),
                                  "target names"))
            for t in fits:
                if t not in targets:
                    raise CampaignError(f"{_where(source, key + '.targets')}: {t!r} is not "
                                        f"among the campaign's targets ({', '.join(targets)})")
        calibrators.append(CalibratorSpec(c["name"], tuple(ms), dict(opts), own, fits))
    if len({c.name for c in calibrators}) != len(calibrators):
        raise CampaignError(f"{_where(source, 'calibrator')}: a calibrator appears twice; "
                            f"list all its models in one table")
    for t in targets:
        if not any(c.fits(t) for c in calibrators):
            raise CampaignError(f"{_where(source, 'calibrator')}: no calibrator fits the "
                                f"target {t!r} (their targets = [...] leave it out)")

    cat = doc.get("catalogue")
    if cat is not None:
        if not isinstance(cat, str):
            raise CampaignError(f"{_where(source, 'catalogue')}: expected a file name")
        if base_dir is not None and not Path(cat).is_absolute():
            cat = str(Path(base_dir) / cat)
    name = doc.get("name", Path(source).stem if source else "campaign")
    if not isinstance(name, str) or not name:
        raise CampaignError(f"{_where(source, 'name')}: expected a non-empty string")
    desc = doc.get("description", "")
    if not isinstance(desc, str):
        raise CampaignError(f"{_where(source, 'description')}: expected a string")
    return Campaign(name=name, description=desc, source=str(source), cameras=tuple(cameras),
                    models=models, targets=targets, renderers=tuple(renderers),
                    calibrators=tuple(calibrators), poses_n=n, poses_seed=seed,
                    poses_cover=cover,
                    keep_images=_bool(source, "keep_images", doc.get("keep_images", False)),
                    keep_maps=_bool(source, "keep_maps", doc.get("keep_maps", True)),
                    catalogue=cat, seed=noise_seed, responses=responses,
                    share_identical_cameras=_bool(source, "share_identical_cameras",
                                                  doc.get("share_identical_cameras", True)),
                    target_models=target_models,
                    verdict_modes=_verdict_modes(source, doc.get("verdict_modes",
                                                                 list(VERDICT_MODES))))


def _verdict_modes(source, value):
    r'''verdict_modes -> its modes in PROJECTION_MODES order, checked: known names, and
"rotation" among them (the headline every judgement reads)'''
    modes = _list_of(source, "verdict_modes", value, (str,), "projection-difference modes")
    for m in modes:
        if m not in PROJECTION_MODES:
            raise CampaignError(f"{_where(source, 'verdict_modes')}: unknown mode {m!r}; "
                                f"known: {', '.join(PROJECTION_MODES)}")
    if "rotation" not in modes:
        raise CampaignError(f"{_where(source, 'verdict_modes')}: must include 'rotation' (the "
                            f"headline the gate, the report and the sigma read)")
    return tuple(m for m in PROJECTION_MODES if m in modes)


def _target_models(source, table, targets):
    r'''[target_models] -> ((target, (family or "own", ...)), ...), checked'''
    if not isinstance(table, dict):
        raise CampaignError(f"{_where(source, 'target_models')}: expected a table of "
                            f"target = [families]")
    out = []
    for t, fams in table.items():
        if t not in targets:
            raise CampaignError(f"{_where(source, 'target_models.' + t)}: {t!r} is not among "
                                f"the campaign's targets ({', '.join(targets)})")
        fams = _list_of(source, "target_models." + t, fams, (str,), "model families")
        for f in fams:
            if f not in FAMILIES and f != OWN_FAMILY:
                raise CampaignError(f"{_where(source, 'target_models.' + t)}: unknown model "
                                    f"family {f!r}; known: {', '.join(FAMILIES)} or "
                                    f"{OWN_FAMILY!r} (the camera's own)")
        out.append((t, tuple(fams)))
    return tuple(out)


def load_campaign(path):
    r'''Read and check the structure of a campaign TOML file -> Campaign'''
    path = Path(path)
    try:
        with open(path, "rb") as f:
            doc = tomllib.load(f)
    except FileNotFoundError:
        raise CampaignError(f"campaign file '{path}' does not exist") from None
    except tomllib.TOMLDecodeError as e:
        raise CampaignError(f"'{path}': not valid TOML: {e}") from None
    except OSError as e:
        raise CampaignError(f"'{path}': cannot read: {e.strerror}") from None
    return parse_campaign(doc, source=str(path), base_dir=path.resolve().parent)
