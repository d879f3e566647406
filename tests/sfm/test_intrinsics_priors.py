"""Intrinsics the data can tell: an off-centre principal point (refined when the data supports it)
and a focal length stated in EXIF (used as the first guess and as a prior)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from PIL import Image

from nsim.geometry.cameras import Camera
from nsim.io.images import to_uint8, write_image
from nsim.sfm.colmap import initial_focal_px, run_sfm
from nsim.sfm.frames import exif_focal_35mm, exif_hfov_deg
from nsim.sfm.options import SfmOptions
from nsim.synth import oracle as synth_oracle
from nsim.synth import path as synth_path
from nsim.synth import room as synth_room


def _jpeg(path, focal_35mm=None, size=(64, 48)):
    im = Image.fromarray(np.full((size[1], size[0], 3), 128, np.uint8))
    exif = Image.Exif()
    if focal_35mm is not None:
        exif.get_ifd(0x8769)[0xA405] = focal_35mm
    im.save(path, exif=exif.tobytes())
    return path


def test_exif_focal_gives_the_field_of_view(tmp_path):
    a = _jpeg(tmp_path / "a.jpg", 26)
    b = _jpeg(tmp_path / "b.jpg", 26)
    c = _jpeg(tmp_path / "c.jpg", 52)
    none = _jpeg(tmp_path / "d.jpg")
    assert exif_focal_35mm(a) == 26.0 and exif_focal_35mm(none) is None
    hfov = exif_hfov_deg([a, b])
    # a 26 mm-equivalent lens (a phone's main camera) spans about 69 degrees across the long side
    assert hfov == pytest.approx(2 * np.degrees(np.arctan(18 / 26)))
    assert 68.0 < hfov < 70.0
    # the focal length in pixels it implies: f35 / 36 mm of the long side
    assert initial_focal_px("SIMPLE_RADIAL", 1920, 1080, hfov) == pytest.approx(26 / 36 * 1920)
    assert exif_hfov_deg([a, c]) is None and exif_hfov_deg([a, none]) is None
    opts = SfmOptions(focal_prior_hfov_deg=hfov)
    assert opts.hfov_guesses[0] == hfov and len(opts.hfov_guesses) == len(SfmOptions().hfov_guesses) + 1
    with pytest.raises(ValueError, match="refine_principal_point"):
        SfmOptions(refine_principal_point="maybe")


@pytest.mark.slow
def test_off_centre_principal_point_is_refined_when_the_data_supports_it(tmp_path):
    spec = synth_room.make_room("robot-lab", 0)
    n, w, h = 100, 160, 120
    centred = Camera.pinhole_from_fov(w, h, 75.0)
    true_cx, true_cy = centred.cx + 9.0, centred.cy - 6.0  # a phone's lens, off its sensor's centre
    camera = dataclasses.replace(centred, cx=true_cx, cy=true_cy)
    poses = synth_path.handheld_path(spec, n, seed=0)
    oracle = synth_oracle.RoomOracle(spec)
    (tmp_path / "images").mkdir()
    for i, c2w in enumerate(poses):
        write_image(tmp_path / "images" / f"frame_{i:05d}.png",
                    to_uint8(oracle.render_gt(camera, c2w, supersample=2).rgb))
    auto = run_sfm(tmp_path / "images", tmp_path / "auto", SfmOptions(camera_model="PINHOLE"))
    off = run_sfm(tmp_path / "images", tmp_path / "off", SfmOptions(camera_model="PINHOLE",
                                                                   refine_principal_point="off"))
    pp_auto = auto.stats.principal_point
    assert pp_auto["refined"], pp_auto
    cam = next(iter(auto.cameras.values()))
    # within 2 px of the truth (the vertical offset trades a little against pitch), against 9 and 6 px at the centre
    assert (cam.cx, cam.cy) == pytest.approx((true_cx, true_cy), abs=2.0), (cam, pp_auto)
    assert off.stats.principal_point == {"mode": "off", "refined": False}
    cam_off = next(iter(off.cameras.values()))
    assert cam_off.cx == pytest.approx(centred.cx) and cam_off.cy == pytest.approx(centred.cy)
    assert auto.stats.mean_reprojection_error_px < off.stats.mean_reprojection_error_px
