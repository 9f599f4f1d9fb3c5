r'''Terrain scenes: 2.5-D height fields with an albedo texture and a sun

SYNOPSIS

    from targets.terrain import Sun, make_terrain, ground_pose

    terrain = make_terrain(extent=(-1, 15, -8, 8), cell=0.05, texel=0.01, seed=3,
                           sun=Sun(azimuth_deg=120, elevation_deg=35))
    terrain.heights      # (Ny,Nx) float64 node heights (m), z up
    terrain.albedo       # (Ty,Tx) float32 in [0,1] over the same extent
    terrain.height_at(x, y)   # the surface itself (x, y broadcast; metres)

    Rt_ref_terrain = ground_pose(height_m=0.53)   # (4,3): terrain in a z-DOWN rover frame

The terrain frame has x, y horizontal and z UP; node (i, j) of the grid is at
x = x0 + i*cell, y = y0 + j*cell with height heights[j, i]. The surface is the
TRIANGLE PAIR of each cell, split along the diagonal from node (i, j) to node
(i+1, j+1): with u = (x - x_i)/cell and v = (y - y_j)/cell,

    u >= v:  z = h00 + u (h10 - h00) + v (h11 - h10)
    u <  v:  z = h00 + v (h01 - h00) + u (h11 - h01)

(hab = heights[j+b, i+a]). The ray caster (renderers/raycast_terrain.py)
intersects exactly this surface. The albedo image covers the rectangle of the
grid, texel (ti, tj) centred at x0 + (ti + 1/2) * width / Tx, and is sampled
bilinearly.

Height fields come from a data file (Terrain.from_file: a 16-bit PNG or .npy
grid times a height scale), an analytic function (Terrain.from_function), or
are generated (make_terrain: multi-scale value noise plus scattered rocks,
which are bumps with a darker albedo). Everything generated is deterministic
for a seed.

The sun is given by azimuth (degrees from +x towards +y) and elevation above
the horizontal plane; Sun.direction() is the unit vector towards it.
'''

import math
from dataclasses import dataclass, field

import numpy as np

from reference_models.errors import CamvalError


class TerrainError(CamvalError):
    '''A terrain description (file, grid, texture, sun) that cannot be used.'''


@dataclass(frozen=True)
class Sun:
    r'''The sun: azimuth from +x towards +y, elevation above the terrain's plane (degrees)'''

    azimuth_deg: float = 135.0
    elevation_deg: float = 35.0

    def __post_init__(self):
        if not (0.0 < self.elevation_deg <= 90.0):
            raise TerrainError(f"sun elevation {self.elevation_deg!r} deg must be in (0, 90]")

    def direction(self):
        r'''Unit vector towards the sun in the terrain frame (z up); shape (3,)'''
        az, el = math.radians(self.azimuth_deg), math.radians(self.elevation_deg)
        return np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])


