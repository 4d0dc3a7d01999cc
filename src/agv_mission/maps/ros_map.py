"""Read and write ROS ``map_server`` maps (``map.yaml`` + ``map.pgm``/``.png``).

:func:`load_ros_map` follows ROS 1 ``map_server`` (``image_loader.cpp``, noetic):

* ``image`` is resolved against the YAML file's folder (``map.pgm``, ``./map.pgm`` and
  absolute paths all work); PGM (binary P5 and plain P2) and PNG are read with Pillow.
* each pixel's channels are averaged (alpha included in ``trinary`` mode, as ROS does);
  ``negate: 1`` replaces the average ``c`` by ``255 - c``; ``occ = (255 - c) / 255``.
* ``trinary`` (default): ``occ > occupied_thresh`` -> 100, ``occ < free_thresh`` -> 0,
  else -1. ``scale``: as trinary, but between the thresholds the value is
  ``int(1 + 98 * (occ - free) / (occupied - free))`` and fully transparent pixels are -1.
  ``raw``: the cell is the (negated) average itself, stored as a signed byte
  (so 255 reads as -1).
* image row 0 is the top of the map; the grid is flipped so that row 0 is the lowest y.
* ``origin: [x, y, yaw]`` is the pose of the lower-left pixel.

Differences: ``negate``, ``occupied_thresh`` and ``free_thresh`` are optional here
(defaults 0, 0.65, 0.196, the values ``map_saver`` writes); palette images are read
as their colours, not their indices; an RGB image has no alpha (ROS 1 reads its blue
channel as alpha); 16-bit images are scaled to 8 bits.

:func:`save_ros_map` writes what ``map_saver`` writes: a P5 PGM with 254 free, 0
occupied (>= 65) and 205 unknown, and the YAML beside it with a relative ``image``.
"""

from __future__ import annotations

import math
import os
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import yaml

from agv_mission.atomic import atomic_write_bytes, input_path
from agv_mission.geometry import Pose2D
from agv_mission.maps.grid import MAX_GRID_CELLS, OccupancyGrid
from agv_mission.yaml_safe import safe_load

if TYPE_CHECKING:
    from PIL import Image

MODES = ("trinary", "scale", "raw")
DEFAULT_OCCUPIED_THRESH = 0.65
DEFAULT_FREE_THRESH = 0.196

# map_saver's output values and the cell thresholds it uses (ROS 1 noetic).
PGM_FREE = 254
PGM_OCCUPIED = 0
PGM_UNKNOWN = 205
SAVER_THRESHOLD_FREE = 25
SAVER_THRESHOLD_OCCUPIED = 65


class MapLoadError(ValueError):
    """A ROS map (YAML or image) that cannot be read; the message names the file."""


def load_ros_map(yaml_path: str | os.PathLike[str]) -> OccupancyGrid:
    """Load a ``map_server`` YAML and its image into an :class:`OccupancyGrid`."""
    yaml_path = Path(yaml_path)
    meta = _read_yaml(yaml_path)
    image_path, resolution, origin, negate, occ_th, free_th, mode = _parse_meta(yaml_path, meta)
    pixels, alpha = _read_image(yaml_path, image_path, mode)

    color = pixels
    if negate:
        color = 255.0 - color
    if mode == "raw":
        data = np.floor(color).astype(np.uint8).view(np.int8)
    else:
        occ = (255.0 - color) / 255.0
        data = np.full(occ.shape, -1, dtype=np.int8)
        if mode == "scale":
            ratio = (occ - free_th) / (occ_th - free_th)
            scaled = np.clip(np.floor(1.0 + 98.0 * ratio), 0, 255).astype(np.int64)
            opaque = alpha >= 1.0
            data[opaque] = scaled[opaque].astype(np.int8)
        data[occ < free_th] = 0
        data[occ > occ_th] = 100
    data = np.ascontiguousarray(data[::-1])
    return OccupancyGrid(data=data, resolution=resolution, origin=origin)


def saver_pixels(grid: OccupancyGrid) -> np.ndarray:
    """The grid as map_saver draws it (254 free, 0 occupied, 205 unknown), uint8, image row
    0 at the top of the map: the saved PGM's and the dashboards' picture."""
    data = np.asarray(grid.data).astype(np.int16)
    pixels = np.full(data.shape, PGM_UNKNOWN, dtype=np.uint8)
    pixels[(data >= 0) & (data <= SAVER_THRESHOLD_FREE)] = PGM_FREE
    pixels[data >= SAVER_THRESHOLD_OCCUPIED] = PGM_OCCUPIED
    return np.ascontiguousarray(pixels[::-1])


