r'''Calibration targets: exact board geometry and the Pattern a renderer draws

SYNOPSIS

    from targets.boards import load_target

    target = load_target("dots")       # or "apriltag", "chessboard", or a .toml path
    known_targets()                    # {name: file} of the built-in targets (targets/data)
    target.detector                    # the detector that finds it (targets.detect)
    p   = target.points()              # (N,3) surveyed points in the board frame, metres
    ids = target.point_ids()           # (N,) stable integer ids
    pattern = target.pattern()         # targets.pattern.Pattern for a renderer
    outline = target.outline()         # (M,3) points along the board's edge
    plan = target.planning_outline()   # (M,3) what a pose keeps in the image (targets.poses)
    dots = target.dot_outlines(1440)   # (N,1440,3) circle outlines (kind "dots" only)

A target is defined by a TOML file (targets/data/NAME.toml; read with
tomllib). The board frame is mrcal's: the board face is the plane z = 0, x to
the right and y down across its face, grid point (ix, iy) at
(ix*spacing, iy*spacing, 0), and a camera sees the board from z < 0.

Three kinds:

- "dots": the paper's JPL target, an nx x ny grid of dark dots on a light
  board. A few dots (the orientation mark) are larger, at grid positions that
  no rotation or flip of the grid maps onto themselves, so a detector can
  number the dots uniquely even through a mirrored camera. The points are the
  dot centres, id = iy*nx + ix.
- "apriltag": a Kalibr-style AprilGrid of tag36h11 tags; the points are the 4
  outer corners of each tag's black border, id = 4*tag_id + corner, the
  corners in pupil_apriltags' order (bottom-left, bottom-right, top-right,
  top-left of the upright tag, y down).
- "chessboard": mrcal's preferred target; the points are the inner corners,
  id = iy*nx + ix. Light dots in a few dark squares fix its orientation.

A target's geometry is one of these kinds; which detector finds it is a
separate choice: the key `detector` of its file names any detector of the
registry (targets.detect.known_detectors(): the built-in ones and plug-ins of
the entry-point group "camval.detectors"); without it, the built-in detector
of its kind. So a plug-in detector is used from a campaign through a target
file, e.g. kind = "chessboard" and detector = "my_chessboard" beside the
chessboard's geometry. The lists live in one place each: the geometry kinds
are the builders here (TARGET_KINDS), the named targets are the files of
targets/data (known_targets()), the detectors are targets.detect's registry.

The tag36h11 codes are read from the AprilTag 3 C library that pupil_apriltags
ships (AprilRobotics/apriltag, tag36h11.c), so the board draws exactly the
codes the detector decodes.
'''

import dataclasses
import functools
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from reference_models.errors import CamvalError

from .pattern import Pattern

DATA_DIR = Path(__file__).resolve().parent / "data"

# largest subdivision of a tag bit we accept to make the gap between tags a whole number of cells
MAX_BIT_SUBDIVISION = 20


class TargetError(CamvalError, ValueError):
    '''A target definition that cannot be used (bad file, bad numbers, wrong kind).'''


# ---------------------------------------------------------------------------------------------
# grid symmetries
def grid_transforms(na, nb, nx, ny):
    r'''The maps from a detected lattice (a, b) to board grid indices (ix, iy)

SYNOPSIS

    for swap, flip_a, flip_b in grid_transforms(na, nb, nx, ny):
        ix, iy = apply_grid_transform((swap, flip_a, flip_b), a, b, na, nb)

A lattice of na x nb points found in an image is the board's nx x ny grid seen
in one of up to 8 ways (the rotations and flips of a rectangle); these are the
ways compatible with the shapes: without swap when (na, nb) == (nx, ny), with
swap when (na, nb) == (ny, nx). Returns a list of (swap, flip_a, flip_b).
'''
    out = []
    for swap in (False, True):
        shape_ok = (na, nb) == ((ny, nx) if swap else (nx, ny))
        if not shape_ok:
            continue
        for flip_a in (False, True):
            for flip_b in (False, True):
                out.append((swap, flip_a, flip_b))
    return out