@dataclass(frozen=True, eq=False)
class Terrain:
    r'''A height field, its albedo texture, the sun and the lighting levels

heights: (Ny,Nx) node heights (m, z up), Ny, Nx >= 2
cell:    node spacing (m)
origin:  (x0, y0), the position of node (0, 0)
albedo:  (Ty,Tx) reflectance in [0,1] covering the grid's rectangle
sun:     Sun
ambient: sky light added to every point (as a fraction of the sun's irradiance)
'''

    heights: np.ndarray
    cell: float
    origin: tuple = (0.0, 0.0)
    albedo: np.ndarray = None
    sun: Sun = field(default_factory=Sun)
    ambient: float = 0.15
    description: str = ""

    def __post_init__(self):
        h = np.ascontiguousarray(self.heights, dtype=np.float64)
        if h.ndim != 2 or min(h.shape) < 2:
            raise TerrainError(f"a height field needs a (Ny,Nx) grid with Ny, Nx >= 2; "
                               f"got shape {h.shape}")
        if not np.all(np.isfinite(h)):
            raise TerrainError("the height field has non-finite heights")
        if not (self.cell > 0 and math.isfinite(self.cell)):
            raise TerrainError(f"cell size must be > 0 m; got {self.cell!r}")
        a = np.full((1, 1), 0.5, np.float32) if self.albedo is None else self.albedo
        a = np.ascontiguousarray(a, dtype=np.float32)
        if a.ndim != 2 or not np.all(np.isfinite(a)) or a.min() < 0 or a.max() > 1:
            raise TerrainError("albedo must be a (Ty,Tx) image with values in [0,1]")
        if not (0.0 <= self.ambient <= 1.0):
            raise TerrainError(f"ambient must be in [0,1]; got {self.ambient!r}")
        h.setflags(write=False)
        a.setflags(write=False)
        object.__setattr__(self, "heights", h)
        object.__setattr__(self, "albedo", a)
        object.__setattr__(self, "origin", (float(self.origin[0]), float(self.origin[1])))
        object.__setattr__(self, "cell", float(self.cell))

    # --- construction -------------------------------------------------------
    @classmethod
    def from_function(cls, f, extent, cell, **kw):
        r'''Sample z = f(x, y) (numpy-broadcasting) on the nodes of a grid over
extent = (xmin, xmax, ymin, ymax)'''
        x, y = _node_axes(extent, cell)
        z = np.asarray(f(x[None, :], y[:, None]), dtype=np.float64)
        z = np.broadcast_to(z, (y.size, x.size))
        return cls(heights=z, cell=cell, origin=(x[0], y[0]), **kw)

    @classmethod
    def from_file(cls, path, cell, height_scale=1.0, height_offset=0.0, origin=(0.0, 0.0), **kw):
        r'''Read a height grid from a .npy array or a 16-bit (or 8-bit) PNG

height = value * height_scale + height_offset; row j of the file is y = y0 + j*cell.
'''
        return cls(heights=load_height_grid(path) * height_scale + height_offset,
                   cell=cell, origin=origin, **kw)

    def replace(self, **kw):
        import dataclasses
        return dataclasses.replace(self, **kw)

    # --- geometry -------------------------------------------------------------
    @property
    def shape(self):
        return self.heights.shape

    def extent(self):
        r'''(xmin, xmax, ymin, ymax) of the grid (m)'''
        ny, nx = self.heights.shape
        x0, y0 = self.origin
        return (x0, x0 + (nx - 1) * self.cell, y0, y0 + (ny - 1) * self.cell)

    def height_at(self, x, y):
        r'''The surface height at (x, y), NaN outside the grid

SYNOPSIS

    z = terrain.height_at(x, y)   # x, y broadcast; z has their broadcast shape
'''
        x, y = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64))
        ny, nx = self.heights.shape
        gx = (x - self.origin[0]) / self.cell
        gy = (y - self.origin[1]) / self.cell
        inside = (gx >= 0) & (gx <= nx - 1) & (gy >= 0) & (gy <= ny - 1)
        i = np.clip(np.floor(np.where(inside, gx, 0)), 0, nx - 2).astype(int)
        j = np.clip(np.floor(np.where(inside, gy, 0)), 0, ny - 2).astype(int)
        u, v = gx - i, gy - j
        h = self.heights
        h00, h10, h01, h11 = h[j, i], h[j, i + 1], h[j + 1, i], h[j + 1, i + 1]
        z = np.where(u >= v, h00 + u * (h10 - h00) + v * (h11 - h10),
                     h00 + v * (h01 - h00) + u * (h11 - h01))
        return np.where(inside, z, np.nan)

    def albedo_at(self, x, y):
        r'''Bilinear albedo at (x, y) (clamped at the grid's edge)'''
        xmin, xmax, ymin, ymax = self.extent()
        ty, tx = self.albedo.shape
        fx = np.clip((np.asarray(x) - xmin) / (xmax - xmin) * tx - 0.5, 0, tx - 1)
        fy = np.clip((np.asarray(y) - ymin) / (ymax - ymin) * ty - 0.5, 0, ty - 1)
        i = np.minimum(np.floor(fx).astype(int), max(tx - 2, 0))
        j = np.minimum(np.floor(fy).astype(int), max(ty - 2, 0))
        a = self.albedo
        i1, j1 = np.minimum(i + 1, tx - 1), np.minimum(j + 1, ty - 1)
        u, v = fx - i, fy - j
        return ((1 - v) * ((1 - u) * a[j, i] + u * a[j, i1])
                + v * ((1 - u) * a[j1, i] + u * a[j1, i1]))

    def as_dict(self):
        return {"kind": "terrain", "shape": list(self.heights.shape), "cell_m": self.cell,
                "origin": list(self.origin), "extent": list(self.extent()),
                "texture_shape": list(self.albedo.shape),
                "height_range_m": [float(self.heights.min()), float(self.heights.max())],
                "sun": {"azimuth_deg": self.sun.azimuth_deg,
                        "elevation_deg": self.sun.elevation_deg},
                "ambient": self.ambient, "description": self.description}


def _node_axes(extent, cell):
    xmin, xmax, ymin, ymax = (float(v) for v in extent)
    if not (xmax > xmin and ymax > ymin and cell > 0):
        raise TerrainError(f"extent {extent!r} must be (xmin, xmax, ymin, ymax) with "
                           f"xmax > xmin, ymax > ymin, and cell > 0")
    nx = int(math.ceil((xmax - xmin) / cell - 1e-9)) + 1
    ny = int(math.ceil((ymax - ymin) / cell - 1e-9)) + 1
    return xmin + cell * np.arange(nx), ymin + cell * np.arange(ny)


