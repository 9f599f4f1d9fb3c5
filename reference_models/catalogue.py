r'''The camera catalogue: the paper's 22 camera slots and 11 extra real models

SYNOPSIS

    from reference_models.catalogue import load_catalogue

    cat = load_catalogue()                        # or load_catalogue(overlay="my.toml")
    e = cat.get(15)                               # slot id (int or "15")
    e = cat.get("SuperCam")                       # an extra's name
    e = cat.get("models/navcam.cahvor")           # a model file
    e.model.project(p)                            # CAHV / CAHVOR / CAHVORE
    [e.id for e in cat.slots()]                   # 1 .. 22, paper order
    [e.name for e in cat.extras()]

The data (reference_models/data/cameras.toml, a copy of the project's catalogue
with its provenance) has [[camera]] tables for the slots (id, rover, role, side,
status, source, stands_in or derivation, frame) and [[extra]] tables (name,
role, status, source, ...), each with the model's numbers: C, A, H, V [, O, R
[, E, model_type, linearity]], width, height. status is "real" (the named
camera), "substitute" (another real camera of the same role) or "derived" (a
real model moved rigidly).

OVERLAY

A user points a slot at a model of their own (the real MER models live in
JPL's calibration bundles) with an overlay TOML file:

    # my-overlay.toml
    [[replace]]
    id = 15                                   # a slot id; or: name = "SuperCam"
    file = "models/mer2_navcam_left.cahvor"   # relative to this overlay file
    note = "MER-B navcam SN102 from the calibration bundle"   # optional

    [[extra]]                                 # add a camera of one's own
    name = "my-hazcam"
    file = "models/my_hazcam.cahvore"
    role = "front hazcam"                     # optional

file may be a JPL .cahv/.cahvor/.cahvore, a PDS3 label (.LBL/.IMG) or a mrcal
.cameramodel. A replaced entry keeps its id, rover, role and side, gets status
"user" and source = the file, and remembers the entry it replaced
(entry.replaces). `camval catalogue list --overlay my-overlay.toml` shows it.
'''

import functools
import math
import os
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from .cahvore import CAHV, CAHVOR, CAHVORE
from .errors import CamvalError, ModelError, ModelFileError, UnknownCameraError

MODEL_FIELDS = ("C", "A", "H", "V", "O", "R", "E", "model_type", "linearity", "width", "height")
ENTRY_FIELDS = ("id", "name", "rover", "role", "side", "status", "source", "stands_in",
                "derivation", "frame")
MODEL_SUFFIXES = (".cahv", ".cahvor", ".cahvore", ".lbl", ".img", ".cameramodel")
OVERLAY_REPLACE_KEYS = {"id", "name", "file", "note", "status"}
OVERLAY_EXTRA_KEYS = {"name", "file", "note", "status", "role", "rover", "side", "frame"}


class CatalogueError(CamvalError):
    '''A malformed catalogue or overlay file.'''


@dataclass(frozen=True, eq=False)
class CatalogueEntry:
    r'''One camera of the catalogue

key: stable string key ("15" for slot 15, the name for an extra, the path for
a model file); id: slot id 1-22 or None; name: an extra's name, or
"<rover> <role> <side>" for a slot; kind: "slot", "extra" or "file";
provenance: every non-geometry field of the catalogue entry, verbatim
(source, serial, stands_in, derivation, note, size_note, ...); replaces: the
entry an overlay replaced, or None.
'''

    key: str
    id: int | None
    name: str
    rover: str | None
    role: str | None
    side: str | None
    status: str
    source: str | None
    stands_in: str | None
    derivation: str | None
    frame: str | None
    model: object
    kind: str = "slot"
    provenance: dict = field(default_factory=dict)
    replaces: "CatalogueEntry | None" = None

    @property
    def family(self):
        return self.model.family

    def __repr__(self):
        return (f"CatalogueEntry(key={self.key!r}, name={self.name!r}, status={self.status!r}, "
                f"model={self.model.family} {self.model.width}x{self.model.height})")


def model_from_fields(fields, where="catalogue entry"):
    r'''A CAHV / CAHVOR / CAHVORE from a dict of C, A, H, V [, O, R [, E, model_type,
linearity]], width, height (as in cameras.toml)'''
    for k in ("C", "A", "H", "V", "width", "height"):
        if k not in fields:
            raise CatalogueError(f"{where}: no {k}")
    kw = {k: fields[k] for k in ("C", "A", "H", "V", "width", "height")}
    try:
        if "E" in fields:
            return CAHVORE(**kw, O=fields["O"], R=fields["R"], E=fields["E"],
                           model_type=fields.get("model_type", 3),
                           linearity=fields.get("linearity"))
        if "O" in fields or "R" in fields:
            return CAHVOR(**kw, O=fields.get("O"), R=fields.get("R"))
        return CAHV(**kw)
    except ModelError as e:
        raise CatalogueError(f"{where}: {e}") from None


