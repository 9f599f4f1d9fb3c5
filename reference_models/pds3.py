r'''Import the camera model of a PDS3 label (GEOMETRIC_CAMERA_MODEL group)

SYNOPSIS

    from reference_models.pds3 import read_pds3_model

    m = read_pds3_model("1N491020376ILFCNY9P0706L0M1.LBL")   # or the .IMG with its label

The label's group

    GROUP                 = GEOMETRIC_CAMERA_MODEL
      MODEL_TYPE          = CAHVORE
      MODEL_COMPONENT_ID  = (C,A,H,V,O,R,E,T,P)
      MODEL_COMPONENT_1   = (0.609331,-0.041064,-0.233849)
      ...
      MODEL_COMPONENT_8   = 3.0          (T: CAHVORE type)
      MODEL_COMPONENT_9   = 0.37         (P: linearity)
    END_GROUP             = GEOMETRIC_CAMERA_MODEL

(GEOMETRIC_CAMERA_MODEL_PARMS in later missions' labels) gives the vectors
(by MODEL_COMPONENT_ID when present, else in the order
C, A, H, V, O, R, E, T, P), and the IMAGE object's LINE_SAMPLES and LINES give
the image width and height. PDS camera models are in the product's own 0-based
pixel coordinates (subframing and downsampling already applied).

Problems raise ModelFileError naming the label, the line and what was expected.
'''

import math
import os
import re

from .cahvore import CAHV, CAHVOR, CAHVORE
from .errors import ModelError, ModelFileError

DEFAULT_COMPONENT_ORDER = ("C", "A", "H", "V", "O", "R", "E", "T", "P")
FAMILY_COMPONENTS = {
    "CAHV": ("C", "A", "H", "V"),
    "CAHVOR": ("C", "A", "H", "V", "O", "R"),
    "CAHVORE": ("C", "A", "H", "V", "O", "R", "E", "T", "P"),
}
# MSL and later labels name the group GEOMETRIC_CAMERA_MODEL_PARMS
GROUP_NAMES = ("GEOMETRIC_CAMERA_MODEL", "GEOMETRIC_CAMERA_MODEL_PARMS")
# a PDS3 label ends at END; attached labels are followed by binary data
MAX_LABEL_BYTES = 1 << 20

_re_assign = re.compile(r"^\s*(\^?[A-Z_][A-Z0-9_:]*)\s*=\s*(.*?)\s*$")


def _label_lines(path):
    with open(path, "rb") as f:
        raw = f.read(MAX_LABEL_BYTES)
    text = raw.decode("latin-1")
    lines = []
    for line in text.splitlines():
        if line.strip() == "END":
            return lines
        lines.append(line)
    if not lines or not any(_re_assign.match(x) for x in lines[:5]):
        raise ModelFileError(path, None, "not a PDS3 label (no 'NAME = value' statements)")
    return lines


def _statements(path, lines):
    r'''[(lineno, name, value)] with multi-line values ( ... ) and "..." joined'''
    out = []
    i = 0
    while i < len(lines):
        line = re.sub(r"/\*.*?\*/", "", lines[i])
        m = _re_assign.match(line)
        if not m:
            i += 1
            continue
        lineno = i + 1
        name, value = m.group(1), m.group(2)
        while (value.count("(") > value.count(")") or value.count('"') % 2 == 1) \
                and i + 1 < len(lines):
            i += 1
            value += " " + re.sub(r"/\*.*?\*/", "", lines[i]).strip()
        out.append((lineno, name, value))
        i += 1
    return out


def _strip_units(s):
    return re.sub(r"<[^>]*>", "", s).strip().strip('"').strip()


def _floats(path, lineno, name, value, count):
    v = _strip_units(value)
    if count > 1:
        if not (v.startswith("(") and v.endswith(")")):
            raise ModelFileError(path, lineno, f"{name} = {value}; expected ({count} numbers)")
        v = v[1:-1]
    words = [w.strip().strip('"') for w in v.split(",")] if count > 1 else [v]
    if len(words) != count:
        raise ModelFileError(path, lineno,
                             f"{name} has {len(words)} number(s); expected {count}")
    out = []
    for w in words:
        try:
            x = float(_strip_units(w))
        except ValueError:
            raise ModelFileError(
                path, lineno, f"{name}: {w!r} is not a number; expected {count} numbers") from None
        if not math.isfinite(x):
            raise ModelFileError(path, lineno, f"{name}: {w!r} is not finite")
        out.append(x)
    return out


