r'''What a renderer needs to draw a planar calibration target

A Pattern is a plain value describing a board in its own frame (metres):
the board lies in the plane z = 0, x to the right and y down across its face
(as mrcal's calibration objects: point (i, j) of a grid is at
(i*spacing, j*spacing, 0)); the camera sees it from z < 0. Both faces look the
same. The albedo at a board point (x, y) is, in painting order:

1. background_value outside the board rectangle `extent`;
2. board_value inside it;
3. cells[iy, ix] inside the square cell (ix, iy) of the cell grid (origin
   cell_origin, side cell_size) when that value is finite (NaN: transparent);
4. circle_value inside any circle (cx, cy, r) of `circles`.

Non-finite points (a ray that misses the board plane) get background_value.
Albedo lies in [0, 1]; the rendered image of a flat, unlit board is the
area-average of the albedo over each pixel's footprint.
'''

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class Pattern:
    extent: tuple            # (xmin, xmax, ymin, ymax) of the board, metres
    board_value: float = 1.0
    background_value: float = 0.0
    cells: np.ndarray = None      # (ny, nx) float64 albedo; NaN = transparent
    cell_origin: tuple = (0.0, 0.0)
    cell_size: float = 0.0
    circles: np.ndarray = None    # (N,3) float64: cx, cy, r
    circle_value: float = 0.0

    def albedo(self, x, y):
        r'''Reference (slow, numpy) evaluation of the albedo at board points

SYNOPSIS

    a = pattern.albedo(x, y)   # x, y broadcast; a has their shape
'''
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        xmin, xmax, ymin, ymax = self.extent
        inside = (x >= xmin) & (x < xmax) & (y >= ymin) & (y < ymax)
        a = np.where(inside, self.board_value, self.background_value)
        if self.cells is not None:
            # off-board points (also NaN, inf) never index a cell: cast only finite values
            fx = np.where(inside, (x - self.cell_origin[0]) / self.cell_size, -1.0)
            fy = np.where(inside, (y - self.cell_origin[1]) / self.cell_size, -1.0)
            ix = np.floor(fx).astype(np.int64)
            iy = np.floor(fy).astype(np.int64)
            ny, nx = self.cells.shape
            ok = inside & (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
            v = self.cells[np.clip(iy, 0, ny - 1), np.clip(ix, 0, nx - 1)]
            a = np.where(ok & np.isfinite(v), v, a)
        if self.circles is not None and len(self.circles):
            c = self.circles
            xs = np.where(inside, x, 0.0)[..., None]
            ys = np.where(inside, y, 0.0)[..., None]
            d2 = (xs - c[:, 0]) ** 2 + (ys - c[:, 1]) ** 2
            hit = inside & np.any(d2 <= c[:, 2] ** 2, axis=-1)
            a = np.where(hit, self.circle_value, a)
        return a
