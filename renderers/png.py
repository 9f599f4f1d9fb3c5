r'''16-bit PNG output of rendered images, and reading PNGs back as float

SYNOPSIS

    from renderers.png import save_png16, load_png

    save_png16("pose0.png", image)   # image (H,W) float in [0,1] -> uint16 round(image*65535)
    image = load_png("pose0.png")    # (H,W) float32 in [0,1]; 8- or 16-bit greyscale

A rendered image is float32 in [0,1]; a 16-bit PNG keeps it to 1/65535 (7.6e-6),
far below any detector's noise. Reading accepts 8- and 16-bit single-channel
PNGs (8-bit ones are divided by 255).
'''

from pathlib import Path

import numpy as np

from reference_models.errors import CamvalError


class ImageFileError(CamvalError):
    '''An image file that cannot be written or read as camval expects.'''


def save_png16(path, image):
    r'''Write a float image in [0,1] as a 16-bit greyscale PNG

SYNOPSIS

    save_png16(path, image)   # image has shape (H,W); values in [0,1]

The stored value is round(image * 65535). Values outside [0,1] or non-finite
values are an error (ImageFileError), as is a path cv2 cannot write.
'''
    import cv2

    path = Path(path)
    img = np.asarray(image)
    if img.ndim != 2 or img.shape[0] == 0 or img.shape[1] == 0:
        raise ImageFileError(f"cannot write '{path}': image has shape {img.shape}; "
                             "expected (height, width)")
    img = img.astype(np.float64)
    if not np.all(np.isfinite(img)):
        raise ImageFileError(f"cannot write '{path}': image has non-finite pixels")
    lo, hi = float(img.min()), float(img.max())
    if lo < 0.0 or hi > 1.0:
        raise ImageFileError(f"cannot write '{path}': pixel values span [{lo:.9g}, {hi:.9g}]; "
                             "expected [0, 1]")
    if path.suffix.lower() != ".png":
        raise ImageFileError(f"cannot write '{path}': expected a .png file name")
    q = np.round(img * 65535.0).astype(np.uint16)
    try:
        ok = cv2.imwrite(str(path), q)
    except cv2.error as e:
        raise ImageFileError(f"cannot write '{path}': {str(e).strip().splitlines()[-1]}") from None
    if not ok:
        raise ImageFileError(f"cannot write '{path}' (does its directory exist and is it "
                             "writable?)")
    return path


def load_png(path):
    r'''Read an 8- or 16-bit greyscale PNG as float32 in [0,1]

SYNOPSIS

    image = load_png(path)   # (H,W) float32
'''
    import cv2

    path = Path(path)
    if not path.is_file():
        raise ImageFileError(f"cannot read '{path}': no such file")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ImageFileError(f"cannot read '{path}': not an image file cv2 can decode")
    if img.ndim != 2:
        raise ImageFileError(f"cannot read '{path}': it has {img.shape[2]} channels; "
                             "expected a single-channel (greyscale) image")
    if img.dtype == np.uint8:
        return img.astype(np.float32) / np.float32(255.0)
    if img.dtype == np.uint16:
        return img.astype(np.float32) / np.float32(65535.0)
    raise ImageFileError(f"cannot read '{path}': pixel type {img.dtype}; expected 8 or 16 bit")
