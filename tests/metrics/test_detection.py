"""Detection: IoU and matching against hand-computed values, NMS against OpenCV's, YOLO decoding,
a hand-built ONNX model through cv2.dnn, HOG on a drawn pedestrian, COCO JSON and bad input.
"""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from nsim.errors import InputError
from nsim.metrics.detection import (
    PERSON_LABEL,
    Detections,
    HogConfig,
    HogPeopleDetector,
    Letterbox,
    MatchConfig,
    OnnxConfig,
    OnnxDetector,
    YoloDecodeConfig,
    box_iou,
    box_iou_xywh,
    compare_detections,
    decode_yolo,
    evaluate_detection,
    letterbox,
    match_boxes,
    nms,
    read_coco_detections,
    write_coco_results,
    xywh_to_xyxy,
    xyxy_to_xywh,
)


def dets(boxes, labels=None, scores=None) -> Detections:
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    n = len(boxes)
    return Detections(boxes, np.ones(n) if scores is None else scores, np.zeros(n) if labels is None else labels)


# ---- IoU ---------------------------------------------------------------------------------


def test_box_iou_hand_computed():
    a = np.array([[0.0, 0.0, 10.0, 10.0], [0.0, 0.0, 2.0, 2.0]])
    b = np.array([[5.0, 5.0, 15.0, 15.0], [0.0, 0.0, 10.0, 10.0], [20.0, 20.0, 30.0, 30.0]])
    iou = box_iou(a, b)
    assert iou.shape == (2, 3)
    assert iou[0, 0] == pytest.approx(25.0 / 175.0)  # 5x5 overlap, 100 + 100 - 25
    assert iou[0, 1] == 1.0 and iou[0, 2] == 0.0
    assert iou[1, 1] == pytest.approx(4.0 / 100.0)  # contained
    # zero-area boxes: IoU 0, not NaN
    assert box_iou([[1.0, 1.0, 1.0, 1.0]], [[1.0, 1.0, 1.0, 1.0]])[0, 0] == 0.0
    assert box_iou(np.zeros((0, 4)), b).shape == (0, 3)


def test_xywh_round_trip_and_iou():
    xywh = np.array([[10.0, 20.0, 30.0, 40.0], [0.0, 0.0, 5.0, 5.0]])
    np.testing.assert_array_equal(xywh_to_xyxy(xywh), [[10, 20, 40, 60], [0, 0, 5, 5]])
    np.testing.assert_array_equal(xyxy_to_xywh(xywh_to_xyxy(xywh)), xywh)
    assert box_iou_xywh(xywh[:1], [[25.0, 20.0, 30.0, 40.0]])[0, 0] == pytest.approx(15 * 40 / (2 * 1200 - 600))


def test_box_iou_bad_input():
    with pytest.raises(InputError, match=r"expected \(N, 4\)"):
        box_iou(np.zeros((2, 3)), np.zeros((1, 4)))
    with pytest.raises(InputError, match="NaN or inf"):
        box_iou([[0.0, 0.0, np.nan, 1.0]], [[0.0, 0.0, 1.0, 1.0]])
    with pytest.raises(InputError, match=r"boxes b\[1\]: x1 < x0"):
        box_iou([[0.0, 0.0, 1.0, 1.0]], [[0.0, 0.0, 1.0, 1.0], [5.0, 0.0, 4.0, 1.0]])


# ---- matching ----------------------------------------------------------------------------


