r'''Exact JPL camera models (CAHV, CAHVOR, CAHVORE), their file formats and the camera catalogue

SYNOPSIS

    from reference_models import load_catalogue, read_model, to_mrcal

    m = load_catalogue().get(15).model        # MER-B navcam left, CAHVOR
    q = m.project(p)                          # p (...,3) -> q (...,2)
    origin, v = m.unproject(q)

Importing this package is light (numpy only); mrcal is imported when used.
'''

from .cahvore import CAHV, CAHVOR, CAHVORE, Photogrammetric, truncate
from .catalogue import (
    Catalogue,
    CatalogueEntry,
    CatalogueError,
    field_of_view_deg,
    load_catalogue,
    load_model_file,
)
from .conventions import PIXEL_CENTRE_OFFSET, image_bounds, pixel_centres
from .errors import (
    CamvalError,
    ModelError,
    ModelFileError,
    NotRepresentableError,
    UnknownCameraError,
)
from .jpl_files import OutputExistsError, jpl_theta, read_model, write_model
from .m2020_json import read_m2020_json
from .mrcal_convert import from_mrcal, to_mrcal
from .pds3 import read_pds3_model

__all__ = [
    "CAHV", "CAHVOR", "CAHVORE", "Photogrammetric", "truncate",
    "Catalogue", "CatalogueEntry", "CatalogueError", "field_of_view_deg", "load_catalogue",
    "load_model_file",
    "PIXEL_CENTRE_OFFSET", "image_bounds", "pixel_centres",
    "CamvalError", "ModelError", "ModelFileError", "NotRepresentableError", "UnknownCameraError",
    "OutputExistsError", "jpl_theta", "read_model", "write_model",
    "read_m2020_json", "from_mrcal", "to_mrcal", "read_pds3_model",
]
