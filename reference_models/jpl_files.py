r'''Read and write JPL camera-model text files (.cahv, .cahvor, .cahvore)

SYNOPSIS

    from reference_models.jpl_files import read_model, write_model

    m = read_model("navcam_left.cahvor")     # CAHV, CAHVOR or CAHVORE
    write_model(m, "copy.cahvor")            # refuses to overwrite unless overwrite=True

The format is JPL's (cmod_cahv*_write) and mrcal's: one "NAME = values" entry a line,
'#' comments, blank lines ignored:

    Model = CAHVORE3,0.37 = general        (or CAHV = perspective, linear;
                                             CAHVOR = perspective, distortion;
                                             CAHVORE1 = perspective, distortion, pupil;
                                             CAHVORE2 = fish-eye)
    Dimensions = 1024 1024                 width height, pixels
    C = x y z                              metres
    A = x y z                              unit vector
    H = x y z                              pixels
    V = x y z                              pixels
    O = x y z                              unit vector        (CAHVOR, CAHVORE)
    R = r0 r1 r2                                              (CAHVOR, CAHVORE)
    E = e0 e1 e2                                              (CAHVORE)
    S =                                    covariance: 3N rows of 3N numbers
     ...                                   (N = number of vectors)
    Hs    = ...                            optional derived values; when present
    Hc    = ...                            they must agree with H, V, A
    Vs    = ...
    Vc    = ...
    Theta = -1.5707963267948966 (-90.0 deg)
    S internal =                           5 rows of 5 numbers
     ...

Theta in a file is JPL's signed angle from H' to V' about A: -90 deg for an
ordinary (right-handed: H' x V' along A) camera, positive for a mirrored one.
Without a Model line the family follows the vectors present (CAHVORE needs the
Model line: it carries the type and linearity).

Files are written at full precision (the shortest decimal that reads back to
the same float64), so write -> read is exact.

Every problem with a file raises reference_models.errors.ModelFileError naming
the file, the 1-based line and what was expected.
'''

import math
import os
import re
from pathlib import Path

import numpy as np

from .cahvore import CAHV, CAHVOR, CAHVORE, UNIT_TOLERANCE
from .errors import CamvalError, ModelError, ModelFileError
from .poseutils import cross3

VECTOR_NAMES = ("C", "A", "H", "V", "O", "R", "E")
DERIVED_NAMES = ("Hs", "Hc", "Vs", "Vc", "Theta")
FAMILY_VECTORS = {"CAHV": "CAHV", "CAHVOR": "CAHVOR", "CAHVORE": "CAHVORE"}
MODEL_LINE = {
    "CAHV": "CAHV = perspective, linear",
    "CAHVOR": "CAHVOR = perspective, distortion",
}
# Derived values are printed with a few decimals by some tools; beyond this
# disagreement they describe another camera.
DERIVED_TOLERANCE_PX = 0.05
DERIVED_TOLERANCE_RELATIVE = 1e-5
THETA_TOLERANCE = 1e-3  # radians


class OutputExistsError(CamvalError, FileExistsError):
    '''An output file exists already and overwriting was not asked for.'''


def jpl_theta(model):
    r'''JPL's signed angle from H' to V' about A (radians)

SYNOPSIS

    jpl_theta(m)    # -pi/2 for an ordinary camera; > 0 for a mirrored one

This is the "Theta" of a JPL model file; Photogrammetric.theta is its absolute
value.
'''
    ph = model.photogrammetric()
    return math.atan2(float(cross3(ph.Vp, ph.Hp) @ model.A), float(ph.Hp @ ph.Vp))


# --- reading ------------------------------------------------------------------

_re_entry = re.compile(r"^\s*([A-Za-z_][A-Za-z_0-9]*(?:\s+internal)?)\s*=\s*(.*?)\s*$")
_re_cahvore = re.compile(r"^CAHVORE\s*([0-9]+)\s*(?:,\s*(\S+?))?\s*(?:=.*)?$")


def _numbers(path, lineno, name, text, count, integer=False):
    words = text.split()
    if len(words) != count:
        raise ModelFileError(path, lineno,
                             f"{name} has {len(words)} number(s); expected {count}")
    out = []
    for w in words:
        try:
            x = float(w)
        except ValueError:
            raise ModelFileError(
                path, lineno, f"{name}: {w!r} is not a number; expected {count} numbers") from None
        if not math.isfinite(x):
            raise ModelFileError(path, lineno,
                                 f"{name}: {w!r} is not finite; expected finite numbers")
        if integer and not x.is_integer():
            raise ModelFileError(path, lineno, f"{name}: {w!r} is not an integer")
        out.append(x)
    return out


