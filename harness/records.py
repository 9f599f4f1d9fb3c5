r'''Campaign records and the run document

SYNOPSIS

    from harness.records import Record, RunStore, load_run

    store = RunStore.create("runs/20261122T150000Z", campaign_dict, adapters)
    store.save_job(job_key, [record, ...])     # as each job finishes (atomic)
    store.done_jobs()                          # {job_key, ...}: resume skips these
    doc = store.assemble()                     # writes run.json (atomic), returns it

    doc = load_run("runs/20261122T150000Z")   # a run dir or a run.json
    doc["records"]["15/CAHVOR/dots/raycast[spp=16,adaptive,coverage=area]/jpl[CAHVOR]"]["projection"]["rms"]

One Record per camera x model family x target x renderer setting x calibrator
(and its model), keyed by a stable `fullname`

    camera/model/target/renderer[settings]/calibrator[model]

e.g. "15/CAHVOR/dots/raycast[spp=16,adaptive,coverage=area]/jpl[CAHVOR]". Records are plain
JSON (json.dumps(..., allow_nan=False): NaN and inf are stored as null).

A run directory holds

    campaign.json        the resolved campaign (what resume re-runs)
    records/*.json       one file per finished job, written atomically as it ends
    run.json             the run document, assembled from records/ (atomic)
    maps/*.npy           downsampled projection-difference maps (keep_maps)
    images/...           rendered images (keep_images)

An interrupted run loses at most the jobs that were running: every finished
job is already in records/, and resume (harness.runner) skips it.
'''

import dataclasses
import datetime
import hashlib
import json
import math
import os
import platform
import re
import subprocess
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from reference_models.errors import CamvalError

SCHEMA_VERSION = 1
RUN_DOCUMENT = "run.json"
RUN_KIND = "camval-run"
BASELINE_KIND = "camval-baseline"
# a benchmark's document (benchmarks/common.py): records a gate spec can judge too
BENCHMARK_KIND = "camval-benchmark"
# what `camval gate` and `camval baseline save` read
GATED_KINDS = (RUN_KIND, BASELINE_KIND, BENCHMARK_KIND)
STATUSES = ("ok", "failed", "not-applicable")
# Fields that depend on the machine, not on the campaign: left out when two
# runs are compared for determinism.
TIMING_FIELDS = ("seconds",)


class RunError(CamvalError):
    '''A run directory or run document that cannot be read or written.'''


def jsonable(x):
    r'''numpy values (recursively) -> plain JSON values; NaN/inf -> None'''
    import numpy as np

    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        x = float(x)
        return x if math.isfinite(x) else None
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        return jsonable(dataclasses.asdict(x))
    return x


def settings_label(settings):
    r'''"spp=16,adaptive" for {"spp": 16, "adaptive": True, "options": {...}}

Options follow, sorted by name, as key=value; then the camera-response
profile, if the settings name one ("response": "realistic" ->
",response=realistic"). Settings without a response give the label they
always had, so clean records keep their fullnames.
'''
    parts = [f"spp={int(settings.get('spp', 1))}",
             "adaptive" if settings.get("adaptive", False) else "full"]
    for k, v in sorted((settings.get("options") or {}).items()):
        if isinstance(v, bool):
            v = "true" if v else "false"
        parts.append(f"{k}={v}")
    if settings.get("response"):
        parts.append(f"response={settings['response']}")
    return ",".join(parts)


def renderer_key(renderer, settings):
    r'''The renderer's part of a fullname: "label[settings]" ("povray[spp=16,adaptive,camera=mesh]")

The label is settings["label"] when the campaign gives one, else the
renderer's name; settings["setup"] (how the renderer is run: a command, a
timeout) never enters it, so a baseline joins whatever the setup. The
options a renderer applies by default (renderers.base.DEFAULT_OPTIONS) are
named whether the settings give them or not ("raycast[spp=16,adaptive,
coverage=area]"): a record of another default never joins.
'''
    from renderers.base import DEFAULT_OPTIONS  # here: records stay light to import
    defaults = DEFAULT_OPTIONS.get(renderer)
    if defaults:
        settings = dict(settings, options={**defaults, **(settings.get("options") or {})})
    return f"{settings.get('label') or renderer}[{settings_label(settings)}]"