def save_ros_map(grid: OccupancyGrid, stem_path: str | os.PathLike[str]) -> tuple[Path, Path]:
    """Write ``<stem>.pgm`` and ``<stem>.yaml`` in ``map_saver``'s trinary format.

    A ``.pgm``/``.yaml``/``.yml`` suffix on ``stem_path`` is dropped. Both files are
    written atomically (temporary file in the same folder, then ``os.replace``).
    Returns ``(pgm_path, yaml_path)``.
    """
    stem_path = Path(stem_path)
    if stem_path.suffix.lower() in (".pgm", ".yaml", ".yml"):
        stem_path = stem_path.with_suffix("")
    pgm_path = stem_path.parent / (stem_path.name + ".pgm")
    yaml_path = stem_path.parent / (stem_path.name + ".yaml")
    stem_path.parent.mkdir(parents=True, exist_ok=True)

    pixels = saver_pixels(grid)
    header = (
        f"P5\n# CREATOR: agv_mission ros_map.py {grid.resolution:.3f} m/pix\n"
        f"{grid.width} {grid.height}\n255\n"
    ).encode("ascii")
    atomic_write_bytes(pgm_path, header + pixels.tobytes())

    o = grid.origin
    text = (
        f"image: {pgm_path.name}\n"
        f"resolution: {_fmt(grid.resolution)}\n"
        f"origin: [{_fmt(o.x)}, {_fmt(o.y)}, {_fmt(o.yaw)}]\n"
        "negate: 0\n"
        f"occupied_thresh: {DEFAULT_OCCUPIED_THRESH}\n"
        f"free_thresh: {DEFAULT_FREE_THRESH}\n\n"
    )
    atomic_write_bytes(yaml_path, text.encode("utf-8"))
    return pgm_path, yaml_path


# Keys only a map_server map YAML has (a world file has none of them).
MAP_ONLY_KEYS = ("image", "origin", "negate", "occupied_thresh", "free_thresh", "mode")
REQUIRED_KEYS = ("image", "resolution", "origin")


def is_ros_map_yaml(meta: object) -> bool:
    """True for a parsed YAML document meant as a ``map_server`` map: it has a key only a
    map has (so a map without ``resolution`` is reported as a map lacking it)."""
    return isinstance(meta, dict) and any(key in meta for key in MAP_ONLY_KEYS)


# --------------------------------------------------------------------------- helpers


def _fmt(value: float) -> str:
    """``%f`` like map_saver, unless that would lose precision."""
    text = f"{value:.6f}"
    return text if float(text) == value else repr(float(value))