def _parse_family(path, lineno, value):
    r'''(family, model_type, linearity) from the value of a Model line'''
    head = value.split("=")[0].strip()
    m = _re_cahvore.match(value.strip())
    if m:
        mtype = int(m.group(1))
        if mtype not in (1, 2, 3):
            raise ModelFileError(
                path, lineno, f"unknown CAHVORE type {mtype} in 'Model = {value}'; "
                "known types are 1 (perspective), 2 (fisheye), 3 (general)")
        linearity = None
        if m.group(2) is not None:
            try:
                linearity = float(m.group(2))
            except ValueError:
                raise ModelFileError(path, lineno,
                                     f"CAHVORE linearity {m.group(2)!r} is not a number") from None
            if not math.isfinite(linearity):
                raise ModelFileError(path, lineno,
                                     f"CAHVORE linearity {m.group(2)!r} is not finite")
        implied = {1: 1.0, 2: 0.0}.get(mtype)
        if implied is not None and linearity is not None and linearity != implied:
            raise ModelFileError(
                path, lineno, f"CAHVORE type {mtype} has linearity {implied:g}; got {linearity!r}")
        if mtype == 3 and linearity is None:
            raise ModelFileError(
                path, lineno, "CAHVORE type 3 needs a linearity ('CAHVORE3,0.37 = general')")
        return "CAHVORE", mtype, linearity
    if head.upper().startswith("CAHVORE"):
        raise ModelFileError(path, lineno,
                             f"cannot parse the CAHVORE declaration 'Model = {value}'; "
                             "expected e.g. 'Model = CAHVORE3,0.37 = general'")
    if head.upper() in ("CAHV", "CAHVOR"):
        return head.upper(), None, None
    raise ModelFileError(path, lineno,
                         f"unknown model {head!r}; expected CAHV, CAHVOR or CAHVORE<type>")


def _parse(path, text):
    r'''entries {name: (lineno, value)} and matrix blocks {name: (lineno, rows)}'''
    entries = {}
    blocks = {}
    block = None
    for lineno, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        m = _re_entry.match(line)
        if m:
            name, value = m.group(1), m.group(2)
            name = re.sub(r"\s+", " ", name)
            if name in entries or name in blocks:
                raise ModelFileError(path, lineno, f"{name} is given twice")
            if value == "":
                block = (name, lineno, [])
                blocks[name] = (lineno, block[2])
            else:
                block = None
                entries[name] = (lineno, value)
            continue
        if block is not None:
            block[2].append((lineno, stripped))
            continue
        raise ModelFileError(path, lineno,
                             f"cannot parse {stripped[:40]!r}; expected 'NAME = values'")
    return entries, blocks


def _check_block(path, name, lineno, rows, n):
    if len(rows) != n:
        raise ModelFileError(path, lineno,
                             f"{name} has {len(rows)} row(s); expected {n} rows of {n} numbers")
    for rlineno, row in rows:
        _numbers(path, rlineno, f"{name} row", row, n)


