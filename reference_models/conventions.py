r'''The pixel convention of camval, written down once

Pixel coordinates q = (x, y) are JPL's and mrcal's:

- x is the sample (column) index and grows to the right; y is the line (row)
  index and grows downwards.
- The CENTRE of the top-left pixel is q = (0, 0). That pixel covers
  [-0.5, 0.5) x [-0.5, 0.5); the image of width W covers x in [-0.5, W-0.5).
- Pixel (ix, iy) of an image array is img[iy, ix] and its centre is at
  q = (ix, iy).

Alternatives named and rejected:

- "corner" convention (q = (0,0) at the top-left CORNER of the top-left pixel,
  centres at half-integers): used by OpenGL window coordinates and POV-Ray's
  screen mapping. A renderer that uses it without converting is off by exactly
  (0.5, 0.5) px; camval's tests and the gate exist to catch that slip.
- 1-based indexing (VICAR lines/samples start at 1): PDS labels give camera
  models in 0-based coordinates already; nothing here is 1-based.

Every renderer adapter has a test proving its offset against this convention:
a small dot rendered at a known point must have its centroid at the exact
expected image position.
'''

import numpy as np

# Offset of a pixel's centre from its integer index, in the convention above.
PIXEL_CENTRE_OFFSET = 0.0


def pixel_centres(width, height):
    r'''Pixel-centre coordinates of a whole image

SYNOPSIS

    q = pixel_centres(W, H)
    # q has shape (H,W,2); q[iy,ix] = (ix, iy)
'''
    x = np.arange(width, dtype=np.float64) + PIXEL_CENTRE_OFFSET
    y = np.arange(height, dtype=np.float64) + PIXEL_CENTRE_OFFSET
    return np.stack(np.meshgrid(x, y), axis=-1)


def image_bounds(width, height):
    r'''(xmin, xmax, ymin, ymax) of the area covered by an image's pixels'''
    return (-0.5, width - 0.5, -0.5, height - 0.5)
