"""Textures: offline photos, bilinear sampling against a plain twin, baked faces and mip sampling."""

from __future__ import annotations

import socket

import numpy as np
import pytest

from nsim.synth import textures
from nsim.synth.room import ROOM_PRESETS, room_faces
from nsim.synth.textures import PHOTO_NAMES, bake_room_textures, load_photo, sample_faces, sample_texture
from tests.synth.simple_room import simple_spec


def test_every_photo_loads_offline(monkeypatch):
    def no_network(*args, **kwargs):
        raise OSError("network disabled in this test")

    monkeypatch.setattr(socket.socket, "connect", no_network)
    monkeypatch.setattr(socket, "create_connection", no_network)
    textures._load_photo_cached.cache_clear()
    for name in PHOTO_NAMES:
        photo = load_photo(name)
        assert photo.ndim == 3 and photo.shape[2] == 3 and min(photo.shape[:2]) >= 150, name
        assert photo.dtype == np.float32 and 0.0 <= photo.min() and photo.max() <= 1.0
        assert not photo.flags.writeable
    with pytest.raises(ValueError, match="valid: astronaut"):
        load_photo("lena")


def _bilinear_twin(tex: np.ndarray, uv_m: np.ndarray, mpt: float, mode: str) -> np.ndarray:
    """Plain per-sample loop: the reference for ``sample_texture``."""
    H, W = tex.shape[:2]
    out = np.zeros((len(uv_m), tex.shape[2]))
    for n, (u, v) in enumerate(uv_m):
        x, y = u / mpt - 0.5, v / mpt - 0.5
        x0, y0 = int(np.floor(x)), int(np.floor(y))
        fx, fy = x - x0, y - y0
        for dy, wy in ((0, 1 - fy), (1, fy)):
            for dx, wx in ((0, 1 - fx), (1, fx)):
                xi, yi = x0 + dx, y0 + dy
                if mode == "wrap":
                    xi, yi = xi % W, yi % H
                else:
                    xi, yi = min(max(xi, 0), W - 1), min(max(yi, 0), H - 1)
                out[n] += wx * wy * tex[yi, xi]
    return out


@pytest.mark.parametrize("mode", ["wrap", "clamp"])
def test_sample_texture_matches_plain_twin(mode):
    rng = np.random.default_rng(0)
    tex = rng.random((7, 11, 3)).astype(np.float32)
    uv = rng.uniform(-0.2, 0.3, size=(300, 2))
    np.testing.assert_allclose(sample_texture(tex, uv, 0.02, mode), _bilinear_twin(tex, uv, 0.02, mode), atol=1e-5)


def test_sample_texture_texel_centres_and_wrap():
    tex = np.random.default_rng(1).random((5, 6, 3)).astype(np.float32)
    mpt = 0.1
    ii, jj = np.meshgrid(np.arange(5), np.arange(6), indexing="ij")
    uv = np.stack([(jj.ravel() + 0.5) * mpt, (ii.ravel() + 0.5) * mpt], axis=-1)
    np.testing.assert_allclose(sample_texture(tex, uv, mpt), tex.reshape(-1, 3), atol=1e-6)
    period = np.array([6 * mpt, 5 * mpt])
    np.testing.assert_allclose(sample_texture(tex, uv + 3 * period, mpt), tex.reshape(-1, 3), atol=1e-5)
    with pytest.raises(ValueError):
        sample_texture(tex, uv, mpt, mode="mirror")


def test_baked_faces_cover_each_face_and_are_deterministic():
    spec = simple_spec()
    tex = bake_room_textures(spec)
    faces = room_faces(spec)
    assert tex.n_faces == len(faces) and tex.texels.dtype == np.uint32
    for f, face in enumerate(faces):
        h, w = tex.level_shape[f, 0]
        assert w == round(face.size_uv_m[0] / face.material.metres_per_texel)
        np.testing.assert_allclose(tex.texels_per_m[f, 0], (w / face.size_uv_m[0], h / face.size_uv_m[1]))
        assert tuple(tex.level_shape[f, -1]) == (1, 1)
    again = bake_room_textures(simple_spec())
    np.testing.assert_array_equal(tex.texels, again.texels)


def test_sample_faces_level0_equals_sample_texture_twin():
    spec = simple_spec()
    tex = bake_room_textures(spec)
    rng = np.random.default_rng(2)
    for f in (0, 2, 6, 11):  # floor, a wall, two cube faces
        size = np.array(room_faces(spec)[f].size_uv_m)
        uv = rng.uniform(0.0, 1.0, size=(200, 2)) * size
        uv_texels = uv * tex.texels_per_m[f, 0]  # in texel units: metres_per_texel = 1
        want = sample_texture(tex.face_image(f), uv_texels, 1.0, mode="clamp")
        got = sample_faces(tex, np.full(len(uv), f), uv)
        np.testing.assert_allclose(got, want, atol=1e-5)


def test_footprint_selects_blurrier_mips():
    spec = simple_spec()
    tex = bake_room_textures(spec)
    rng = np.random.default_rng(3)
    uv = rng.uniform(0.2, 3.5, size=(4000, 2))
    face = np.full(len(uv), 2)
    sharp = sample_faces(tex, face, uv)
    tiny = sample_faces(tex, face, uv, footprint_m=np.full(len(uv), 1e-4))
    np.testing.assert_allclose(tiny, sharp, atol=1e-6)  # below a texel: level 0
    stds = [sample_faces(tex, face, uv, footprint_m=np.full(len(uv), fp)).std() for fp in (0.005, 0.04, 0.3)]
    assert stds[0] > stds[1] > stds[2]
    coarse = sample_faces(tex, face, uv, footprint_m=np.full(len(uv), 100.0))  # whole face: its mean colour
    np.testing.assert_allclose(coarse, np.broadcast_to(tex.face_image(2, tex.n_levels - 1)[0, 0], coarse.shape),
                               atol=1e-6)


def test_preset_faces_are_rich_in_texture(oracles):
    """At the scale a 640 px camera sees from a few metres (mip 1), no large face is mostly flat."""
    for name in ROOM_PRESETS:
        tex = oracles[name].textures
        for f, face in enumerate(room_faces(oracles[name].spec)):
            if min(face.size_uv_m) < 0.3:
                continue
            g = tex.face_image(f, 1).mean(axis=-1)
            h, w = (s // 8 * 8 for s in g.shape)
            block_std = g[:h, :w].reshape(h // 8, 8, w // 8, 8).std(axis=(1, 3))
            assert (block_std < 0.01).mean() < 0.35, (name, f, face.material.texture)