def apply_grid_transform(transform, a, b, na, nb):
    r'''(ix, iy) of lattice points (a, b) under one of grid_transforms()'''
    swap, flip_a, flip_b = transform
    a = np.asarray(a)
    b = np.asarray(b)
    if flip_a:
        a = na - 1 - a
    if flip_b:
        b = nb - 1 - b
    return (b, a) if swap else (a, b)


def _check_mark_asymmetric(positions, nx, ny, what, source):
    r'''Raise unless no nontrivial rotation/flip of the grid maps `positions` onto itself'''
    pos = {tuple(int(v) for v in p) for p in positions}
    a = np.array([p[0] for p in sorted(pos)])
    b = np.array([p[1] for p in sorted(pos)])
    for t in grid_transforms(nx, ny, nx, ny):
        if t == (False, False, False):
            continue
        ix, iy = apply_grid_transform(t, a, b, nx, ny)
        if {(int(i), int(j)) for i, j in zip(ix, iy, strict=True)} == pos:
            raise TargetError(
                f"{source}: the orientation mark {what} {sorted(pos)} is symmetric under a "
                f"rotation or flip of the {nx}x{ny} grid; expected positions that no rotation "
                f"or flip maps onto themselves")


# ---------------------------------------------------------------------------------------------
# tag36h11
@functools.lru_cache(maxsize=1)
def tag36h11_family():
    r'''The tag36h11 family from the AprilTag C library that pupil_apriltags ships

SYNOPSIS

    fam = tag36h11_family()
    fam["codes"]            # list of 587 ints (36-bit codes)
    fam["bit_x"], fam["bit_y"]   # 36 cell positions inside the black border

Read through ctypes from libapriltag's tag36h11_create(), so the board shows
exactly the codes the detector decodes.
'''
    import ctypes

    import pupil_apriltags
    from pupil_apriltags.bindings import _ApriltagFamily

    libdir = Path(pupil_apriltags.__file__).resolve().parent
    candidates = [p for pattern in ("lib*/libapriltag.so*", "lib*/*apriltag*.dylib",
                                    "lib*/*apriltag*.dll")
                  for p in sorted(libdir.glob(pattern))]
    if not candidates:
        raise TargetError(f"cannot find the AprilTag C library in {libdir}; "
                          "expected pupil_apriltags' libapriltag")
    lib = ctypes.CDLL(str(candidates[0]))
    lib.tag36h11_create.restype = ctypes.POINTER(_ApriltagFamily)
    lib.tag36h11_destroy.argtypes = [ctypes.POINTER(_ApriltagFamily)]
    ptr = lib.tag36h11_create()
    try:
        f = ptr.contents
        fam = {
            "codes": [int(f.codes[i]) for i in range(f.ncodes)],
            "nbits": int(f.nbits),
            "bit_x": [int(f.bit_x[i]) for i in range(f.nbits)],
            "bit_y": [int(f.bit_y[i]) for i in range(f.nbits)],
            "width_at_border": int(f.width_at_border),
            "total_width": int(f.total_width),
            "reversed_border": bool(f.reversed_border),
        }
    finally:
        lib.tag36h11_destroy(ptr)
    if fam["nbits"] != 36 or fam["width_at_border"] != 8 or fam["reversed_border"]:
        raise TargetError(f"unexpected tag36h11 layout in {candidates[0]}: {fam['nbits']} bits, "
                          f"border width {fam['width_at_border']}; expected 36 bits, width 8")
    return fam


def tag36h11_bits(tag_id):
    r'''The 8x8 cells of tag `tag_id` inside and including its black border

SYNOPSIS

    bits = tag36h11_bits(7)    # (8,8) bool, True = white; row 0 is the top of the upright tag
'''
    fam = tag36h11_family()
    if not 0 <= tag_id < len(fam["codes"]):
        raise TargetError(f"tag36h11 has ids 0..{len(fam['codes']) - 1}; got {tag_id}")
    w = fam["width_at_border"]
    bits = np.zeros((w, w), dtype=bool)
    code = fam["codes"][tag_id]
    nbits = fam["nbits"]
    for i in range(nbits):
        if (code >> (nbits - 1 - i)) & 1:
            bits[fam["bit_y"][i], fam["bit_x"][i]] = True
    return bits


# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Target:
    r'''A calibration target: surveyed points, their ids, and the pattern to draw

Build with load_target() or target_from_dict(). Fields:

- name, kind ("dots" | "apriltag" | "chessboard": the geometry), source (the file)
- detector: the name of the detector that finds it (targets.detect; default its kind)
- spec: the definition (TOML content with defaults), JSON-able
- extent: (xmin, xmax, ymin, ymax) of the board, metres
- grid_shape: (nx, ny) of the point grid (dots, chessboard), tags (apriltag)
'''

    name: str
    kind: str
    source: str
    spec: dict
    extent: tuple
    grid_shape: tuple
    _points: np.ndarray
    _ids: np.ndarray
    _radii: np.ndarray
    _pattern: Pattern
    detector: str = None

    def points(self):
        r'''(N,3) float64: the surveyed points in the board frame (metres)'''
        return self._points.copy()

    def point_ids(self):
        r'''(N,) int64: stable ids of the points, in the order of points()'''
        return self._ids.copy()

    def pattern(self):
        r'''The targets.pattern.Pattern a renderer draws'''
        return self._pattern

    @property
    def Npoints(self):
        return len(self._ids)

    def dot_radii(self):
        r'''(N,) float64: radius of each dot (metres); kind "dots" only'''
        self._require("dots", "dot_radii")
        return self._radii.copy()

    def dot_outlines(self, Noutline=1440):
        r'''Points along each dot's circle

SYNOPSIS

    p = target.dot_outlines(1440)   # (N,1440,3); p[i,k] at angle 2 pi k/1440 on dot i
'''
        self._require("dots", "dot_outlines")
        if int(Noutline) < 3:
            raise TargetError(f"a dot outline needs at least 3 points; got {Noutline}")
        t = np.arange(int(Noutline), dtype=np.float64) * (2.0 * math.pi / int(Noutline))
        c = self._points
        r = self._radii[:, None]
        return np.stack((c[:, 0:1] + r * np.cos(t), c[:, 1:2] + r * np.sin(t),
                         np.zeros((len(c), len(t)))), axis=-1)

    def outline(self, Nper_edge=16):
        r'''Points along the board's rectangular edge

SYNOPSIS

    p = target.outline(16)    # (4*16,3), z = 0, going round the board from (xmin, ymin)
'''
        return _rectangle_outline(self.extent, Nper_edge)

    def planning_extent(self):
        r'''(xmin, xmax, ymin, ymax), metres: the part of the board a calibration pose must
keep in the image for its detector to find every point (targets.poses plans by it)

SYNOPSIS

    target.planning_extent()     # chessboard 10x10, 0.1 m squares: (-0.1, 1.0, -0.1, 1.0)
    target.planning_outline(16)  # (4*16,3) points along it

A dot board and an AprilGrid: the printed board (extent). A chessboard found by its
built-in detector (targets.detect_chessboard): the inner corners grown by the reach of
the corner refinement's window, CHESSBOARD_CLEARANCE squares (targets.corners: the
window keeps short of the next feature it does not model, a square away; blurred, its
line strips keep short of it by the blur's reach and LINES_SLACK): the outer squares,
without the light margin beyond them, which the detector does not use. Measured
(docs/corners.md, "Planning a chessboard by its corners"), the image's edge cutting a
frontal board d px past its outermost corners on all four sides: OpenCV's board search
finds it from d = 9.5 px (squares of 12-30 px) to 12 px (60-100 px squares), which the
outer square and the planner's margin (2 % of the image, at least 4 px) hold; under a
1 px blur the refinement drops the outermost corners ("window off the image") up to
0.6-0.7 square past them (40 px squares), inside the outer square. A chessboard with a
plug-in detector: the printed board (its detector's needs are not known here).
'''
        if self.kind == "chessboard" and self.detector in (None, "chessboard"):
            from .corners import CHESSBOARD_CLEARANCE
            grow = CHESSBOARD_CLEARANCE * float(self.spec["square"])
            x, y = self._points[:, 0], self._points[:, 1]
            return (float(x.min()) - grow, float(x.max()) + grow,
                    float(y.min()) - grow, float(y.max()) + grow)
        return self.extent

    def planning_outline(self, Nper_edge=16):
        r'''Points along planning_extent(), going round it as outline() goes round the board'''
        return _rectangle_outline(self.planning_extent(), Nper_edge)

    def centre(self, extent=None):
        r'''(3,) the centre of the board rectangle (or of the rectangle extent)'''
        xmin, xmax, ymin, ymax = self.extent if extent is None else extent
        return np.array([(xmin + xmax) / 2, (ymin + ymax) / 2, 0.0])

    def size(self, extent=None):
        r'''(width, height) of the board (or of the rectangle extent), metres'''
        xmin, xmax, ymin, ymax = self.extent if extent is None else extent
        return (xmax - xmin, ymax - ymin)

    def as_dict(self):
        r'''A JSON-able description: the definition plus the number of points'''
        return {"name": self.name, "kind": self.kind, "detector": self.detector,
                "source": self.source, "extent": list(self.extent), "Npoints": self.Npoints,
                "spec": self.spec}

    def _require(self, kind, what):
        if self.kind != kind:
            raise TargetError(f"{what}() is defined for {kind!r} targets; "
                              f"target {self.name!r} is {self.kind!r}")


