"""Structure from motion for ``nsim reconstruct`` (frames in, metric poses and sparse points out) and
for registering a robot's recording into a scene (``nsim register-log``).

``frames``  sharp, distinct frames from a video (two decoding passes), or a folder of images;
``colmap``  SIFT, sequential (with loop detection) or exhaustive matching, incremental mapping
            and global bundle adjustment with pycolmap, deterministic for a fixed input;
``align``   Sim(3) fits, association with a reference, floor-plane gravity alignment, metric
            scale helpers and pose errors against ground truth (plain numpy);
``metric``  the scale-and-frame step: reference trajectory, known distance or camera height;
``imported`` poses from an exported transforms.json instead of SfM, through the same step;
``reconstruction`` the frames, SfM and that step as the ``poses`` artifact's files (``nsim reconstruct``);
``plot``    the top-down PNG of the camera path over the sparse points;
``localize`` single images (a robot's frames) localised in a scene's sparse model;
``register`` a robot's odometry trajectory fitted to its localised frames (frame, clock offset).

No workspace code here: paths and arrays in, results out (the stages are ``nsim.stages.reconstruct``
and ``nsim.stages.register_log``).
Import ``nsim.sfm.colmap`` (or ``cv2``) before ``pycolmap`` anywhere: see ``nsim.sfm.colmap``.
"""