def load_height_grid(path):
    r'''A (Ny,Nx) float64 grid from .npy or a single-channel 8/16-bit PNG'''
    from pathlib import Path
    p = Path(path)
    if not p.is_file():
        raise TerrainError(f"height field '{p}' does not exist")
    suffix = p.suffix.lower()
    if suffix == ".npy":
        try:
            z = np.load(p, allow_pickle=False)
        except ValueError as e:
            raise TerrainError(f"'{p}': not a numeric .npy array ({e})") from None
    elif suffix == ".png":
        import cv2
        z = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        if z is None:
            raise TerrainError(f"'{p}': not a readable PNG")
        if z.ndim != 2 or z.dtype not in (np.uint8, np.uint16):
            raise TerrainError(f"'{p}': a height PNG must be single-channel 8 or 16 bit; "
                               f"got shape {z.shape}, {z.dtype}")
    else:
        raise TerrainError(f"'{p}': unknown height-field format {suffix!r}; known: .npy, .png")
    if z.ndim != 2 or z.dtype.kind not in "iuf":
        raise TerrainError(f"'{p}': expected a 2-D numeric grid; got shape {z.shape}, {z.dtype}")
    return z.astype(np.float64)


def load_texture(path):
    r'''A grey albedo image in [0,1] from an 8/16-bit image file (colour is averaged)'''
    import cv2
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise TerrainError(f"texture '{path}' is not a readable image")
    if img.dtype not in (np.uint8, np.uint16):
        raise TerrainError(f"texture '{path}' must be 8 or 16 bit; got {img.dtype}")
    scale = 255.0 if img.dtype == np.uint8 else 65535.0
    img = img.astype(np.float32) / scale
    if img.ndim == 3:
        img = img[..., :3].mean(axis=-1)
    return img


# --- generation ------------------------------------------------------------
def value_noise(shape, wavelength_px, rng):
    r'''Smooth noise of unit variance-ish: random lattice every `wavelength_px`
samples, bicubically interpolated to shape (Ny,Nx)'''
    import cv2
    ny, nx = shape
    w = max(float(wavelength_px), 1.0)
    gy, gx = int(math.ceil(ny / w)) + 3, int(math.ceil(nx / w)) + 3
    lattice = rng.standard_normal((gy, gx)).astype(np.float32)
    if w <= 1.0:
        return lattice[:ny, :nx].astype(np.float64)
    up = cv2.resize(lattice, (int(round(gx * w)), int(round(gy * w))),
                    interpolation=cv2.INTER_CUBIC)
    off = int(w)
    return up[off:off + ny, off:off + nx].astype(np.float64)


def fractal_noise(shape, base_wavelength_px, octaves, persistence, rng):
    r'''Sum of value noise octaves, wavelengths halving and amplitudes * persistence'''
    out = np.zeros(shape)
    amp, wl, norm = 1.0, float(base_wavelength_px), 0.0
    for _ in range(octaves):
        out += amp * value_noise(shape, wl, rng)
        norm += amp * amp
        amp *= persistence
        wl /= 2.0
        if wl < 1.0:
            break
    return out / math.sqrt(norm)