def test_hungarian_beats_greedy_on_the_classic_case():
    # 1-D in x (every box spans y 0..10): pred A overlaps ref X best (9/11) and ref Y less (8/12);
    # pred B overlaps X (7/13) and Y only 4/16, under the threshold. Greedy gives A to X and leaves
    # B single; the assignment maximising the summed IoU pairs A-Y and B-X.
    ref = dets([[0, 0, 10, 10], [3, 0, 13, 10]])  # X, Y
    pred = dets([[1, 0, 11, 10], [-3, 0, 7, 10]])  # A, B
    iou = box_iou(pred.boxes_xyxy, ref.boxes_xyxy)
    np.testing.assert_allclose(iou, [[9 / 11, 8 / 12], [7 / 13, 4 / 16]])
    hung = match_boxes(pred, ref, MatchConfig(iou_threshold=0.3))
    np.testing.assert_array_equal(hung.pairs, [[0, 1], [1, 0]])
    np.testing.assert_allclose(hung.ious, [8 / 12, 7 / 13])
    assert hung.precision == 1.0 and hung.recall == 1.0
    assert hung.mean_iou == pytest.approx((8 / 12 + 7 / 13) / 2)
    greedy = match_boxes(pred, ref, MatchConfig(iou_threshold=0.3, method="greedy"))
    np.testing.assert_array_equal(greedy.pairs, [[0, 0]])
    assert greedy.precision == 0.5 and greedy.recall == 0.5 and greedy.mean_iou == pytest.approx(9 / 11)


def test_match_threshold_classes_and_empty():
    ref = dets([[0, 0, 10, 10]], labels=[1])
    pred = dets([[0, 0, 10, 5]], labels=[1])  # IoU 0.5 exactly
    assert match_boxes(pred, ref, MatchConfig(iou_threshold=0.5)).n_matched == 1
    assert match_boxes(pred, ref, MatchConfig(iou_threshold=0.51)).n_matched == 0
    other = dets([[0, 0, 10, 10]], labels=[2])
    assert match_boxes(other, ref).n_matched == 0
    assert match_boxes(other, ref, MatchConfig(class_aware=False)).n_matched == 1
    empty = match_boxes(Detections.empty(), ref)
    assert math.isnan(empty.precision) and empty.recall == 0.0 and math.isnan(empty.mean_iou)


def test_compare_detections_pools_counts():
    real = [dets([[0, 0, 10, 10], [20, 20, 30, 30]]), dets([[0, 0, 4, 4]])]
    sim = [dets([[0, 0, 10, 8]]), dets([[0, 0, 4, 4], [50, 50, 60, 60]])]
    result = compare_detections(sim, real)
    assert (result.n_pred, result.n_ref, result.n_matched) == (3, 3, 2)
    assert result.precision == pytest.approx(2 / 3) and result.recall == pytest.approx(2 / 3)
    assert result.mean_iou == pytest.approx((0.8 + 1.0) / 2)
    records = result.records("kitchen", "hog")
    assert records[0] == {"scene": "kitchen", "detector": "hog", "frame": 0, "n_sim": 1, "n_real": 2,
                          "ious": (pytest.approx(0.8),)}
    with pytest.raises(InputError, match="2 simulated frames but 1 real"):
        compare_detections(sim, real[:1])


# ---- NMS and YOLO decoding ---------------------------------------------------------------


def test_nms_matches_opencv():
    rng = np.random.default_rng(0)
    xy = rng.uniform(0, 200, (300, 2))
    wh = rng.uniform(10, 60, (300, 2))
    boxes = np.column_stack([xy, xy + wh])
    scores = rng.uniform(0, 1, 300)
    for thr in (0.3, 0.5, 0.7):
        ours = nms(boxes, scores, thr)
        ref = cv2.dnn.NMSBoxes(xyxy_to_xywh(boxes).tolist(), scores.tolist(), 0.0, thr)
        np.testing.assert_array_equal(ours, np.asarray(ref).ravel())


def test_nms_is_class_wise():
    boxes = np.array([[0, 0, 10, 10], [0, 0, 10, 10.0]])
    assert nms(boxes, [0.9, 0.8], 0.5).tolist() == [0]
    assert nms(boxes, [0.9, 0.8], 0.5, labels=[0, 1]).tolist() == [0, 1]


def yolov8_output(rows):
    """(1, 4 + C, N) from rows (cx, cy, w, h, class scores...)."""
    return np.asarray(rows, dtype=np.float32).T[None]