def make_fullname(camera, model, target, renderer, settings, calibrator, calibrator_model):
    r'''The stable key of a record: camera/model/target/label[settings]/calibrator[model]'''
    return (f"{camera}/{model}/{target}/{renderer_key(renderer, settings)}"
            f"/{calibrator}[{calibrator_model}]")


@dataclass(frozen=True)
class Record:
    r'''One calibrator's verdict on one rendered image set

fullname:         camera/model/target/renderer[settings]/calibrator[model]
camera:           catalogue key of the camera ("15", "supercam", a file name)
camera_label:     human name ("MER B navcam left")
model:            the model family the images were rendered with (CAHV, CAHVOR, CAHVORE)
target, renderer: names; settings: {"spp", "adaptive", "options"[, "response": profile]
                  [, "label": the campaign's name for the renderer][, "setup": how it was
                  run (recorded, not in the fullname)]}
calibrator, calibrator_model: e.g. "jpl", "CAHVOR"
status:           "ok" | "failed" | "not-applicable"; reason: why not ok
stage:            the stage that failed ("camera", "poses", "render", "response", "detect",
                  "calibrate", "compare") or "" when ok
residuals:        {"n", "min", "max", "rms", "mean"} px, per point (paper Fig. 3)
params:           {name: fit - truth} (harness.compare.parameter_errors: Hc, Vc px;
                  Hs, Vs fractional; theta_deg; C_mm; A_deg, O_deg; R0..R2, R0_frac..;
                  E0..E2); None = not estimated by this calibrator
projection:       {"rms", "max"} px (fitted-rotation projection difference, truth vs
                  fit) and per mode {"rotation"|"intrinsics"|"world": {"rms", "max", ...}}
seconds:          {"render_per_image" (median), "render_first_image", "render", "detect",
                  "calibrate", "compare",
                  "response" (the camera response of all images), "response_stages":
                  {stage: seconds summed over the images, "setup": building the chain}}
detections:       {"n_expected", "n_found", "per_pose": [n_found, ...]}
image_size:       [width, height]
artifacts:        relative paths inside the run dir ({"map": "maps/....npy", "images": [...]})
versions:         {"renderer": "...", "calibrator": "..."}
info:             anything else the stages reported
response:         the camera response applied after rendering: {"profile": name ("" for
                  none), "stages": [{"stage", "params"}, ...] in the order they ran,
                  "full_well_e", "seed": {"campaign", "profile", "job_sha256"}} (the
                  last two only when stages ran);
                  None in records written before camera response existed
features:         what the renderer modelled beyond geometry: {"shading", "texture",
                  "shadows"} (bools); a board target is flat albedo: all false
verdict:          how much of the error the images caused (harness.verdict.assess):
                  {"floor", "renderer", "total"} each {"params", "projection"} (fit of
                  the exact observations vs truth, image fit vs that fit, image fit vs
                  truth), "exact_fit", "detection_noise", "floor_far", "floor_reason";
                  floor and renderer projection in the modes of the campaign's
                  verdict_modes (run.json campaign.verdict_modes; "rotation" by default),
                  total in every mode;
                  None in records that are not ok and in records written before it
'''

    fullname: str
    camera: str
    camera_label: str
    model: str
    target: str
    renderer: str
    settings: dict
    calibrator: str
    calibrator_model: str
    status: str
    reason: str = ""
    stage: str = ""
    residuals: dict = None
    params: dict = None
    projection: dict = None
    seconds: dict = field(default_factory=dict)
    detections: dict = None
    image_size: list = None
    artifacts: dict = field(default_factory=dict)
    versions: dict = field(default_factory=dict)
    info: dict = field(default_factory=dict)
    response: dict = None
    features: dict = None
    verdict: dict = None

    def __post_init__(self):
        if self.status not in STATUSES:
            raise RunError(f"record {self.fullname!r}: status {self.status!r} is not one of "
                           f"{', '.join(STATUSES)}")

    def as_dict(self):
        return jsonable(dataclasses.asdict(self))

    @classmethod
    def from_dict(cls, d):
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise RunError(f"record {d.get('fullname')!r} has unknown fields "
                           f"{sorted(unknown)}; known: {sorted(names)}")
        return cls(**d)