def _read_yaml(yaml_path: Path) -> dict:
    if not yaml_path.is_file():
        raise MapLoadError(f"{yaml_path}: map YAML file not found")
    try:
        meta = safe_load(yaml_path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise MapLoadError(f"{yaml_path}: cannot read map YAML: {exc}") from exc
    if not isinstance(meta, dict):
        raise MapLoadError(
            f"{yaml_path}: a map YAML must be a mapping with 'image', 'resolution' and 'origin'"
        )
    return meta


def _number(yaml_path: Path, meta: dict, key: str, default: float | None = None) -> float:
    if key not in meta:
        if default is None:
            raise MapLoadError(f"{yaml_path}: missing required key '{key}'")
        return default
    value = meta[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise MapLoadError(f"{yaml_path}: '{key}' must be a number, got {value!r}")
    return float(value)


def _parse_meta(yaml_path: Path, meta: dict):
    missing = [key for key in REQUIRED_KEYS if key not in meta]
    if missing:
        raise MapLoadError(
            f"{yaml_path}: the map YAML lacks {' and '.join(repr(k) for k in missing)} "
            f"(a map_server map needs {', '.join(REQUIRED_KEYS)})"
        )
    image = meta.get("image")
    if not isinstance(image, str) or not image.strip():
        raise MapLoadError(f"{yaml_path}: 'image' must be a file name, got {image!r}")
    image_path = input_path(image.strip(), yaml_path.parent)

    resolution = _number(yaml_path, meta, "resolution")
    if resolution <= 0:
        raise MapLoadError(f"{yaml_path}: 'resolution' must be > 0, got {resolution}")

    if "origin" not in meta:
        raise MapLoadError(f"{yaml_path}: missing required key 'origin'")
    origin = meta["origin"]
    if (
        not isinstance(origin, (list, tuple))
        or len(origin) != 3
        or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
            for v in origin
        )
    ):
        raise MapLoadError(f"{yaml_path}: 'origin' must be [x, y, yaw] (3 numbers), got {origin!r}")

    negate = meta.get("negate", 0)
    if isinstance(negate, bool):
        negate = int(negate)
    if negate not in (0, 1):
        raise MapLoadError(f"{yaml_path}: 'negate' must be 0 or 1, got {negate!r}")

    occ_th = _number(yaml_path, meta, "occupied_thresh", DEFAULT_OCCUPIED_THRESH)
    free_th = _number(yaml_path, meta, "free_thresh", DEFAULT_FREE_THRESH)
    if not 0.0 <= free_th < occ_th <= 1.0:
        raise MapLoadError(
            f"{yaml_path}: need 0 <= free_thresh < occupied_thresh <= 1, "
            f"got free_thresh={free_th}, occupied_thresh={occ_th}"
        )

    mode = meta.get("mode", "trinary")
    if mode not in MODES:
        raise MapLoadError(f"{yaml_path}: 'mode' must be one of {', '.join(MODES)}, got {mode!r}")

    pose = Pose2D(float(origin[0]), float(origin[1]), float(origin[2]))
    return image_path, resolution, pose, bool(negate), occ_th, free_th, mode


def _read_image(yaml_path: Path, image_path: Path, mode: str):
    """(channel average, alpha 0..255) of every pixel as float64, top row first."""
    if not image_path.is_file():  # a directory or a FIFO (which would block a read) too
        what = "is not a regular file" if image_path.exists() else "not found"
        raise MapLoadError(f"{yaml_path}: image file {image_path} {what}")
    from PIL import Image, UnidentifiedImageError  # a built-in world has no image to read

    cannot = f"{yaml_path}: cannot read image {image_path}"
    try:
        with warnings.catch_warnings():  # PIL warns past 89 M pixels; ours is the bound
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            img = Image.open(image_path)
    except Image.DecompressionBombError as exc:  # PIL's refusal past 179 M pixels
        raise MapLoadError(
            f"{yaml_path}: image {image_path}: more than {MAX_GRID_CELLS:.0e} pixels ({exc})"
        ) from None
    except (OSError, UnidentifiedImageError, ValueError) as exc:
        raise MapLoadError(f"{cannot}: {exc}") from exc
    with img:
        width, height = img.size
        if width * height > MAX_GRID_CELLS:
            raise MapLoadError(
                f"{yaml_path}: image {image_path}: {width} x {height} pixels, more than "
                f"{MAX_GRID_CELLS:.0e}"
            )
        try:
            img.load()
            img = _normalise_mode(img)
            arr = np.asarray(img)
        except (OSError, ValueError) as exc:
            raise MapLoadError(f"{cannot}: {exc}") from exc
    if arr.ndim == 2:
        return arr.astype(np.float64), np.full(arr.shape, 255.0)
    n = arr.shape[2]
    has_alpha = img.mode in ("RGBA", "LA")
    if has_alpha:
        alpha = arr[..., -1].astype(np.float64)
        avg_channels = n if mode == "trinary" else n - 1
    else:
        alpha = np.full(arr.shape[:2], 255.0)
        avg_channels = n
    color = arr[..., :avg_channels].astype(np.float64).sum(axis=2) / avg_channels
    return color, alpha


def _normalise_mode(img: Image.Image) -> Image.Image:
    from PIL import Image

    if img.mode in ("L", "RGB", "RGBA"):
        return img
    if img.mode == "LA":  # SDL_image gives RGBA: three equal channels plus alpha
        lum, alpha = img.split()
        return Image.merge("RGBA", (lum, lum, lum, alpha))
    if img.mode == "1":
        return img.convert("L")
    if img.mode in ("P", "PA"):
        return img.convert("RGBA" if "transparency" in img.info or img.mode == "PA" else "RGB")
    if img.mode.startswith("I"):  # 16-bit grey: Pillow scales to 0..65535
        arr = np.asarray(img).astype(np.float64)
        return Image.fromarray(np.clip(np.rint(arr / 257.0), 0, 255).astype(np.uint8))
    if img.mode == "F":
        return Image.fromarray(np.clip(np.asarray(img), 0, 255).astype(np.uint8))
    return img.convert("RGB")