def test_decode_yolov8_hand_made():
    out = yolov8_output([
        [50, 40, 20, 10, 0.9, 0.1],   # class 0, kept
        [51, 40, 20, 10, 0.8, 0.1],   # overlaps the first, suppressed
        [51, 40, 20, 10, 0.1, 0.7],   # same box but class 1: kept (class-wise NMS)
        [10, 10, 4, 4, 0.2, 0.1],     # below the score threshold
    ])
    got = decode_yolo(out, YoloDecodeConfig(layout="columns", score_threshold=0.25, nms_iou=0.45))
    np.testing.assert_allclose(got.boxes_xyxy, [[40, 35, 60, 45], [41, 35, 61, 45]])
    np.testing.assert_allclose(got.scores, [0.9, 0.7], rtol=1e-6)
    assert got.labels.tolist() == [0, 1]
    only_people = decode_yolo(out, YoloDecodeConfig(layout="columns", classes=(1,)))
    assert only_people.labels.tolist() == [1]
    # letterboxed: input = image * 0.5 + (0, 10) -> image boxes twice as large, shifted back
    back = decode_yolo(out, YoloDecodeConfig(layout="columns"), Letterbox(0.5, 0.0, 10.0))
    np.testing.assert_allclose(back.boxes_xyxy[0], [80, 50, 120, 70])
    # "auto" reads the longer axis as the candidates: a real model's (1, 84, 8400) output
    many = np.zeros((1, 84, 8400), np.float32)
    many[0, :4, 5], many[0, 4, 5] = [50, 40, 20, 10], 0.9
    np.testing.assert_allclose(decode_yolo(many).boxes_xyxy, [[40, 35, 60, 45]])


def test_decode_yolov5_and_end2end():
    v5 = np.array([[[50, 40, 20, 10, 0.5, 0.9, 0.2], [50, 40, 20, 10, 0.2, 0.9, 0.9]]])
    got = decode_yolo(v5, YoloDecodeConfig(format="yolov5", layout="rows", score_threshold=0.25))
    np.testing.assert_allclose(got.scores, [0.45])  # objectness x class score; the second is 0.18
    e2e = np.array([[[1, 2, 3, 4, 0.9, 2], [1, 2, 3, 4, 0.8, 2], [0, 0, 1, 1, 0.1, 0]]])
    got = decode_yolo(e2e, YoloDecodeConfig(format="end2end", layout="rows"))
    assert len(got) == 2 and got.labels.tolist() == [2, 2]  # no NMS: the model did it
    with pytest.raises(InputError, match="at least 6 values"):
        decode_yolo(np.zeros((1, 10, 5)), YoloDecodeConfig(format="yolov5"))
    with pytest.raises(InputError, match="batch of 1"):
        decode_yolo(np.zeros((2, 6, 10)))


def test_letterbox_geometry():
    image = np.zeros((100, 200, 3), np.uint8)
    out, box = letterbox(image, (64, 64))
    assert out.shape == (64, 64, 3) and box.scale == pytest.approx(0.32) and (box.pad_x, box.pad_y) == (0.0, 16.0)
    assert out[0, 0, 0] == 114 and out[32, 32, 0] == 0
    np.testing.assert_allclose(box.to_image([[0, 16, 64, 48]]), [[0, 0, 200, 100]])


# ---- an ONNX model through cv2.dnn --------------------------------------------------------
# The venv has no `onnx` package (torch.onnx.export needs it), so the test writes a tiny model's
# protobuf by hand: output0 = Reshape(Conv(GlobalAveragePool(images), 0)) + pred, i.e. a constant
# YOLOv8 tensor (1, 4 + C, N) that still flows from the input through real layers.


def _varint(n: int) -> bytes:
    out = bytearray()
    while True:
        b, n = n & 0x7F, n >> 7
        out.append(b | 0x80 if n else b)
        if not n:
            return bytes(out)


def _int_field(num: int, value: int) -> bytes:
    return _varint(num << 3) + _varint(value)


def _bytes_field(num: int, value: bytes | str) -> bytes:
    value = value.encode() if isinstance(value, str) else value
    return _varint(num << 3 | 2) + _varint(len(value)) + value


def _tensor(name: str, array: np.ndarray) -> bytes:  # onnx.TensorProto
    dtype = {np.dtype(np.float32): 1, np.dtype(np.int64): 7}[array.dtype]
    return (b"".join(_int_field(1, d) for d in array.shape) + _int_field(2, dtype) + _bytes_field(8, name)
            + _bytes_field(9, array.tobytes()))