def load_model_file(path):
    r'''A model from a file: JPL .cahv/.cahvor/.cahvore (or any other name), a
PDS3 label (.LBL/.IMG) or a mrcal .cameramodel'''
    path = os.fspath(path)
    suffix = Path(path).suffix.lower()
    if suffix in (".lbl", ".img"):
        from .pds3 import read_pds3_model
        return read_pds3_model(path)
    if suffix == ".cameramodel":
        if not os.path.exists(path):
            raise ModelFileError(path, None, "no such file")
        import mrcal

        from .mrcal_convert import from_mrcal
        try:
            cm = mrcal.cameramodel(path)
        except Exception as e:  # mrcal raises bare Exception for bad files
            raise ModelFileError(path, None, f"mrcal cannot read it: {e}") from None
        try:
            return from_mrcal(cm)
        except ModelError as e:
            raise ModelFileError(path, None, str(e)) from None
    from .jpl_files import read_model
    return read_model(path)


def _entry_from_toml(t, kind, where):
    prov = {k: v for k, v in t.items() if k not in MODEL_FIELDS}
    model = model_from_fields(t, where)
    if kind == "slot":
        if not isinstance(t.get("id"), int):
            raise CatalogueError(f"{where}: a [[camera]] needs an integer id")
        name = " ".join(str(t[k]) for k in ("rover", "role", "side") if t.get(k))
        key = str(t["id"])
    else:
        if not isinstance(t.get("name"), str):
            raise CatalogueError(f"{where}: an [[extra]] needs a name")
        name = key = t["name"]
    return CatalogueEntry(
        key=key, id=t.get("id") if kind == "slot" else None, name=name,
        rover=t.get("rover"), role=t.get("role"), side=t.get("side"),
        status=t.get("status", "real"), source=t.get("source"),
        stands_in=t.get("stands_in"), derivation=t.get("derivation"), frame=t.get("frame"),
        model=model, kind=kind, provenance=prov)


def file_entry(path):
    r'''A CatalogueEntry for a model file that is not in the catalogue'''
    path = os.fspath(path)
    model = load_model_file(path)
    return CatalogueEntry(key=path, id=None, name=Path(path).name, rover=None, role=None,
                          side=None, status="file", source=path, stands_in=None,
                          derivation=None, frame=None, model=model, kind="file",
                          provenance={"source": path})


class Catalogue:
    r'''The catalogue's entries: slots (paper order) then extras'''

    def __init__(self, entries):
        self._entries = list(entries)
        keys = [e.key for e in self._entries]
        if len(set(keys)) != len(keys):
            raise CatalogueError(f"duplicate catalogue keys: {sorted(keys)}")

    def __iter__(self):
        return iter(self._entries)

    def __len__(self):
        return len(self._entries)

    def entries(self):
        return list(self._entries)

    def slots(self):
        return [e for e in self._entries if e.kind == "slot"]

    def extras(self):
        return [e for e in self._entries if e.kind != "slot"]

    def keys(self):
        return [e.key for e in self._entries]

    def _valid(self):
        ids = [e.id for e in self.slots()]
        id_text = f"{min(ids)}-{max(ids)}" if ids else "none"
        names = ", ".join(e.name for e in self.extras())
        return f"valid: slot ids {id_text}; extras {names}; or a model file path"

    def get(self, spec):
        r'''The entry for a slot id (15 or "15"), an extra's name or a model-file path

SYNOPSIS

    e = catalogue.get(15); e = catalogue.get("SuperCam"); e = catalogue.get("x.cahvor")

Raises UnknownCameraError (listing the valid ids and names) for anything else;
a model file that cannot be read raises ModelFileError.
'''
        if isinstance(spec, bool):
            raise UnknownCameraError(f"unknown camera {spec!r}; {self._valid()}")
        if isinstance(spec, int | np.integer):
            for e in self.slots():
                if e.id == int(spec):
                    return e
            raise UnknownCameraError(f"no catalogue slot {spec}; {self._valid()}")
        if isinstance(spec, os.PathLike):
            return file_entry(spec)
        if not isinstance(spec, str):
            raise UnknownCameraError(f"unknown camera {spec!r}; {self._valid()}")
        s = spec.strip()
        if s.isdigit():
            return self.get(int(s))
        for e in self._entries:
            if s == e.key or s == e.name:
                return e
        for e in self._entries:
            if s.lower() in (e.key.lower(), e.name.lower()):
                return e
        if os.path.exists(s) or Path(s).suffix.lower() in MODEL_SUFFIXES or os.sep in s:
            return file_entry(s)
        raise UnknownCameraError(f"unknown camera {spec!r}; {self._valid()}")


def catalogue_path():
    r'''The packaged cameras.toml'''
    return resources.files("reference_models").joinpath("data", "cameras.toml")


def _read_toml(path, what):
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise CatalogueError(f"{what} '{path}': no such file") from None
    except tomllib.TOMLDecodeError as e:
        raise CatalogueError(f"{what} '{path}': not valid TOML: {e}") from None


