"""A grid as a browser draws it: a PNG (base64) with the grid's resolution, origin and size,
the shape of the dashboards' ``map`` and ``zones`` messages (service-api.md)."""

from __future__ import annotations

import base64
import io
from typing import Any

import numpy as np
from PIL import Image

from agv_mission.maps.grid import OccupancyGrid
from agv_mission.maps.ros_map import saver_pixels


def grid_png(
    grid: OccupancyGrid, pixels: np.ndarray | None = None, mode: str = "L"
) -> dict[str, Any]:
    """``pixels`` (row 0 at the top; default: the grid as map_saver draws it) as a PNG
    placed on ``grid``."""
    buf = io.BytesIO()
    image = saver_pixels(grid) if pixels is None else pixels
    Image.fromarray(image, mode=mode).save(buf, format="PNG")
    return {
        "resolution": grid.resolution,
        "origin": [round(grid.origin.x, 4), round(grid.origin.y, 4)],
        "width": grid.width,
        "height": grid.height,
        "png": base64.b64encode(buf.getvalue()).decode("ascii"),
    }
