"""ROS map_server maps: loading the real maps, saving, round trips, modes and errors."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image

from agv_mission.geometry import Pose2D
from agv_mission.maps.grid import FREE, OCCUPIED, UNKNOWN, OccupancyGrid
from agv_mission.maps.ros_map import MapLoadError, load_ros_map, save_ros_map

REAL_MAPS = ["turtlebot3_world", "aws_small_house"]


def read_pgm_bytes(path: Path) -> np.ndarray:
    """Pixels of a binary (P5, 8-bit) PGM, parsed by hand: (height, width), top row first."""
    raw = path.read_bytes()
    tokens: list[bytes] = []
    pos = 0
    while len(tokens) < 4:
        while raw[pos : pos + 1].isspace():
            pos += 1
        if raw[pos : pos + 1] == b"#":
            pos = raw.index(b"\n", pos) + 1
            continue
        end = pos
        while not raw[end : end + 1].isspace():
            end += 1
        tokens.append(raw[pos:end])
        pos = end
    magic, width, height, maxval = tokens[0], int(tokens[1]), int(tokens[2]), int(tokens[3])
    assert magic == b"P5" and maxval == 255
    pixels = np.frombuffer(raw[pos + 1 :], dtype=np.uint8)
    assert pixels.size == width * height
    return pixels.reshape(height, width)


def write_map(folder: Path, pixels: np.ndarray, image_name: str = "map.pgm", **meta) -> Path:
    """Write an image (top row first) and a map YAML beside it; returns the YAML path."""
    folder.mkdir(parents=True, exist_ok=True)
    Image.fromarray(pixels).save(folder / Path(image_name).name)
    doc = {"image": image_name, "resolution": 0.05, "origin": [0.0, 0.0, 0.0]}
    doc.update(meta)
    path = folder / "map.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


# --------------------------------------------------------------------------- real maps


@pytest.mark.parametrize("name", REAL_MAPS)
def test_real_map_cell_counts_match_the_pgm(name: str, ros_maps: Path) -> None:
    pixels = read_pgm_bytes(ros_maps / name / "map.pgm")
    grid = load_ros_map(ros_maps / name / "map.yaml")
    assert (grid.height, grid.width) == pixels.shape
    assert grid.data.dtype == np.int8
    assert grid.counts() == {
        "free": int(np.count_nonzero(pixels == 254)),
        "occupied": int(np.count_nonzero(pixels == 0)),
        "unknown": int(np.count_nonzero(pixels == 205)),
    }
    assert sum(grid.counts().values()) == pixels.size  # the files hold only 254 / 0 / 205


@pytest.mark.parametrize("name", REAL_MAPS)
def test_real_map_is_flipped_to_row_zero_at_the_bottom(name: str, ros_maps: Path) -> None:
    pixels = read_pgm_bytes(ros_maps / name / "map.pgm")
    grid = load_ros_map(ros_maps / name / "map.yaml")
    expected = np.select([pixels == 254, pixels == 0], [FREE, OCCUPIED], UNKNOWN)[::-1]
    np.testing.assert_array_equal(grid.data, expected)


def test_real_map_metadata(ros_maps: Path) -> None:
    tb3 = load_ros_map(ros_maps / "turtlebot3_world" / "map.yaml")
    assert (tb3.width, tb3.height, tb3.resolution) == (384, 384, 0.05)
    assert tb3.origin == Pose2D(-10.0, -10.0, 0.0)
    house = load_ros_map(ros_maps / "aws_small_house" / "map.yaml")
    assert (house.width, house.height) == (500, 500)
    assert house.origin == Pose2D(-12.5, -12.5, 0.0)
    # The AWS spawn stands on free ground; a TurtleBot3 pillar centre is not free.
    assert house.value_at(np.array([3.831436, -1.234452])) == FREE
    assert tb3.value_at(np.array([-1.1, -1.1])) != FREE


def test_leading_dot_slash_image_path(tmp_path: Path, ros_maps: Path) -> None:
    assert "image: ./map.pgm" in (ros_maps / "turtlebot3_world" / "map.yaml").read_text()
    pixels = np.array([[254, 0], [205, 254]], dtype=np.uint8)
    for image in ("./map.pgm", "map.pgm", str(tmp_path / "a" / "map.pgm")):
        grid = load_ros_map(write_map(tmp_path / "a", pixels, image_name=image))
        np.testing.assert_array_equal(grid.data, [[UNKNOWN, FREE], [FREE, OCCUPIED]])


def test_save_reproduces_map_saver_bytes_and_loads_back(tmp_path: Path, ros_maps: Path) -> None:
    original = load_ros_map(ros_maps / "aws_small_house" / "map.yaml")
    pgm, yml = save_ros_map(original, tmp_path / "out" / "house")
    assert (pgm.name, yml.name) == ("house.pgm", "house.yaml")
    np.testing.assert_array_equal(
        read_pgm_bytes(pgm), read_pgm_bytes(ros_maps / "aws_small_house" / "map.pgm")
    )
    meta = yaml.safe_load(yml.read_text())
    assert meta == {
        "image": "house.pgm",
        "resolution": 0.05,
        "origin": [-12.5, -12.5, 0.0],
        "negate": 0,
        "occupied_thresh": 0.65,
        "free_thresh": 0.196,
    }
    again = load_ros_map(yml)
    np.testing.assert_array_equal(again.data, original.data)
    assert again.origin == original.origin and again.resolution == original.resolution
    assert sorted(p.name for p in pgm.parent.iterdir()) == ["house.pgm", "house.yaml"]


def test_round_trip_keeps_every_cell_of_an_odd_grid(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    data = rng.choice(np.array([FREE, OCCUPIED, UNKNOWN], dtype=np.int8), size=(37, 53))
    grid = OccupancyGrid(data, 0.0375, Pose2D(-1.2345678901, 2.5, 0.3))
    _, yml = save_ros_map(grid, tmp_path / "odd.pgm")  # a suffix is dropped
    assert yml.name == "odd.yaml"
    again = load_ros_map(yml)
    np.testing.assert_array_equal(again.data, data)
    assert again.resolution == grid.resolution
    assert again.origin == grid.origin
    # Saving again over the same stem replaces the files.
    grid.data[0, 0] = OCCUPIED
    save_ros_map(grid, tmp_path / "odd")
    assert load_ros_map(yml).data[0, 0] == OCCUPIED


# --------------------------------------------------------------------------- modes


def test_trinary_thresholds_and_negate(tmp_path: Path) -> None:
    pixels = np.array([[0, 254, 205, 100, 255, 200]], dtype=np.uint8)
    plain = load_ros_map(write_map(tmp_path / "plain", pixels))
    # occ = (255 - p) / 255: 1.0, 0.004, 0.196078 (> free_thresh), 0.61, 0.0, 0.216
    np.testing.assert_array_equal(plain.data[0], [100, 0, -1, -1, 0, -1])
    negated = load_ros_map(write_map(tmp_path / "neg", pixels, negate=1))
    # negate: occ = p / 255, the thresholds keep their meaning
    np.testing.assert_array_equal(negated.data[0], [0, 100, 100, -1, 100, 100])


def test_scale_mode(tmp_path: Path) -> None:
    pixels = np.array([[0, 255, 128, 180, 205]], dtype=np.uint8)
    grid = load_ros_map(write_map(tmp_path, pixels, mode="scale"))
    expected = [100, 0]
    for p in (128, 180, 205):
        occ = (255 - p) / 255.0
        expected.append(int(1 + 98 * (occ - 0.196) / (0.65 - 0.196)))
    np.testing.assert_array_equal(grid.data[0], expected)
    assert expected[2:] == [66, 22, 1]


def test_scale_mode_transparent_pixels_are_unknown(tmp_path: Path) -> None:
    lum = np.array([[128, 128, 0, 255]], dtype=np.uint8)
    alpha = np.array([[255, 0, 0, 0]], dtype=np.uint8)
    rgba = np.stack([lum, lum, lum, alpha], axis=-1)
    scale = load_ros_map(write_map(tmp_path / "s", rgba, image_name="map.png", mode="scale"))
    np.testing.assert_array_equal(scale.data[0], [66, -1, 100, 0])
    # trinary mode averages alpha in with the colour, as map_server does
    trinary = load_ros_map(write_map(tmp_path / "t", rgba, image_name="map.png"))
    np.testing.assert_array_equal(trinary.data[0], [-1, -1, 100, -1])


def test_raw_mode(tmp_path: Path) -> None:
    pixels = np.array([[0, 100, 101, 255]], dtype=np.uint8)
    grid = load_ros_map(write_map(tmp_path / "raw", pixels, mode="raw"))
    np.testing.assert_array_equal(grid.data[0], [0, 100, 101, -1])
    negated = load_ros_map(write_map(tmp_path / "rawneg", pixels, mode="raw", negate=1))
    np.testing.assert_array_equal(negated.data[0], [-1, 155 - 256, 154 - 256, 0])


def test_rgb_png_is_averaged(tmp_path: Path) -> None:
    rgb = np.array([[[0, 0, 0], [254, 254, 254], [255, 0, 0], [255, 255, 150]]], dtype=np.uint8)
    grid = load_ros_map(write_map(tmp_path, rgb, image_name="map.png"))
    np.testing.assert_array_equal(grid.data[0], [100, 0, 100, 0])  # (255+0+0)/3 = 85 -> 0.67


def test_plain_p2_pgm(tmp_path: Path) -> None:
    (tmp_path / "map.pgm").write_text("P2\n# plain\n3 2\n255\n254 0 205\n0 0 254\n")
    (tmp_path / "map.yaml").write_text("image: map.pgm\nresolution: 0.1\norigin: [1, 2, 0]\n")
    grid = load_ros_map(tmp_path / "map.yaml")
    np.testing.assert_array_equal(grid.data, [[100, 100, 0], [0, 100, -1]])
    assert grid.origin == Pose2D(1.0, 2.0, 0.0) and math.isclose(grid.resolution, 0.1)


# --------------------------------------------------------------------------- errors


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("image: nothere.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n", "nothere.pgm not found"),
        ("resolution: 0.05\norigin: [0, 0, 0]\n", "the map YAML lacks 'image'"),
        ("image: map.pgm\norigin: [0, 0, 0]\n", "the map YAML lacks 'resolution'"),
        ("image: map.pgm\nresolution: 0.05\n", "the map YAML lacks 'origin'"),
        ("image: map.pgm\nresolution: -1\norigin: [0, 0, 0]\n", "'resolution' must be > 0"),
        ("image: map.pgm\nresolution: 0.05\norigin: [0, 0]\n", "'origin' must be [x, y, yaw]"),
        ("image: map.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nmode: fancy\n", "'mode' must be"),
        ("image: map.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nnegate: 2\n", "'negate' must be"),
        (
            "image: map.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nfree_thresh: 0.7\n",
            "free_thresh < occupied_thresh",
        ),
        ("- just\n- a list\n", "must be a mapping"),
        ("image: [unclosed\n", "cannot read map YAML"),
    ],
)
def test_clear_errors(tmp_path: Path, text: str, expected: str) -> None:
    Image.fromarray(np.full((2, 2), 254, dtype=np.uint8)).save(tmp_path / "map.pgm")
    (tmp_path / "map.yaml").write_text(text)
    with pytest.raises(MapLoadError) as info:
        load_ros_map(tmp_path / "map.yaml")
    assert str(tmp_path / "map.yaml") in str(info.value)
    assert expected in str(info.value)


def test_missing_yaml_and_unreadable_image(tmp_path: Path) -> None:
    with pytest.raises(MapLoadError, match="not found"):
        load_ros_map(tmp_path / "absent.yaml")
    (tmp_path / "map.pgm").write_bytes(b"this is no image")
    (tmp_path / "map.yaml").write_text("image: map.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n")
    with pytest.raises(MapLoadError, match="cannot read image"):
        load_ros_map(tmp_path / "map.yaml")


@pytest.mark.parametrize(
    ("size", "expected"),
    [
        # PIL refuses past 179 M pixels (a DecompressionBombError traceback before)
        ("100000 100000", "map.pgm: more than 1e+08 pixels"),
        # PIL only warns below that and decodes: gigabytes of float tables
        ("12000 9000", "map.pgm: 12000 x 9000 pixels, more than 1e+08"),
    ],
)
def test_an_image_claiming_too_many_pixels_is_refused(tmp_path, size, expected) -> None:
    """A PGM header is a few bytes whatever size it claims: refused before decoding."""
    import warnings

    (tmp_path / "map.pgm").write_bytes(f"P5\n{size}\n255\n".encode() + bytes(1000))
    (tmp_path / "map.yaml").write_text("image: map.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # and no DecompressionBombWarning either
        with pytest.raises(MapLoadError) as info:
            load_ros_map(tmp_path / "map.yaml")
    assert str(info.value).startswith(f"{tmp_path / 'map.yaml'}: image ")
    assert expected in str(info.value)


@pytest.mark.parametrize("kind", ["directory", "fifo"])
def test_an_image_that_is_no_regular_file_is_named_so(tmp_path: Path, kind: str) -> None:
    """A map YAML whose image is a directory or a FIFO (open() on it would block) is
    refused as such, not reported 'not found'."""
    image = tmp_path / "map.pgm"
    if kind == "directory":
        image.mkdir()
    else:
        import os

        os.mkfifo(image)
    meta = tmp_path / "map.yaml"
    meta.write_text("image: map.pgm\nresolution: 0.05\norigin: [0.0, 0.0, 0.0]\n")
    with pytest.raises(MapLoadError, match="is not a regular file"):
        load_ros_map(meta)
