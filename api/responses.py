"""What several routes answer alike: the OpenAPI error responses they share and the colour scale
of the images they draw. Routes import this module, never each other."""

from __future__ import annotations

import numpy as np
from fastapi import status as http

from api.deps import Responses
from workers.records import JobRecord

NOT_FOUND: Responses = {http.HTTP_404_NOT_FOUND: {"description": "No such job (or it expired)"}}
#: Errors of the upload form (POST /v1/jobs and /v1/estimate) for the OpenAPI docs.
UPLOAD_ERRORS: Responses = {
    400: {"description": "params is not JSON"},
    413: {"description": "File or image too large"},
    415: {"description": "Not a supported image format"},
}


#: Response header of colour-mapped images: the value (pixels) the top colour stands for.
SCALE_HEADER = "X-Scale-Max"


def display_max(record: JobRecord, disparity: np.ndarray) -> float:
    """The disparity the preview's top colour stands for: the job's range, else the map's max."""
    top = record.disparity_range.max_disparity if record.disparity_range else None
    if isinstance(top, int | float) and top > 0:
        return float(top)
    return max(float(np.max(disparity)), 1.0)