def parse_model_text(text, path="<string>"):
    r'''A camera model from the text of a JPL model file

SYNOPSIS

    m = parse_model_text(open("x.cahvor").read(), "x.cahvor")

path only names the source in error messages. See read_model().
'''
    entries, blocks = _parse(path, text)

    for name, (lineno, _) in entries.items():
        if name.upper().startswith(("LENSMODEL_", "DISTORTION")):
            raise ModelFileError(path, lineno,
                                 f"{name}: a mrcal lens-model extension has no JPL equivalent; "
                                 "expected a CAHV, CAHVOR or CAHVORE file")

    family = mtype = linearity = None
    model_line = None
    if "Model" in entries:
        model_line, value = entries["Model"]
        family, mtype, linearity = _parse_family(path, model_line, value)

    vectors = {}
    lines = {}
    for name in VECTOR_NAMES:
        if name in entries:
            lineno, value = entries[name]
            vectors[name] = np.array(_numbers(path, lineno, name, value, 3))
            lines[name] = lineno
    for name in ("C", "A", "H", "V"):
        if name not in vectors:
            raise ModelFileError(path, model_line,
                                 f"the {name} vector is missing; expected a line '{name} = x y z'")

    if family is None:
        if "E" in vectors:
            raise ModelFileError(path, None,
                                 "an E vector but no 'Model = CAHVORE<type>[,linearity]' line; "
                                 "the CAHVORE type and linearity are needed")
        family = "CAHVOR" if ("O" in vectors or "R" in vectors) else "CAHV"
    need = {"CAHV": ("C", "A", "H", "V"), "CAHVOR": ("C", "A", "H", "V", "O", "R"),
            "CAHVORE": VECTOR_NAMES}[family]
    for name in need:
        if name not in vectors:
            raise ModelFileError(
                path, model_line,
                f"the {name} vector is missing: {family} needs it; expected '{name} = x y z'")
    for name in VECTOR_NAMES:
        if name in vectors and name not in need:
            raise ModelFileError(path, lines[name],
                                 f"{name} does not belong to a {family} model "
                                 f"(Model line {model_line})")

    if "Dimensions" not in entries:
        raise ModelFileError(path, None,
                             "the image size is missing; expected 'Dimensions = width height'")
    dlineno, dvalue = entries["Dimensions"]
    width, height = _numbers(path, dlineno, "Dimensions", dvalue, 2, integer=True)
    if width <= 0 or height <= 0:
        raise ModelFileError(
            path, dlineno, f"image size {width:g} x {height:g}; expected positive width and height")

    for name in ("A", "O"):
        if name in vectors:
            n = float(np.linalg.norm(vectors[name]))
            if abs(n - 1.0) > UNIT_TOLERANCE:
                raise ModelFileError(path, lines[name],
                                     f"|{name}| = {n:.9g}; expected a unit vector "
                                     f"(|{name}| within {UNIT_TOLERANCE:g} of 1)")
    A = vectors["A"] / np.linalg.norm(vectors["A"])
    for name in ("H", "V"):
        h = vectors[name]
        s = float(np.linalg.norm(h - (h @ A) * A))
        if not s > 1e-6 * float(np.linalg.norm(h)):
            raise ModelFileError(path, lines[name],
                                 f"A is parallel to {name} (focal length {name}s = {s:.3g} px); "
                                 f"expected {name} to have a component perpendicular to A")

    kw = dict(C=vectors["C"], A=vectors["A"], H=vectors["H"], V=vectors["V"],
              width=int(width), height=int(height))
    try:
        if family == "CAHV":
            model = CAHV(**kw)
        elif family == "CAHVOR":
            model = CAHVOR(**kw, O=vectors["O"], R=vectors["R"])
        else:
            model = CAHVORE(**kw, O=vectors["O"], R=vectors["R"], E=vectors["E"],
                            model_type=mtype, linearity=linearity)
    except ModelError as e:
        raise ModelFileError(path, _line_of_error(str(e), lines, dlineno, model_line),
                             str(e)) from None

    _check_derived(path, model, entries)
    nvec = len(need)
    if "S" in blocks:
        _check_block(path, "S", blocks["S"][0], blocks["S"][1], 3 * nvec)
    if "S internal" in blocks:
        _check_block(path, "S internal", blocks["S internal"][0], blocks["S internal"][1], 5)
    for name, (lineno, _) in blocks.items():
        if name not in ("S", "S internal"):
            raise ModelFileError(path, lineno, f"{name} has no value; expected '{name} = values'")
    return model


def _line_of_error(message, lines, dimensions_line, model_line):
    m = re.match(r"^A is parallel to (H|V)", message)
    if m:
        return lines.get(m.group(1))
    m = re.match(r"^(C|A|H|V|O|R|E) ", message)
    if m:
        return lines.get(m.group(1))
    if message.startswith("O points"):
        return lines.get("O")
    if message.startswith("H' and V'"):
        return lines.get("V")
    if message.startswith("image "):
        return dimensions_line
    if message.startswith("CAHVORE"):
        return model_line
    return None