def _value_info(name: str, shape: tuple[int, ...]) -> bytes:  # onnx.ValueInfoProto, float tensor
    dims = b"".join(_bytes_field(1, _int_field(1, d)) for d in shape)
    return _bytes_field(1, name) + _bytes_field(2, _bytes_field(1, _int_field(1, 1) + _bytes_field(2, dims)))


def _node(op: str, inputs: list[str], outputs: list[str]) -> bytes:  # onnx.NodeProto
    return (b"".join(_bytes_field(1, i) for i in inputs) + b"".join(_bytes_field(2, o) for o in outputs)
            + _bytes_field(3, outputs[0]) + _bytes_field(4, op))


def tiny_yolo_onnx(pred: np.ndarray, size: int) -> bytes:
    graph = b"".join(_bytes_field(1, n) for n in (
        _node("GlobalAveragePool", ["images"], ["gap"]),
        _node("Conv", ["gap", "w"], ["zero"]),
        _node("Reshape", ["zero", "shape"], ["zero3"]),
        _node("Add", ["zero3", "pred"], ["output0"]),
    ))
    graph += _bytes_field(2, "tiny_yolo")
    graph += _bytes_field(5, _tensor("w", np.zeros((1, 3, 1, 1), np.float32)))
    graph += _bytes_field(5, _tensor("shape", np.array([1, 1, 1], np.int64)))
    graph += _bytes_field(5, _tensor("pred", pred.astype(np.float32)))
    graph += _bytes_field(11, _value_info("images", (1, 3, size, size)))
    graph += _bytes_field(12, _value_info("output0", pred.shape))
    opset = _bytes_field(1, "") + _int_field(2, 13)
    return _int_field(1, 7) + _bytes_field(7, graph) + _bytes_field(8, opset)


def test_onnx_detector_end_to_end(tmp_path):
    # network input 64x64; boxes in network pixels
    pred = yolov8_output([[32, 24, 16, 8, 0.9, 0.05], [33, 24, 16, 8, 0.6, 0.05], [8, 8, 4, 4, 0.1, 0.1]])
    path = tmp_path / "tiny.onnx"
    path.write_bytes(tiny_yolo_onnx(pred, 64))
    detector = OnnxDetector(path, OnnxConfig(input_wh=(64, 64), decode=YoloDecodeConfig(layout="columns")))
    image = np.zeros((64, 128, 3), np.uint8)  # letterboxed: scale 0.5, pad_y 16
    raw, box = detector.raw(image)
    np.testing.assert_allclose(raw, pred, atol=1e-6)
    assert (box.scale, box.pad_x, box.pad_y) == (0.5, 0.0, 16.0)
    got = detector(image)
    assert len(got) == 1 and got.labels.tolist() == [0]
    np.testing.assert_allclose(got.boxes_xyxy, [[48, 8, 80, 24]], atol=1e-4)  # (24..40, 20..28) network px


def test_onnx_detector_bad_weights(tmp_path):
    with pytest.raises(InputError, match="no such ONNX weights file"):
        OnnxDetector(tmp_path / "missing.onnx")
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"not a model")
    with pytest.raises(InputError, match="cannot read this ONNX model"):
        OnnxDetector(bad)


# ---- HOG -------------------------------------------------------------------------------------


def pedestrian(x: int, width: int = 320, height: int = 240) -> np.ndarray:
    """A dark stick figure (head, torso, arms, legs), 150 px tall, on a light background (RGB)."""
    image = np.full((height, width, 3), 200, np.uint8)
    ink, y = (40, 40, 40), 40
    cv2.circle(image, (x, y + 12), 11, ink, -1)
    cv2.ellipse(image, (x, y + 55), (17, 32), 0, 0, 360, ink, -1)
    for side in (-1, 1):
        cv2.line(image, (x + 8 * side, y + 80), (x + 14 * side, y + 140), ink, 10)
        cv2.line(image, (x + 16 * side, y + 35), (x + 24 * side, y + 85), ink, 7)
    return image