def without_timings(record_dict):
    r'''A record dict with the machine-dependent fields removed (for determinism checks)'''
    return {k: v for k, v in record_dict.items() if k not in TIMING_FIELDS}


def get_field(record_dict, path):
    r'''The value at a dotted path ("projection.rms", "params.Hc"), or None'''
    v = record_dict
    for part in path.split("."):
        if not isinstance(v, dict) or part not in v:
            return None
        v = v[part]
    return v


def dumps(doc):
    try:
        return json.dumps(jsonable(doc), indent=1, sort_keys=True, allow_nan=False) + "\n"
    except (TypeError, ValueError) as e:
        raise RunError(f"cannot serialise the run document: {e}") from None


def write_atomic(path, text):
    r'''Write text to path through a temporary file in the same directory + os.replace'''
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def write_json_atomic(path, doc):
    write_atomic(path, dumps(doc))


def utc_now():
    return datetime.datetime.now(datetime.UTC).replace(microsecond=0).isoformat().replace(
        "+00:00", "Z")


def utc_stamp():
    r'''"20261122T150312Z": a run directory name'''
    return datetime.datetime.now(datetime.UTC).strftime("%Y%m%dT%H%M%SZ")


def git_commit(repo=None):
    r'''{"commit": sha or None, "dirty": bool or None} of the source tree'''
    repo = repo or Path(__file__).resolve().parent.parent
    try:
        sha = subprocess.run(["git", "rev-parse", "HEAD"], cwd=repo, capture_output=True,
                             text=True, timeout=10, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               cwd=repo, capture_output=True, text=True, timeout=10,
                               check=True).stdout.strip() != ""
        return {"commit": sha, "dirty": dirty}
    except (OSError, subprocess.SubprocessError):
        return {"commit": None, "dirty": None}


def machine():
    return {"hostname": platform.node(), "system": platform.system(),
            "release": platform.release(), "machine": platform.machine(),
            "python": platform.python_version(), "cpus": os.cpu_count()}


def job_filename(job_key):
    r'''A file name for a job's records: readable slug + short hash (unique, any length key)'''
    slug = re.sub(r"[^A-Za-z0-9=.,_-]+", "_", job_key)[:80]
    digest = hashlib.sha1(job_key.encode()).hexdigest()[:12]
    return f"{slug}-{digest}.json"