def make_terrain(extent=(-1.0, 15.0, -8.0, 8.0), cell=0.05, texel=0.01, seed=0,
                 relief_m=0.25, relief_wavelength_m=6.0, rocks_per_m2=0.25,
                 rock_radius_m=(0.04, 0.3), sun=None, ambient=0.15, texture=None, grain=0.8):
    r'''A generated terrain: fractal relief, scattered rocks, a granular albedo

SYNOPSIS

    t = make_terrain(extent=(xmin, xmax, ymin, ymax), cell=0.05, texel=0.01, seed=0)

relief_m:    std of the smooth relief (m), largest wavelength relief_wavelength_m
rocks_per_m2, rock_radius_m: rock density and radius range; a rock is the cap
             z = 0.6 R sqrt(1 - r^2/R^2) on the relief, with albedo 0.6x that of soil
texel:       size of one albedo texel (m); the soil albedo is multi-scale value
             noise from 1 m down to single texels (grains)
grain:       amplitude ratio of successive octaves of the soil albedo (halving
             wavelengths): larger keeps more contrast at the finest scales
texture:     an albedo image (e.g. load_texture(path)) to use instead of the generated one
Everything is drawn from numpy's default_rng(seed).
'''
    rng = np.random.default_rng(seed)
    x, y = _node_axes(extent, cell)
    shape = (y.size, x.size)
    z = relief_m * fractal_noise(shape, relief_wavelength_m / cell, 6, 0.45, rng)

    xmin, xmax, ymin, ymax = x[0], x[-1], y[0], y[-1]
    area = (xmax - xmin) * (ymax - ymin)
    nrocks = rng.poisson(rocks_per_m2 * area) if rocks_per_m2 > 0 else 0
    r_lo, r_hi = rock_radius_m
    # a power law: many small rocks, few big ones
    radii = r_lo * (r_hi / r_lo) ** (rng.random(nrocks) ** 2)
    rx = rng.uniform(xmin, xmax, nrocks)
    ry = rng.uniform(ymin, ymax, nrocks)
    rock = np.zeros(shape)
    for cx, cy, r in zip(rx, ry, radii, strict=True):
        i0, i1 = np.searchsorted(x, [cx - r, cx + r])
        j0, j1 = np.searchsorted(y, [cy - r, cy + r])
        if i1 <= i0 or j1 <= j0:
            continue
        d2 = (x[None, i0:i1] - cx) ** 2 + (y[j0:j1, None] - cy) ** 2
        cap = 0.6 * r * np.sqrt(np.clip(1 - d2 / (r * r), 0, None))
        np.maximum(rock[j0:j1, i0:i1], cap, out=rock[j0:j1, i0:i1])
    z = z + rock

    if texture is None:
        tx = int(round((xmax - xmin) / texel))
        ty = int(round((ymax - ymin) / texel))
        soil = 0.42 + 0.11 * fractal_noise((ty, tx), 1.0 / texel, 12, grain, rng)
        # rock albedo: darker, with its own speckle, drawn at texel resolution
        txc = xmin + (np.arange(tx) + 0.5) * (xmax - xmin) / tx
        tyc = ymin + (np.arange(ty) + 0.5) * (ymax - ymin) / ty
        dark = np.ones((ty, tx), np.float32)
        for cx, cy, r in zip(rx, ry, radii, strict=True):
            i0, i1 = np.searchsorted(txc, [cx - r, cx + r])
            j0, j1 = np.searchsorted(tyc, [cy - r, cy + r])
            if i1 <= i0 or j1 <= j0:
                continue
            d2 = (txc[None, i0:i1] - cx) ** 2 + (tyc[j0:j1, None] - cy) ** 2
            np.minimum(dark[j0:j1, i0:i1], np.where(d2 < r * r, 0.6, 1.0),
                       out=dark[j0:j1, i0:i1])
        albedo = np.clip(soil * dark, 0.02, 0.98).astype(np.float32)
    else:
        albedo = np.asarray(texture, np.float32)
    return Terrain(heights=z, cell=cell, origin=(xmin, ymin), albedo=albedo,
                   sun=sun if sun is not None else Sun(), ambient=ambient,
                   description=f"generated: seed {seed}, relief {relief_m} m, "
                               f"{nrocks} rocks, texel {texel} m")


# --- placement --------------------------------------------------------------
def ground_pose(height_m, pitch_deg=0.0, yaw_deg=0.0):
    r'''Place a terrain (z up) under a z-DOWN frame (JPL rover, mast)

SYNOPSIS

    Rt_ref_terrain = ground_pose(height_m=0.53, pitch_deg=0)
    # (4,3); p_ref = p_terrain @ Rt[:3].T + Rt[3]

The terrain's x is the frame's x (forward), its y the frame's -y, its z the
frame's -z; its z = 0 plane lies height_m below the frame's origin. pitch_deg
> 0 means the frame is pitched DOWN (a mast looking down), so the ground
appears rotated up in it; yaw_deg turns the frame about the vertical.
'''
    flip = np.diag([1.0, -1.0, -1.0])
    Rt_level_terrain = np.vstack((flip, [0.0, 0.0, height_m]))
    p = math.radians(pitch_deg)
    yw = math.radians(yaw_deg)
    # frame axes in the level (z-down) frame: pitch down about y, then yaw about z
    Ry = np.array([[math.cos(p), 0, -math.sin(p)], [0, 1, 0], [math.sin(p), 0, math.cos(p)]])
    Rz = np.array([[math.cos(yw), -math.sin(yw), 0], [math.sin(yw), math.cos(yw), 0], [0, 0, 1]])
    R_level_frame = Rz @ Ry
    R_frame_level = R_level_frame.T
    R = R_frame_level @ Rt_level_terrain[:3]
    t = R_frame_level @ Rt_level_terrain[3]
    return np.vstack((R, t))