def _rectangle_outline(extent, Nper_edge):
    r'''(4*Nper_edge,3) points along the rectangle extent = (xmin, xmax, ymin, ymax), z = 0,
going round it from (xmin, ymin)'''
    n = int(Nper_edge)
    if n < 1:
        raise TargetError(f"need at least 1 point per edge; got {Nper_edge}")
    xmin, xmax, ymin, ymax = extent
    s = np.arange(n, dtype=np.float64) / n
    edges = [
        np.stack((xmin + s * (xmax - xmin), np.full(n, ymin)), axis=-1),
        np.stack((np.full(n, xmax), ymin + s * (ymax - ymin)), axis=-1),
        np.stack((xmax - s * (xmax - xmin), np.full(n, ymax)), axis=-1),
        np.stack((np.full(n, xmin), ymax - s * (ymax - ymin)), axis=-1),
    ]
    xy = np.concatenate(edges)
    return np.concatenate((xy, np.zeros((len(xy), 1))), axis=-1)


# ---------------------------------------------------------------------------------------------
def known_targets():
    r'''{name: path} of the built-in targets: the files targets/data/NAME.toml

SYNOPSIS

    known_targets()     # {"apriltag": Path(...), "chessboard": ..., "dots": ...}
'''
    return {p.stem: p for p in sorted(DATA_DIR.glob("*.toml"))}


def load_target(name_or_path):
    r'''Load a target by name (known_targets(): "dots", "apriltag", "chessboard") or from
a TOML file

SYNOPSIS

    target = load_target("dots")
    target = load_target("my/board.toml")
'''
    s = str(name_or_path)
    known = known_targets()
    if s in known:
        path = known[s]
    else:
        path = Path(s)
        if not path.is_file():
            raise TargetError(f"unknown target {s!r}: not a known name "
                              f"({', '.join(known)}) and no such file")
    try:
        with open(path, "rb") as f:
            spec = tomllib.load(f)
    except tomllib.TOMLDecodeError as e:
        raise TargetError(f"'{path}': not valid TOML ({e})") from None
    except OSError as e:
        raise TargetError(f"'{path}': cannot read ({e.strerror})") from None
    return target_from_dict(spec, source=str(path))


def target_from_dict(spec, source="<dict>"):
    r'''Build a Target from a definition (the content of a target TOML file)'''
    spec = dict(spec)
    kind = spec.get("kind")
    if kind not in TARGET_KINDS:
        raise TargetError(f"{source}: kind = {kind!r}; expected one of {', '.join(TARGET_KINDS)}"
                          f" (the board geometries; a plug-in detector is named by the key "
                          f"detector)")
    spec.setdefault("name", Path(source).stem if source != "<dict>" else kind)
    detector = _detector_name(spec, kind, source)
    target = _BUILDERS[kind](spec, source)
    return dataclasses.replace(target, detector=detector)