def test_hog_detects_a_pedestrian_and_matches_raw_opencv():
    detector = HogPeopleDetector(HogConfig(win_stride_px=4))
    image = pedestrian(140)
    got = detector(image)
    assert len(got) == 1 and got.labels.tolist() == [PERSON_LABEL]
    x0, y0, x1, y1 = got.boxes_xyxy[0]
    assert x0 < 140 - 24 and x1 > 140 + 24 and y0 < 52 and y1 > 180  # the box holds the figure
    # the wrapper is OpenCV's detectMultiScale plus NMS
    hog = cv2.HOGDescriptor()
    hog.setSVMDetector(cv2.HOGDescriptor_getDefaultPeopleDetector())
    rects, weights = hog.detectMultiScale(image[..., ::-1].copy(), winStride=(4, 4), padding=(8, 8), scale=1.05)
    keep = nms(xywh_to_xyxy(np.asarray(rects, float)), np.ravel(weights), 0.45)
    np.testing.assert_allclose(got.boxes_xyxy, xywh_to_xyxy(np.asarray(rects, float))[keep])
    assert len(detector(np.full((240, 320, 3), 200, np.uint8))) == 0
    # smaller than the 64x128 window: refused (OpenCV would crash), unless upscaled
    with pytest.raises(InputError, match="60x40 px .* smaller than the 64x128 px detection window"):
        detector(np.zeros((40, 60, 3), np.uint8))
    assert len(HogPeopleDetector(HogConfig(upscale=4.0))(np.zeros((40, 60, 3), np.uint8))) == 0
    small = HogPeopleDetector(HogConfig(win_stride_px=4, upscale=2.0))(cv2.resize(image, (160, 120)))
    assert len(small) == 1 and box_iou(small.boxes_xyxy, got.boxes_xyxy / 2.0)[0, 0] > 0.7  # boxes in input px


def test_detection_experiment_on_images():
    real = [pedestrian(140), pedestrian(100)]
    sim = [pedestrian(150), pedestrian(100)]  # the simulated person stands 10 px off in frame 0
    detector = HogPeopleDetector(HogConfig(win_stride_px=4))
    result = evaluate_detection(sim, real, detector, MatchConfig(iou_threshold=0.3))
    assert result.n_matched == 2 and result.precision == 1.0 and result.recall == 1.0
    s0, r0 = detector(sim[0]), detector(real[0])
    assert result.frames[0].ious[0] == pytest.approx(box_iou(s0.boxes_xyxy, r0.boxes_xyxy)[0, 0])
    assert result.frames[1].ious[0] == pytest.approx(1.0)
    assert result.mean_iou == pytest.approx((result.frames[0].ious[0] + 1.0) / 2)
    with pytest.raises(InputError, match="frame 0: simulated image is 300x240 but real is 320x240"):
        evaluate_detection([pedestrian(140, width=300)], real[:1], detector)
    with pytest.raises(InputError, match="2 simulated frames but 1 real"):
        evaluate_detection(sim, real[:1], detector)


# ---- COCO JSON -----------------------------------------------------------------------------


def coco_dataset(boxes_by_name: dict[str, list[list[float]]]) -> dict:
    images = [{"id": k + 1, "file_name": name, "width": 320, "height": 240} for k, name in enumerate(boxes_by_name)]
    pairs = [(k + 1, b) for k, boxes in enumerate(boxes_by_name.values()) for b in boxes]
    annotations = [{"id": a + 1, "image_id": image_id, "category_id": 1, "bbox": b}
                   for a, (image_id, b) in enumerate(pairs)]
    return {"images": images, "annotations": annotations, "categories": [{"id": 1, "name": "person"}]}