@functools.cache
def _packaged_entries():
    # entries and models are immutable, so every Catalogue can share them
    with resources.as_file(catalogue_path()) as p:
        data = _read_toml(p, "catalogue")
    entries = []
    for i, t in enumerate(data.get("camera", [])):
        entries.append(_entry_from_toml(t, "slot", f"catalogue [[camera]] {t.get('id', i)}"))
    for i, t in enumerate(data.get("extra", [])):
        entries.append(_entry_from_toml(t, "extra", f"catalogue [[extra]] {t.get('name', i)}"))
    return tuple(entries)


def load_catalogue(overlay=None):
    r'''The catalogue, with an optional overlay

SYNOPSIS

    cat = load_catalogue()
    cat = load_catalogue(overlay="my-overlay.toml")     # or a list of overlay files

See the module docstring for the overlay format.
'''
    cat = Catalogue(_packaged_entries())
    if overlay is None:
        return cat
    overlays = [overlay] if isinstance(overlay, str | os.PathLike) else list(overlay)
    for ov in overlays:
        cat = apply_overlay(cat, ov)
    return cat


def apply_overlay(cat, overlay_path):
    r'''The catalogue with the [[replace]] and [[extra]] tables of an overlay applied'''
    overlay_path = os.fspath(overlay_path)
    data = _read_toml(overlay_path, "overlay")
    base = Path(overlay_path).resolve().parent
    unknown = set(data) - {"replace", "extra"}
    if unknown:
        raise CatalogueError(f"overlay '{overlay_path}': unknown table(s) "
                             f"{', '.join(sorted(unknown))}; expected [[replace]] and [[extra]]")
    entries = cat.entries()

    def model_file(t, where):
        f = t.get("file")
        if not isinstance(f, str) or not f:
            raise CatalogueError(f"overlay '{overlay_path}', {where}: needs file = \"path\"")
        p = Path(f).expanduser()
        return str(p if p.is_absolute() else base / p)

    for i, t in enumerate(data.get("replace", [])):
        where = f"[[replace]] {i + 1}"
        bad = set(t) - OVERLAY_REPLACE_KEYS
        if bad:
            raise CatalogueError(f"overlay '{overlay_path}', {where}: unknown key(s) "
                                 f"{', '.join(sorted(bad))}; expected "
                                 f"{', '.join(sorted(OVERLAY_REPLACE_KEYS))}")
        if ("id" in t) == ("name" in t):
            raise CatalogueError(f"overlay '{overlay_path}', {where}: give either id = <slot> "
                                 "or name = \"<extra>\"")
        old = Catalogue(entries).get(t["id"] if "id" in t else str(t["name"]))
        path = model_file(t, where)
        model = load_model_file(path)
        prov = {"source": path, "overlay": overlay_path}
        if "note" in t:
            prov["note"] = t["note"]
        new = CatalogueEntry(
            key=old.key, id=old.id, name=old.name, rover=old.rover, role=old.role,
            side=old.side, status=t.get("status", "user"), source=path, stands_in=None,
            derivation=None, frame=None, model=model, kind=old.kind, provenance=prov,
            replaces=old)
        entries = [new if e is old else e for e in entries]

    for i, t in enumerate(data.get("extra", [])):
        where = f"[[extra]] {i + 1}"
        bad = set(t) - OVERLAY_EXTRA_KEYS
        if bad:
            raise CatalogueError(f"overlay '{overlay_path}', {where}: unknown key(s) "
                                 f"{', '.join(sorted(bad))}; expected "
                                 f"{', '.join(sorted(OVERLAY_EXTRA_KEYS))}")
        name = t.get("name")
        if not isinstance(name, str) or not name or name.isdigit():
            raise CatalogueError(f"overlay '{overlay_path}', {where}: needs name = \"...\" "
                                 "(not a number)")
        if any(name in (e.key, e.name) for e in entries):
            raise CatalogueError(f"overlay '{overlay_path}', {where}: {name!r} exists already; "
                                 "use [[replace]] to replace it")
        path = model_file(t, where)
        model = load_model_file(path)
        prov = {"source": path, "overlay": overlay_path}
        if "note" in t:
            prov["note"] = t["note"]
        entries.append(CatalogueEntry(
            key=name, id=None, name=name, rover=t.get("rover"), role=t.get("role"),
            side=t.get("side"), status=t.get("status", "user"), source=path, stands_in=None,
            derivation=None, frame=t.get("frame"), model=model, kind="extra",
            provenance=prov))
    return Catalogue(entries)


def field_of_view_deg(model):
    r'''(horizontal, vertical) field of view in degrees

SYNOPSIS

    hfov, vfov = field_of_view_deg(m)

The angle between the rays through the middles of the left and right (top and
bottom) image edges, at the outer edges of the edge pixels.
'''
    W, H = model.width, model.height
    xc, yc = (W - 1) / 2.0, (H - 1) / 2.0
    q = np.array(((-0.5, yc), (W - 0.5, yc), (xc, -0.5), (xc, H - 0.5)))
    _, v = model.unproject(q)

    def angle(a, b):
        return math.degrees(math.acos(max(-1.0, min(1.0, float(a @ b)))))

    return angle(v[0], v[1]), angle(v[2], v[3])
