"""The one atomic write (``nsim.io.atomic_path`` and its text/bytes forms) and the writers routed through it."""

from __future__ import annotations

import io

import numpy as np
import pytest

from nsim.config import configs_dir
from nsim.io import atomic_path, atomic_write_bytes, atomic_write_text


def test_write_then_rename_leaves_only_the_file(tmp_path):
    p = atomic_write_text(tmp_path / "a.txt", "héllo\nworld\n")
    assert p == tmp_path / "a.txt" and p.read_bytes() == "héllo\nworld\n".encode()
    atomic_write_bytes(tmp_path / "a.txt", b"\x00\x01")
    assert (tmp_path / "a.txt").read_bytes() == b"\x00\x01"
    assert sorted(x.name for x in tmp_path.iterdir()) == ["a.txt"]


def test_a_failed_write_keeps_the_old_file_and_no_temp(tmp_path):
    target = tmp_path / "a.json"
    target.write_text("old")
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half")
        assert tmp.parent == tmp_path and tmp.name.startswith(".a.json.") and tmp.suffix == ".json"
        raise RuntimeError("killed")
    assert target.read_text() == "old"
    assert sorted(x.name for x in tmp_path.iterdir()) == ["a.json"]


def test_a_named_temp_is_used_and_cleaned(tmp_path):
    target, named = tmp_path / "k.summary.json", tmp_path / ".k.host.123.abc.tmp.summary.json"
    seen = []
    with atomic_path(target, tmp=named) as tmp:
        seen.append(tmp)
        tmp.write_text("{}")
    assert seen == [named] and target.read_text() == "{}" and not named.exists()
    with pytest.raises(OSError):  # the caller's directory must exist
        atomic_write_text(tmp_path / "missing" / "x.txt", "x")


def test_write_gif_is_atomic_and_unchanged(tmp_path):
    """Same bytes as Pillow writing the file directly (the writer before atomic_path), nothing else left."""
    from PIL import Image

    from nsim.train.human import write_gif

    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 256, (12, 16, 3), dtype=np.uint8) for _ in range(3)]
    out = write_gif(tmp_path / "turn.gif", frames, fps=10.0)
    images = [Image.fromarray(f) for f in frames]
    ref = io.BytesIO()
    images[0].save(ref, format="GIF", save_all=True, append_images=images[1:], duration=100, loop=0, optimize=False)
    assert out.read_bytes() == ref.getvalue()
    assert sorted(x.name for x in tmp_path.iterdir()) == ["turn.gif"]


def test_write_bvh_is_atomic_and_unchanged(tmp_path):
    from nsim.human.bvh import format_bvh, read_bvh, write_bvh

    clip = read_bvh(configs_dir() / "motions" / "walk.bvh")
    out = write_bvh(tmp_path / "walk.bvh", clip)
    assert out.read_bytes() == format_bvh(clip).encode("utf-8")
    assert sorted(x.name for x in tmp_path.iterdir()) == ["walk.bvh"]