def _detector_name(spec, kind, source):
    r'''The detector a target file names (key "detector", default its kind), checked
against the registry of targets.detect'''
    name = spec.get("detector", kind)
    if name == kind:
        return name
    if not isinstance(name, str) or not name:
        raise TargetError(f"{source}: detector = {name!r}; expected a detector's name")
    from .detect import known_detectors
    known = known_detectors()
    if name not in known:
        raise TargetError(f"{source}: detector = {name!r} is not registered; known "
                          f"detectors: {', '.join(known)} (plug-ins register under the "
                          f"entry-point group 'camval.detectors')")
    return name


def _get(spec, key, source, kind=float, positive=False, nonneg=False, default=None, albedo=False):
    if key not in spec:
        if default is None:
            raise TargetError(f"{source}: missing '{key}'")
        spec[key] = default
    v = spec[key]
    if kind is int:
        if isinstance(v, bool) or not isinstance(v, int):
            raise TargetError(f"{source}: '{key}' = {v!r}; expected an integer")
    else:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise TargetError(f"{source}: '{key}' = {v!r}; expected a finite number")
        v = float(v)
    if positive and not v > 0:
        raise TargetError(f"{source}: '{key}' = {v!r}; expected a value > 0")
    if nonneg and not v >= 0:
        raise TargetError(f"{source}: '{key}' = {v!r}; expected a value >= 0")
    if albedo and not 0.0 <= v <= 1.0:
        raise TargetError(f"{source}: '{key}' = {v!r}; expected an albedo in [0, 1]")
    return v


def _albedos(spec, source, dark_key):
    board = _get(spec, "board_albedo", source, albedo=True, default=0.9)
    dark = _get(spec, dark_key, source, albedo=True, default=0.1)
    bg = _get(spec, "background_albedo", source, albedo=True, default=0.0)
    if not board - dark > 0.05:
        raise TargetError(f"{source}: board_albedo {board} must exceed {dark_key} {dark} "
                          "by more than 0.05 (dark marks on a light board)")
    return board, dark, bg


def _grid_positions(spec_list, nx, ny, source, what):
    try:
        pos = np.array(spec_list, dtype=np.int64).reshape(-1, 2)
    except (TypeError, ValueError):
        raise TargetError(f"{source}: orientation_mark {what} = {spec_list!r}; "
                          "expected a list of [ix, iy] pairs") from None
    if len(pos) == 0 or np.any(pos < 0) or np.any(pos[:, 0] >= nx) or np.any(pos[:, 1] >= ny):
        raise TargetError(f"{source}: orientation_mark {what} {pos.tolist()} must be non-empty "
                          f"and inside the {nx}x{ny} grid")
    if len({tuple(p) for p in pos.tolist()}) != len(pos):
        raise TargetError(f"{source}: orientation_mark {what} repeats a position")
    return pos


