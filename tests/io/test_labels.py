"""Label strips on preview images (nsim.io.labels): present, not blank, the image below unchanged."""

import numpy as np
import pytest

from nsim.io.labels import LABEL_HEIGHT_PX, add_label, label_strip, tile_grid


def _image(h=30, w=120, seed=0):
    return np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)


def _ink(strip: np.ndarray) -> np.ndarray:
    """Pixels with text on them (the strip is white, the text black)."""
    return strip.min(axis=-1) < 128 if strip.ndim == 3 else strip < 128


def test_label_strip_on_top_image_unchanged():
    im = _image()
    out = add_label(im, "frontleft  t 1.20 s")
    assert LABEL_HEIGHT_PX % 2 == 0 and out.shape == (30 + LABEL_HEIGHT_PX, 120, 3) and out.dtype == np.uint8
    np.testing.assert_array_equal(out[LABEL_HEIGHT_PX:], im)
    strip = out[:LABEL_HEIGHT_PX]
    assert 20 < _ink(strip).sum() < strip.shape[0] * strip.shape[1] // 2  # text, on a mostly white strip
    assert (strip == 255).all(axis=-1).mean() > 0.5
    assert not np.shares_memory(out, im)


def test_grey_image_gets_a_grey_strip():
    im = _image()[..., 0]
    out = add_label(im, "depth")
    assert out.shape == (30 + LABEL_HEIGHT_PX, 120)
    np.testing.assert_array_equal(out[LABEL_HEIGHT_PX:], im)
    assert _ink(out[:LABEL_HEIGHT_PX]).any()


def test_deterministic_and_says_what_it_is_given():
    im = _image()
    np.testing.assert_array_equal(add_label(im, "render"), add_label(im.copy(), "render"))
    assert not np.array_equal(add_label(im, "render"), add_label(im, "ground truth"))
    # the strip depends only on the width and the text, not on the image below
    np.testing.assert_array_equal(add_label(im, "x")[:LABEL_HEIGHT_PX], add_label(_image(seed=1), "x")[:LABEL_HEIGHT_PX])


def test_columns_for_side_by_side_images():
    render, truth = _image(24, 80, 1), _image(24, 80, 2)
    out = add_label(np.concatenate([render, truth], axis=1), ["render", "ground truth"])
    np.testing.assert_array_equal(out[LABEL_HEIGHT_PX:, :80], render)
    np.testing.assert_array_equal(out[LABEL_HEIGHT_PX:, 80:], truth)
    ink = _ink(out[:LABEL_HEIGHT_PX])
    assert ink[:, :80].any() and ink[:, 80:].any()
    # each text starts at its own column's left edge: nothing drawn in the first pixels of a column
    assert not ink[:, 80:82].any()
    # one column holding "ground truth" draws it where the second column of the pair does
    np.testing.assert_array_equal(out[:LABEL_HEIGHT_PX, 80:], label_strip(80, "ground truth"))


def test_long_text_is_shrunk_then_cut_inside_the_strip():
    strip = label_strip(60, "a label much longer than sixty pixels could ever hold")
    ink = _ink(strip)
    assert ink.any() and not ink[:, -2:].any()
    # cut: what follows the shown part does not matter
    np.testing.assert_array_equal(strip, label_strip(60, "a label much longer than sixty pixels could ever hold!!"))
    # a text that fits after shrinking is shown whole, smaller than usual
    assert not np.array_equal(label_strip(60, "frame 12"), label_strip(60, "frame 1"))
    # too narrow for any text: a blank strip, no error
    assert not _ink(label_strip(6, "x")).any()
    # non-ASCII characters are drawn as '?', not an error
    assert _ink(label_strip(120, "t = 1.2 s \u2014 \u00fc")).any()


def test_bad_input():
    with pytest.raises(ValueError, match="uint8"):
        add_label(np.zeros((4, 4, 3), np.float32), "x")
    with pytest.raises(ValueError, match="non-empty"):
        add_label(np.zeros((0, 4, 3), np.uint8), "x")
    with pytest.raises(ValueError, match="at least one text"):
        label_strip(10, [])


def test_tile_grid_places_tiles_in_rows():
    tiles = [add_label(_image(10, 16, k), f"#{k}") for k in range(5)]
    h, w = tiles[0].shape[:2]
    sheet = tile_grid(tiles, ncol=2, pad=3)
    assert sheet.shape == (3 + 3 * (h + 3), 3 + 2 * (w + 3), 3)
    for k, t in enumerate(tiles):
        y, x = 3 + (k // 2) * (h + 3), 3 + (k % 2) * (w + 3)
        np.testing.assert_array_equal(sheet[y:y + h, x:x + w], t)
    assert (sheet[:3] == 255).all() and (sheet[-(h + 3):, 3 + w + 3:] == 255).all()  # padding, empty cell
