"""Instance masks -> COCO boxes: box convention, areas, RLE, PNG and JSON round trips."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nsim.errors import InputError
from nsim.io.coco import (
    InstanceBox,
    binary_from_rle,
    boxes_from_mask,
    coco_dataset,
    coco_from_mask_files,
    load_coco_boxes,
    read_instance_mask,
    rle_from_binary,
    write_coco_json,
    write_instance_mask,
)


@pytest.fixture
def mask() -> np.ndarray:
    m = np.zeros((20, 30), dtype=np.uint16)
    m[2:8, 3:10] = 4  # rows 2..7, columns 3..9
    m[10:20, 25:30] = 300  # touches the bottom-right corner
    m[0, 0] = 4  # a stray pixel of the same person (occluded in between)
    return m


def test_boxes_follow_coco_conventions(mask):
    boxes = boxes_from_mask(mask)
    assert boxes == [
        InstanceBox(4, (0.0, 0.0, 10.0, 8.0), 6 * 7 + 1),  # x = first column, w = last - first + 1
        InstanceBox(300, (25.0, 10.0, 5.0, 10.0), 50),
    ]
    assert boxes_from_mask(np.zeros((4, 4), np.uint8)) == []


def test_rle_round_trip(mask):
    for k in (4, 300):
        binary = mask == k
        rle = rle_from_binary(binary)
        assert rle["size"] == [20, 30] and sum(rle["counts"]) == 600
        assert sum(rle["counts"][1::2]) == binary.sum()  # odd runs are foreground
        np.testing.assert_array_equal(binary_from_rle(rle), binary)
    full = np.ones((2, 2), bool)
    assert rle_from_binary(full)["counts"] == [0, 4]


def test_mask_png_round_trip(tmp_path, mask):
    path = write_instance_mask(tmp_path / "mask.png", mask)
    back = read_instance_mask(path)
    assert back.dtype == np.uint16
    np.testing.assert_array_equal(back, mask)
    assert write_instance_mask(tmp_path / "again.png", mask).read_bytes() == path.read_bytes()
    with pytest.raises(ValueError, match="ids must be in"):
        write_instance_mask(tmp_path / "bad.png", np.full((2, 2), 70000, np.int64))


def test_dataset_json_round_trip(tmp_path, mask):
    empty = np.zeros((20, 30), np.uint16)
    paths = [write_instance_mask(tmp_path / f"{i}.png", m) for i, m in enumerate((mask, empty))]
    data = coco_from_mask_files(paths, ["frontleft/000000.png", "frontleft/000001.png"])
    assert [im["id"] for im in data["images"]] == [1, 2]
    assert data["images"][0] == {"id": 1, "file_name": "frontleft/000000.png", "width": 30, "height": 20}
    assert data["categories"] == [{"id": 1, "name": "person", "supercategory": "person"}]
    ann = data["annotations"]
    assert [(a["id"], a["image_id"], a["instance_id"], a["area"]) for a in ann] == [(1, 1, 4, 43), (2, 1, 300, 50)]
    assert all(a["iscrowd"] == 0 and a["category_id"] == 1 for a in ann)
    path = write_coco_json(tmp_path / "boxes.json", data)
    assert json.loads(path.read_text()) == data
    boxes = load_coco_boxes(path)
    assert boxes == {"frontleft/000000.png": boxes_from_mask(mask), "frontleft/000001.png": []}
    assert write_coco_json(tmp_path / "b.json", coco_dataset([("frontleft/000000.png", mask),
                                                              ("frontleft/000001.png", empty)])).read_bytes() == path.read_bytes()


def test_bad_files_are_input_errors(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(InputError, match="malformed JSON"):
        load_coco_boxes(bad)
    bad.write_text(json.dumps({"images": [{"id": 1, "file_name": "a"}], "annotations": [{"id": 1, "image_id": 9,
                                                                                          "category_id": 1}]}))
    with pytest.raises(InputError, match=r"annotations\[0\]"):
        load_coco_boxes(bad)
    with pytest.raises(InputError, match="no such file"):
        read_instance_mask(tmp_path / "none.png")


def test_bad_mask_files_are_input_errors(tmp_path, mask):
    """The mask reader shares nsim.io.images' file reading: every bad file is one InputError line."""
    empty, corrupt, rgb = tmp_path / "empty.png", tmp_path / "corrupt.png", tmp_path / "rgb.png"
    empty.write_bytes(b"")
    corrupt.write_bytes(b"\x89PNG not really")
    from nsim.io.images import write_image

    write_image(rgb, np.zeros((4, 5, 3), np.uint8))
    with pytest.raises(InputError, match="empty.png: empty file"):
        read_instance_mask(empty)
    with pytest.raises(InputError, match="corrupt.png: not a readable image"):
        read_instance_mask(corrupt)
    with pytest.raises(InputError, match="rgb.png: expected a single-channel 8/16-bit instance mask"):
        read_instance_mask(rgb)
    # written as PNG whatever the name says, the bytes of a .png
    other = write_instance_mask(tmp_path / "mask.bin", mask)
    assert other.read_bytes() == write_instance_mask(tmp_path / "mask.png", mask).read_bytes()