def _check_derived(path, model, entries):
    ph = model.photogrammetric()
    computed = {"Hs": ph.Hs, "Hc": ph.Hc, "Vs": ph.Vs, "Vc": ph.Vc}
    for name in ("Hs", "Vs", "Hc", "Vc"):
        if name not in entries:
            continue
        lineno, value = entries[name]
        (x,) = _numbers(path, lineno, name, value.split("(")[0], 1)
        if name in ("Hs", "Vs") and x <= 0:
            raise ModelFileError(path, lineno,
                                 f"negative focal length {name} = {x!r}; expected {name} > 0")
        tol = DERIVED_TOLERANCE_PX + DERIVED_TOLERANCE_RELATIVE * abs(computed[name])
        if abs(x - computed[name]) > tol:
            raise ModelFileError(path, lineno,
                                 f"{name} = {x!r} disagrees with H, V, A, which give "
                                 f"{name} = {computed[name]:.9g}")
    if "Theta" in entries:
        lineno, value = entries["Theta"]
        (x,) = _numbers(path, lineno, "Theta", value.split("(")[0], 1)
        theta = jpl_theta(model)
        if (x < 0) != (theta < 0):
            raise ModelFileError(
                path, lineno,
                f"negative focal length: Theta = {x!r} says the camera is "
                f"{'ordinary' if x < 0 else 'mirrored'}, but H' x V' points "
                f"{'against' if theta > 0 else 'along'} A (H, V, A give Theta = {theta:.9g}); "
                "one image axis is flipped")
        if abs(x - theta) > THETA_TOLERANCE:
            raise ModelFileError(path, lineno,
                                 f"Theta = {x!r} disagrees with H, V, A, which give "
                                 f"Theta = {theta:.9g}")


def read_model(path):
    r'''Read a JPL camera-model file

SYNOPSIS

    m = read_model("navcam_left.cahvor")
    m.family     # "CAHV", "CAHVOR" or "CAHVORE"

The family comes from the Model line (or, without one, the vectors present),
not from the file's extension. Raises ModelFileError (naming the file, line and
what was expected) for anything malformed or degenerate: a missing vector, a
wrong count of numbers, a non-numeric or non-finite number, |A| far from 1, A
parallel to H or V, a negative focal length, an unknown CAHVORE type, an image
size <= 0.
'''
    path = os.fspath(path)
    try:
        text = Path(path).read_text()
    except FileNotFoundError:
        raise ModelFileError(path, None, "no such file") from None
    except IsADirectoryError:
        raise ModelFileError(path, None, "is a directory; expected a model file") from None
    except UnicodeDecodeError:
        raise ModelFileError(path, None, "is not a text file; expected a JPL model file") from None
    return parse_model_text(text, path)


# --- writing ------------------------------------------------------------------

def _f(x):
    return repr(float(x))


def _vec(name, v):
    return f"{name} = " + " ".join(_f(x) for x in v) + "\n"


def model_text(model, note=None):
    r'''The JPL file text of a model (what write_model writes)'''
    out = []
    if note:
        out += [f"# {line}\n" for line in str(note).splitlines()]
    if model.family == "CAHVORE":
        if model.model_type == 1:
            out.append("Model = CAHVORE1 = perspective, distortion, pupil\n")
        elif model.model_type == 2:
            out.append("Model = CAHVORE2 = fish-eye\n")
        else:
            out.append(f"Model = CAHVORE3,{_f(model.linearity)} = general\n")
    else:
        out.append(f"Model = {MODEL_LINE[model.family]}\n")
    out.append(f"Dimensions = {model.width} {model.height}\n")
    names = {"CAHV": "CAHV", "CAHVOR": "CAHVOR", "CAHVORE": "CAHVORE"}[model.family]
    for name in names:
        out.append(_vec(name, getattr(model, name)))
    n = 3 * len(names)
    # old JPL parsers require the covariance blocks; their values are unknown here
    out.append("S =\n" + ((" 0.0" * n) + "\n") * n)
    ph = model.photogrammetric()
    theta = jpl_theta(model)
    out.append(f"Hs    = {_f(ph.Hs)}\n")
    out.append(f"Hc    = {_f(ph.Hc)}\n")
    out.append(f"Vs    = {_f(ph.Vs)}\n")
    out.append(f"Vc    = {_f(ph.Vc)}\n")
    out.append(f"Theta = {_f(theta)} ({math.degrees(theta):.6f} deg)\n")
    out.append("S internal =\n" + ((" 0.0" * 5) + "\n") * 5)
    return "".join(out)


def write_model(model, path, *, overwrite=False, note=None):
    r'''Write a model as a JPL text file at full precision

SYNOPSIS

    write_model(m, "out.cahvor")                   # OutputExistsError if it exists
    write_model(m, "out.cahvor", overwrite=True)

The file reads back (read_model, mrcal.cameramodel) to exactly the same
numbers. note is written as '#' comment lines at the top.
'''
    path = os.fspath(path)
    if not overwrite and os.path.exists(path):
        raise OutputExistsError(
            f"'{path}' exists; not overwriting it (use --force / overwrite=True)")
    text = model_text(model, note)
    with open(path, "w") as f:
        f.write(text)
    return path
