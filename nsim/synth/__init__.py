"""The test room: a seeded synthetic room with exact ground truth (geometry, images, depth, LiDAR).

Core only (arrays in, arrays out, no workspace I/O). Import from the modules; this package
imports nothing on purpose, so ``nsim.synth.room`` stays cheap (no torch, no OpenCV):

* ``room``: ``RoomSpec``, ``make_room(preset, seed)``, ``ROOM_PRESETS``, footprints and occupancy;
* ``textures``: photos from scikit-image, ``sample_texture``, per-face baking and mip sampling;
* ``raycast``: ``cast(spec, origins, dirs, textures) -> RayHits``, ``Lighting``;
* ``path``: ``handheld_path(spec, n_frames, seed)``, ``handheld_path_at`` (between frames), ``timestamps_s``;
* ``phone``: ``PhoneConfig`` and the phone camera model (exposure and white-balance drift, noise,
  motion blur, rolling shutter, vignetting, JPEG) applied to the oracle's renders;
* ``oracle``: ``RoomOracle`` (``render_gt``, ``cast_rays``, ``lidar_gt``).
"""