def read_pds3_model(path):
    r'''The camera model of a PDS3 label

SYNOPSIS

    m = read_pds3_model("x.LBL")    # CAHV, CAHVOR or CAHVORE
    m.width, m.height               # from the IMAGE object

Reads the first GEOMETRIC_CAMERA_MODEL group. Raises ModelFileError for a
missing group or component, a malformed number, an unknown MODEL_TYPE or
CAHVORE type, or a missing image size.
'''
    path = os.fspath(path)
    try:
        lines = _label_lines(path)
    except FileNotFoundError:
        raise ModelFileError(path, None, "no such file") from None
    statements = _statements(path, lines)

    group = None
    group_done = False
    image = {}
    depth = []  # open OBJECT/GROUP statements: [(kind, name)]
    for lineno, name, value in statements:
        v = _strip_units(value)
        if name in ("OBJECT", "GROUP"):
            depth.append((name, v))
            if name == "GROUP" and v in GROUP_NAMES and group is None:
                group = {"__line__": lineno}
            continue
        if name in ("END_OBJECT", "END_GROUP"):
            if depth and depth.pop()[1] in GROUP_NAMES and group is not None:
                group_done = True
            continue
        top = depth[-1] if depth else None
        if top and top[0] == "GROUP" and top[1] in GROUP_NAMES and not group_done:
            group[name] = (lineno, value)
        elif top == ("OBJECT", "IMAGE") and name in ("LINES", "LINE_SAMPLES"):
            image[name] = (lineno, value)

    if group is None:
        raise ModelFileError(path, None,
                             "no 'GROUP = GEOMETRIC_CAMERA_MODEL' in the label; "
                             "expected a PDS3 label carrying a camera model")
    gline = group["__line__"]
    if "MODEL_TYPE" not in group:
        raise ModelFileError(path, gline, "GEOMETRIC_CAMERA_MODEL has no MODEL_TYPE")
    tline, tvalue = group["MODEL_TYPE"]
    family = _strip_units(tvalue).upper()
    if family not in FAMILY_COMPONENTS:
        raise ModelFileError(path, tline,
                             f"MODEL_TYPE = {tvalue}; expected CAHV, CAHVOR or CAHVORE")
    if "MODEL_COMPONENT_ID" in group:
        iline, ivalue = group["MODEL_COMPONENT_ID"]
        ids = [w.strip().strip('"').upper() for w in _strip_units(ivalue).strip("()").split(",")]
    else:
        iline = gline
        ids = list(DEFAULT_COMPONENT_ORDER[:len(FAMILY_COMPONENTS[family])])
    comps = {}
    for i, cid in enumerate(ids, start=1):
        key = f"MODEL_COMPONENT_{i}"
        if cid not in FAMILY_COMPONENTS[family]:
            continue
        if key not in group:
            raise ModelFileError(path, iline,
                                 f"{key} ({cid}) is missing from GEOMETRIC_CAMERA_MODEL")
        lineno, value = group[key]
        comps[cid] = (lineno, _floats(path, lineno, f"{key} ({cid})", value,
                                      1 if cid in ("T", "P") else 3))
    for cid in FAMILY_COMPONENTS[family]:
        if cid not in comps:
            raise ModelFileError(path, iline,
                                 f"{family} needs component {cid}; MODEL_COMPONENT_ID lists "
                                 f"{', '.join(ids)}")

    for key in ("LINE_SAMPLES", "LINES"):
        if key not in image:
            raise ModelFileError(path, None,
                                 f"the IMAGE object has no {key}; expected the image size there")
    size = {}
    for key in ("LINE_SAMPLES", "LINES"):
        lineno, value = image[key]
        (x,) = _floats(path, lineno, key, value, 1)
        if not (x.is_integer() and x > 0):
            raise ModelFileError(path, lineno, f"{key} = {value}; expected a positive integer")
        size[key] = int(x)

    kw = dict(C=comps["C"][1], A=comps["A"][1], H=comps["H"][1], V=comps["V"][1],
              width=size["LINE_SAMPLES"], height=size["LINES"])
    try:
        if family == "CAHV":
            return CAHV(**kw)
        if family == "CAHVOR":
            return CAHVOR(**kw, O=comps["O"][1], R=comps["R"][1])
        tline_, (t,) = comps["T"]
        if not (t.is_integer() and int(t) in (1, 2, 3)):
            raise ModelFileError(path, tline_,
                                 f"unknown CAHVORE type {t!r}; known types are 1 (perspective), "
                                 "2 (fisheye), 3 (general)")
        (p,) = comps["P"][1]
        return CAHVORE(**kw, O=comps["O"][1], R=comps["R"][1], E=comps["E"][1],
                       model_type=int(t), linearity=p if int(t) == 3 else None)
    except ModelFileError:
        raise
    except ModelError as e:
        m = re.match(r"^A is parallel to (H|V)|^(C|A|H|V|O|R|E) ", str(e))
        cid = (m.group(1) or m.group(2)) if m else None
        raise ModelFileError(path, comps[cid][0] if cid in comps else gline, str(e)) from None
