r'''Import the Mars 2020 camera-model list (m2020-camera-models.json)

SYNOPSIS

    from reference_models.m2020_json import read_m2020_json

    models = read_m2020_json("m2020-camera-models.json")   # {name: model}
    models["NAVL"].family                                   # "CAHVORE"

The file (github.com/nasa-jpl/m2020-urdf-models) is a JSON list of

    {"name": "NAVL", "frame": "Body_RSM_EL",
     "model": {"type": "cahvore", "C": [...], "A": [...], "H": [...], "V": [...],
               "O": [...], "R": [...], "E": [...],
               "pupilType": 3, "linearity": 0.37, "width": 5120, "height": 3840}}

"type" is cahv, cahvor or cahvore; for cahvore "pupilType" is JPL's CAHVORE
type (1 perspective, 2 fisheye, 3 general) and "linearity" its P. Vectors a
type does not use may be null. read_m2020_frames() gives {name: frame}.

Problems raise ModelFileError naming the file and the entry.
'''

import json
import os

from .cahvore import CAHV, CAHVOR, CAHVORE
from .errors import ModelError, ModelFileError

TYPE_VECTORS = {
    "cahv": ("C", "A", "H", "V"),
    "cahvor": ("C", "A", "H", "V", "O", "R"),
    "cahvore": ("C", "A", "H", "V", "O", "R", "E"),
}


def _load(path):
    path = os.fspath(path)
    try:
        with open(path) as f:
            data = json.load(f)
    except FileNotFoundError:
        raise ModelFileError(path, None, "no such file") from None
    except json.JSONDecodeError as e:
        raise ModelFileError(path, e.lineno, f"not valid JSON: {e.msg}") from None
    if not isinstance(data, list):
        raise ModelFileError(path, None, "expected a JSON list of {name, frame, model} entries")
    return path, data


def _model(path, entry):
    name = entry.get("name")
    where = f"entry {name!r}"
    m = entry.get("model")
    if not isinstance(m, dict):
        raise ModelFileError(path, None, f"{where} has no 'model' object")
    mtype = str(m.get("type", "")).lower()
    if mtype not in TYPE_VECTORS:
        raise ModelFileError(path, None,
                             f"{where}: model type {m.get('type')!r}; expected cahv, cahvor "
                             "or cahvore")
    kw = {}
    for key in TYPE_VECTORS[mtype]:
        v = m.get(key)
        if not (isinstance(v, list) and len(v) == 3
                and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)):
            raise ModelFileError(path, None, f"{where}: {key} = {v!r}; expected 3 numbers")
        kw[key] = v
    for key in ("width", "height"):
        n = m.get(key)
        if not (isinstance(n, int) and not isinstance(n, bool) and n > 0):
            raise ModelFileError(path, None,
                                 f"{where}: {key} = {n!r}; expected a positive integer")
        kw[key] = n
    try:
        if mtype == "cahv":
            return CAHV(**kw)
        if mtype == "cahvor":
            return CAHVOR(**kw)
        pupil = m.get("pupilType")
        return CAHVORE(**kw, model_type=pupil,
                       linearity=m.get("linearity") if pupil == 3 else None)
    except ModelError as e:
        raise ModelFileError(path, None, f"{where}: {e}") from None


def read_m2020_json(path):
    r'''{name: model} for every entry of an m2020-camera-models.json file

SYNOPSIS

    models = read_m2020_json(path)
    models["HAZFLA"]      # CAHVORE(...)
'''
    path, data = _load(path)
    out = {}
    for i, entry in enumerate(data):
        if not isinstance(entry, dict) or not isinstance(entry.get("name"), str):
            raise ModelFileError(path, None, f"entry {i} has no name")
        if entry["name"] in out:
            raise ModelFileError(path, None, f"entry {entry['name']!r} appears twice")
        out[entry["name"]] = _model(path, entry)
    return out


def read_m2020_frames(path):
    r'''{name: frame} (the rover frame each model is expressed in)'''
    path, data = _load(path)
    return {e["name"]: e.get("frame") for e in data if isinstance(e, dict) and "name" in e}