def _build_dots(spec, source):
    nx = _get(spec, "nx", source, kind=int)
    ny = _get(spec, "ny", source, kind=int)
    if nx < 1 or ny < 1:
        raise TargetError(f"{source}: grid {nx}x{ny}; expected nx, ny >= 1")
    spacing = _get(spec, "spacing", source, positive=True)
    d = _get(spec, "dot_diameter", source, positive=True)
    if (nx > 1 or ny > 1) and not d < spacing:
        raise TargetError(f"{source}: dot_diameter {d} must be smaller than spacing {spacing}")
    margin = _get(spec, "margin", source, positive=True, default=spacing)
    board, dark, bg = _albedos(spec, source, "dot_albedo")
    radii = np.full(nx * ny, d / 2)
    mark = spec.get("orientation_mark")
    if mark is not None:
        mark = dict(mark)
        dm = _get(mark, "dot_diameter", source + " orientation_mark", positive=True)
        if not dm > 1.2 * d:
            raise TargetError(f"{source}: orientation_mark dot_diameter {dm} must exceed 1.2 x "
                              f"dot_diameter ({1.2 * d:.4g}) to be recognisable")
        if (nx > 1 or ny > 1) and not dm < spacing:
            raise TargetError(f"{source}: orientation_mark dot_diameter {dm} must be smaller "
                              f"than spacing {spacing}")
        pos = _grid_positions(mark.get("dots"), nx, ny, source, "dots")
        _check_mark_asymmetric(pos, nx, ny, "dots", source)
        radii[pos[:, 1] * nx + pos[:, 0]] = dm / 2
        mark["dots"] = pos.tolist()
        spec["orientation_mark"] = mark
    if not margin > radii.max():
        raise TargetError(f"{source}: margin {margin} must exceed the largest dot radius "
                          f"{radii.max()}")
    iy, ix = np.mgrid[0:ny, 0:nx]
    p = np.stack((ix.ravel() * spacing, iy.ravel() * spacing, np.zeros(nx * ny)), axis=-1)
    extent = (-margin, (nx - 1) * spacing + margin, -margin, (ny - 1) * spacing + margin)
    pattern = Pattern(extent=extent, board_value=board, background_value=bg,
                      circles=np.column_stack((p[:, :2], radii)), circle_value=dark)
    return Target(name=str(spec["name"]), kind="dots", source=source, spec=spec, extent=extent,
                  grid_shape=(nx, ny), _points=p, _ids=np.arange(nx * ny, dtype=np.int64),
                  _radii=radii, _pattern=pattern)


def _build_chessboard(spec, source):
    nx = _get(spec, "nx", source, kind=int)
    ny = _get(spec, "ny", source, kind=int)
    if nx < 2 or ny < 2:
        raise TargetError(f"{source}: {nx}x{ny} inner corners; expected nx, ny >= 2")
    sq = _get(spec, "square", source, positive=True)
    margin = _get(spec, "margin", source, positive=True, default=sq)
    board, dark, bg = _albedos(spec, source, "dark_albedo")
    # squares sx in 0..nx, sy in 0..ny; dark when sx + sy is even
    sy, sx = np.mgrid[0:ny + 1, 0:nx + 1]
    cells = np.where((sx + sy) % 2 == 0, dark, board).astype(np.float64)
    circles = None
    mark = spec.get("orientation_mark")
    if mark is not None:
        mark = dict(mark)
        dm = _get(mark, "dot_diameter", source + " orientation_mark", positive=True)
        if not dm < 0.6 * sq:
            raise TargetError(f"{source}: orientation_mark dot_diameter {dm} must be below "
                              f"0.6 x square ({0.6 * sq:.4g}) to leave the corners clear")
        pos = _grid_positions(mark.get("squares"), nx + 1, ny + 1, source, "squares")
        if np.any(pos < 1) or np.any(pos[:, 0] > nx - 1) or np.any(pos[:, 1] > ny - 1):
            raise TargetError(f"{source}: orientation_mark squares {pos.tolist()} must be interior "
                              f"squares (1..{nx - 1}, 1..{ny - 1})")
        if np.any(pos.sum(axis=1) % 2 != 0):
            raise TargetError(f"{source}: orientation_mark squares {pos.tolist()} must be dark "
                              "squares (sx + sy even)")
        _check_mark_asymmetric(pos, nx + 1, ny + 1, "squares", source)
        centres = (pos - 0.5) * sq
        circles = np.column_stack((centres, np.full(len(pos), dm / 2)))
        mark["squares"] = pos.tolist()
        spec["orientation_mark"] = mark
    iy, ix = np.mgrid[0:ny, 0:nx]
    p = np.stack((ix.ravel() * sq, iy.ravel() * sq, np.zeros(nx * ny)), axis=-1)
    extent = (-sq - margin, nx * sq + margin, -sq - margin, ny * sq + margin)
    pattern = Pattern(extent=extent, board_value=board, background_value=bg, cells=cells,
                      cell_origin=(-sq, -sq), cell_size=sq, circles=circles, circle_value=board)
    return Target(name=str(spec["name"]), kind="chessboard", source=source, spec=spec,
                  extent=extent, grid_shape=(nx, ny), _points=p,
                  _ids=np.arange(nx * ny, dtype=np.int64), _radii=None, _pattern=pattern)


