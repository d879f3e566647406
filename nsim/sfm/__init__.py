"""Structure from motion for ``nsim reconstruct``: frames in, metric poses and sparse points out.

``frames``  sharp, distinct frames from a video (two decoding passes), or a folder of images;
``colmap``  SIFT, sequential (with loop detection) or exhaustive matching, incremental mapping
            and global bundle adjustment with pycolmap, deterministic for a fixed input;
``align``   Sim(3) fits, association with a reference, floor-plane gravity alignment, metric
            scale helpers and pose errors against ground truth (plain numpy);
``metric``  the scale-and-frame step: reference trajectory, known distance or camera height;
``imported`` poses from an exported transforms.json instead of SfM, through the same step;
``plot``    the top-down PNG of the camera path over the sparse points.

No workspace code here: paths and arrays in, results out (the stage is ``nsim.stages.reconstruct``).
Import ``nsim.sfm.colmap`` (or ``cv2``) before ``pycolmap`` anywhere: see ``nsim.sfm.colmap``.
"""