class RunStore:
    r'''A run directory: finished jobs stored one file each, assembled into run.json

SYNOPSIS

    store = RunStore.create(run_dir, campaign_dict)    # new run (dir must not hold one)
    store = RunStore.open(run_dir)                      # resume
    store.save_job(job_key, records)                    # records: list of Record or dicts
    store.done_jobs()                                   # set of job keys
    doc = store.assemble(adapters)                      # run.json
'''

    def __init__(self, run_dir):
        self.dir = Path(run_dir)
        self.records_dir = self.dir / "records"

    @classmethod
    def create(cls, run_dir, campaign):
        store = cls(run_dir)
        if (store.dir / "campaign.json").exists():
            raise RunError(f"'{store.dir}' already holds a run; resume it with --resume "
                           f"{store.dir} or choose another --out")
        store.records_dir.mkdir(parents=True, exist_ok=True)
        write_json_atomic(store.dir / "campaign.json",
                          {"campaign": campaign, "started": utc_now()})
        return store

    @classmethod
    def open(cls, run_dir):
        store = cls(run_dir)
        if not (store.dir / "campaign.json").is_file():
            raise RunError(f"'{store.dir}' is not a camval run directory (no campaign.json); "
                           f"expected a directory written by camval verify")
        store.records_dir.mkdir(parents=True, exist_ok=True)
        return store

    def campaign(self):
        return _read_json(self.dir / "campaign.json")["campaign"]

    def started(self):
        return _read_json(self.dir / "campaign.json").get("started")

    def save_job(self, job_key, records, final=True):
        r'''Store a job's records (atomic). final=False: the records say why the job could
not run (a worker died); they are reported, but resume runs the job again.'''
        recs = [r.as_dict() if isinstance(r, Record) else jsonable(r) for r in records]
        write_json_atomic(self.records_dir / job_filename(job_key),
                          {"job": job_key, "final": bool(final), "records": recs})

    def _job_files(self):
        return sorted(self.records_dir.glob("*.json"))

    def done_jobs(self):
        r'''Keys of the jobs whose records are stored (a partial or corrupt file is not done)'''
        done = set()
        for path in self._job_files():
            try:
                doc = _read_json(path)
                if doc.get("final", True):
                    done.add(doc["job"])
            except (RunError, KeyError, AttributeError):
                continue
        return done

    def records(self):
        r'''{fullname: record dict} of every stored job, sorted by fullname'''
        out = {}
        for path in self._job_files():
            try:
                doc = _read_json(path)
            except RunError:
                continue
            for r in doc["records"]:
                out[r["fullname"]] = r
        return dict(sorted(out.items()))

    def assemble(self, adapters=None, extra=None):
        r'''Write run.json from the stored job files (atomic) and return the document'''
        doc = {
            "kind": RUN_KIND,
            "schema_version": SCHEMA_VERSION,
            "created": utc_now(),
            "started": self.started(),
            "source": git_commit(),
            "machine": machine(),
            "adapters": adapters or {},
            "campaign": self.campaign(),
            "records": self.records(),
        }
        doc["minimum_detectable_faults"] = _minimum_detectable_faults(doc)
        if extra:
            doc.update(extra)
        write_json_atomic(self.dir / RUN_DOCUMENT, doc)
        return doc


def _minimum_detectable_faults(doc):
    r'''run.json's "minimum_detectable_faults": {"spec": path, "cameras": {camera: {fault:
{...}}}} under the renderer gate (harness.gate.minimum_detectable_faults), or {"error"}'''
    try:
        from .gate import DEFAULT_SPEC, load_gate_spec, minimum_detectable_faults
        spec = load_gate_spec(DEFAULT_SPEC)
        return {"spec": DEFAULT_SPEC.name, "cameras": minimum_detectable_faults(doc, spec)}
    except Exception as e:  # the run document is written whatever happens here
        return {"error": f"{type(e).__name__}: {e}"}


def _read_json(path):
    try:
        with open(path) as f:
            return json.load(f)
    except FileNotFoundError:
        raise RunError(f"'{path}' does not exist") from None
    except (OSError, json.JSONDecodeError) as e:
        raise RunError(f"'{path}' is not a readable JSON document: {e}") from None


def load_run(path, kinds=(RUN_KIND, BASELINE_KIND)):
    r'''Read a run document (a run directory or its run.json, or a baseline)

SYNOPSIS

    doc = load_run("runs/20261122T150000Z")
    doc["records"]   # {fullname: record dict}

Checks the kind and schema version; a run directory whose run.json is
missing (interrupted before assembly) is assembled from its records/.
'''
    path = Path(path)
    if path.is_dir():
        if not (path / RUN_DOCUMENT).is_file():
            if (path / "campaign.json").is_file():
                return RunStore.open(path).assemble()
            raise RunError(f"'{path}' is not a camval run directory (no {RUN_DOCUMENT}); "
                           f"expected a directory written by camval verify")
        path = path / RUN_DOCUMENT
    doc = _read_json(path)
    if not isinstance(doc, dict) or doc.get("kind") not in kinds:
        raise RunError(f"'{path}' is not a camval run document: kind "
                       f"{doc.get('kind') if isinstance(doc, dict) else None!r}; "
                       f"expected one of {', '.join(kinds)}")
    if doc.get("schema_version") != SCHEMA_VERSION:
        raise RunError(f"'{path}' has schema version {doc.get('schema_version')!r}; this "
                       f"camval reads version {SCHEMA_VERSION}")
    if not isinstance(doc.get("records"), dict):
        raise RunError(f"'{path}' has no records table")
    return doc