def test_coco_dataset_and_results(tmp_path):
    real = tmp_path / "real.json"
    real.write_text(json.dumps(coco_dataset({"f0.png": [[0, 0, 10, 10]], "f1.png": [], "f2.png": [[5, 5, 2, 2]]})))
    sim = tmp_path / "sim.json"
    sim.write_text(json.dumps(coco_dataset({"f0.png": [[0, 0, 10, 5]], "f1.png": [[1, 1, 1, 1]], "f2.png": []})))
    loaded = read_coco_detections(real)
    assert list(loaded) == ["f0.png", "f1.png", "f2.png"] and len(loaded["f1.png"]) == 0
    np.testing.assert_array_equal(loaded["f2.png"].boxes_xyxy, [[5, 5, 7, 7]])
    assert loaded["f0.png"].scores.tolist() == [1.0] and loaded["f0.png"].labels.tolist() == [1]
    result = evaluate_detection(sim, real)
    assert (result.n_pred, result.n_ref, result.n_matched) == (2, 2, 1)
    assert result.mean_iou == pytest.approx(0.5)
    # results lists round-trip through write_coco_results
    out = write_coco_results(tmp_path / "res.json", {7: loaded["f0.png"], 12: loaded["f2.png"]})
    back = read_coco_detections(out)
    assert list(back) == ["7", "12"]
    np.testing.assert_array_equal(back["12"].boxes_xyxy, loaded["f2.png"].boxes_xyxy)


@pytest.mark.parametrize("content, message", [
    ("{not json", r"bad\.json:1: not valid JSON"),
    ('"text"', "expected a COCO dataset object or a list of results"),
    ('{"images": []}', "needs a list 'annotations'"),
    ('[{"image_id": 1, "category_id": 1, "bbox": [0, 0, 1]}]', r"results\[0\]\.bbox: expected 4 numbers"),
    ('[{"image_id": 1, "category_id": 1, "bbox": [0, 0, -1, 1]}]', r"results\[0\]\.bbox: expected finite values"),
    ('[{"image_id": 1, "category_id": "a", "bbox": [0, 0, 1, 1]}]', r"results\[0\]\.category_id: expected an int"),
    ('[{"image_id": 1, "category_id": 1, "bbox": [0, 0, 1, 1], "score": "x"}]', r"results\[0\]\.score"),
    ('{"images": [{"id": 1, "file_name": "a"}, {"id": 1, "file_name": "b"}], "annotations": []}',
     r"images\[1\]\.id: duplicate image id 1"),
    ('{"images": [{"id": 1, "file_name": "a"}], "annotations": [{"image_id": 2, "category_id": 1, '
     '"bbox": [0, 0, 1, 1]}]}', r"annotations\[0\]\.image_id: 2 is not in 'images'"),
])
def test_coco_validation_errors(tmp_path, content, message):
    path = tmp_path / "bad.json"
    path.write_text(content)
    with pytest.raises(InputError, match=message):
        read_coco_detections(path)


def test_coco_datasets_must_list_the_same_images(tmp_path):
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.write_text(json.dumps(coco_dataset({"f0.png": [], "f1.png": []})))
    b.write_text(json.dumps(coco_dataset({"f0.png": []})))
    with pytest.raises(InputError, match="list different images"):
        evaluate_detection(a, b)
    with pytest.raises(InputError, match="no such file"):
        read_coco_detections(tmp_path / "missing.json")


def test_detection_experiment_images_on_disk_against_coco(tmp_path):
    from nsim.io.images import write_image

    detector = HogPeopleDetector(HogConfig(win_stride_px=4))
    paths = [write_image(tmp_path / f"sim_{k}.png", pedestrian(x)) for k, x in enumerate((140, 100))]
    real_boxes = [xyxy_to_xywh(detector(pedestrian(x)).boxes_xyxy).tolist() for x in (140, 100)]
    real = tmp_path / "real.json"
    real.write_text(json.dumps(coco_dataset({"f0.png": real_boxes[0], "f1.png": []})))
    result = evaluate_detection(paths, real, detector, MatchConfig(class_aware=False))  # COCO says category 1
    assert (result.n_pred, result.n_ref, result.n_matched) == (2, 1, 1)
    assert result.frames[0].ious[0] == pytest.approx(1.0) and result.precision == 0.5
    with pytest.raises(InputError, match="has 2 images but 1 frames were given"):
        evaluate_detection(paths[:1], real, detector)