def _build_apriltag(spec, source):
    family = spec.get("family", "tag36h11")
    if family != "tag36h11":
        raise TargetError(f"{source}: family {family!r}; only 'tag36h11' is supported")
    spec["family"] = family
    nx = _get(spec, "nx", source, kind=int)
    ny = _get(spec, "ny", source, kind=int)
    if nx < 1 or ny < 1:
        raise TargetError(f"{source}: {nx}x{ny} tags; expected nx, ny >= 1")
    s = _get(spec, "tag_size", source, positive=True)
    ratio = _get(spec, "tag_spacing", source, positive=True, default=0.3)
    first_id = _get(spec, "first_id", source, kind=int, default=0)
    board, dark, bg = _albedos(spec, source, "dark_albedo")
    ncodes = len(tag36h11_family()["codes"])
    if first_id < 0 or first_id + nx * ny > ncodes:
        raise TargetError(f"{source}: tags {first_id}..{first_id + nx * ny - 1} do not exist; "
                          f"tag36h11 has ids 0..{ncodes - 1}")
    bit = s / 8.0
    gap_bits = 8.0 * ratio
    # cells must tile both tag bits and gaps: subdivide a bit k times
    for k in range(1, MAX_BIT_SUBDIVISION + 1):
        if abs(gap_bits * k - round(gap_bits * k)) < 1e-9:
            break
    else:
        raise TargetError(f"{source}: tag_spacing {ratio} makes a gap of {gap_bits:.6g} tag bits; "
                          f"expected a multiple of 1/{MAX_BIT_SUBDIVISION} bit (e.g. 0.25, 0.3)")
    margin = _get(spec, "margin", source, positive=True, default=max(ratio * s, 2 * bit))
    if not margin >= bit:
        raise TargetError(f"{source}: margin {margin} must be at least one tag bit ({bit:.4g} m) "
                          "of light board around the tags")
    gap_cells = int(round(gap_bits * k))
    tag_cells = 8 * k
    pitch_cells = tag_cells + gap_cells
    cells = np.full((ny * pitch_cells - gap_cells, nx * pitch_cells - gap_cells), np.nan)
    pitch = s * (1.0 + ratio)
    corners = np.array([[0.0, s], [s, s], [s, 0.0], [0.0, 0.0]])   # pupil_apriltags' order
    pts, ids = [], []
    for j in range(ny):
        for i in range(nx):
            tag_id = first_id + j * nx + i
            bits = tag36h11_bits(tag_id)
            block = np.where(np.kron(bits, np.ones((k, k), dtype=bool)), board, dark)
            cells[j * pitch_cells:j * pitch_cells + tag_cells,
                  i * pitch_cells:i * pitch_cells + tag_cells] = block
            origin = np.array([i * pitch, j * pitch])
            pts.append(origin + corners)
            ids.append(4 * tag_id + np.arange(4))
    xy = np.concatenate(pts)
    p = np.column_stack((xy, np.zeros(len(xy))))
    width = nx * pitch - ratio * s
    height = ny * pitch - ratio * s
    extent = (-margin, width + margin, -margin, height + margin)
    pattern = Pattern(extent=extent, board_value=board, background_value=bg, cells=cells,
                      cell_origin=(0.0, 0.0), cell_size=bit / k)
    return Target(name=str(spec["name"]), kind="apriltag", source=source, spec=spec,
                  extent=extent, grid_shape=(nx, ny), _points=p,
                  _ids=np.concatenate(ids).astype(np.int64), _radii=None, _pattern=pattern)


# the geometry kinds: one builder each (a target's detector is chosen apart, by name)
_BUILDERS = {"dots": _build_dots, "apriltag": _build_apriltag, "chessboard": _build_chessboard}
TARGET_KINDS = tuple(_BUILDERS)
