"""nav2 map_server maps: map.yaml + map.pgm, checked with independent readers (yaml, OpenCV, PIL)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import yaml
from PIL import Image

from nsim.errors import InputError
from nsim.io.nav2 import (
    CELL_FREE,
    CELL_OCCUPIED,
    CELL_UNKNOWN,
    cells_to_image,
    read_nav2_map,
    write_nav2_map,
)


def _cells(nx=7, ny=5, seed=0):
    rng = np.random.default_rng(seed)
    return rng.choice(np.array([CELL_FREE, CELL_OCCUPIED, CELL_UNKNOWN], dtype=np.int8), size=(nx, ny))


def test_round_trip_matches_cell_for_cell(tmp_path):
    cells = _cells()
    path = write_nav2_map(tmp_path / "map.yaml", cells, (-1.25, 2.5), 0.05)
    doc = yaml.safe_load(path.read_text())
    assert doc == {"image": "map.pgm", "mode": "trinary", "resolution": 0.05, "origin": [-1.25, 2.5, 0.0],
                   "negate": 0, "occupied_thresh": 0.65, "free_thresh": 0.196}
    for img in (cv2.imread(str(tmp_path / "map.pgm"), cv2.IMREAD_UNCHANGED),
                np.asarray(Image.open(tmp_path / "map.pgm"))):
        assert img.shape == (5, 7) and img.dtype == np.uint8
        for i in range(7):
            for j in range(5):
                want = {CELL_FREE: 254, CELL_OCCUPIED: 0, CELL_UNKNOWN: 205}[int(cells[i, j])]
                assert img[5 - 1 - j, i] == want  # row 0 is the largest y, column i is x
    back = read_nav2_map(path)
    assert back.cells.dtype == np.int8 and (back.cells == cells).all()
    assert back.origin_xy_m == (-1.25, 2.5) and back.resolution_m == 0.05
    (tmp_path / "b").mkdir()
    again = write_nav2_map(tmp_path / "b" / "map.yaml", cells, (-1.25, 2.5), 0.05)
    assert again.read_bytes() == path.read_bytes()
    assert (tmp_path / "b" / "map.pgm").read_bytes() == (tmp_path / "map.pgm").read_bytes()


def test_reads_maps_saved_elsewhere(tmp_path):
    """A PNG map with negate 1 and a PGM with a comment in its header, as other tools write them."""
    cells = _cells(4, 3, seed=1)
    img = cells_to_image(cells)
    cv2.imwrite(str(tmp_path / "m.png"), 255 - img)
    (tmp_path / "m.yaml").write_text("image: m.png\nresolution: 0.1\norigin: [0, 0, 0]\nnegate: 1\n"
                                     "occupied_thresh: 0.65\nfree_thresh: 0.196\n")
    assert (read_nav2_map(tmp_path / "m.yaml").cells == cells).all()
    (tmp_path / "c.pgm").write_bytes(b"P5\n# CREATOR: map_saver.cpp 0.050 m/pix\n4 3\n255\n" + img.tobytes())
    (tmp_path / "c.yaml").write_text("image: c.pgm\nresolution: 0.05\norigin: [1.0, 2.0, 0.0]\nnegate: 0\n"
                                     "occupied_thresh: 0.65\nfree_thresh: 0.196\nmode: trinary\n")
    assert (read_nav2_map(tmp_path / "c.yaml").cells == cells).all()


@pytest.mark.parametrize("text, message", [
    ("image: ../m.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n", "inside the map's folder"),
    ("image: m.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nmode: scale\n", "only trinary"),
    ("image: m.pgm\nresolution: 0.05\norigin: [0, 0, 0.5]\n", "yaw 0"),
    ("image: m.pgm\norigin: [0, 0, 0]\n", "resolution: missing"),
    ("image: other.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n", "not found"),
])
def test_bad_maps_are_named(tmp_path, text, message):
    (tmp_path / "m.pgm").write_bytes(b"P5\n2 1\n255\n\x00\xfe")
    (tmp_path / "m.yaml").write_text(text)
    with pytest.raises(InputError, match=message):
        read_nav2_map(tmp_path / "m.yaml")


def test_truncated_pgm(tmp_path):
    (tmp_path / "m.pgm").write_bytes(b"P5\n4 4\n255\n\x00\x00")
    (tmp_path / "m.yaml").write_text("image: m.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n")
    with pytest.raises(InputError, match="expected 16 bytes"):
        read_nav2_map(tmp_path / "m.yaml")
