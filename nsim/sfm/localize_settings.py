"""The localisation's defaults (``nsim.sfm.localize``), apart from it: ``nsim register-log``'s config takes its
defaults from here, and reading a config must not load OpenCV or pycolmap."""

#: SIFT features per image (``nsim reconstruct``'s ``max_features`` default).
MAX_FEATURES = 8192
#: A scene keypoint takes the 3D point of the model's observation within this many pixels.
MAX_OBSERVATION_PX = 1.5
#: Keypoints per scene image (and query descriptors) compared during retrieval.
RETRIEVAL_PER_IMAGE = 256
RETRIEVAL_QUERY_FEATURES = 1024
#: Lowe's ratio test and the largest distance of unit SIFT descriptors (COLMAP's matcher defaults).
RATIO = 0.8
MAX_DESCRIPTOR_DISTANCE = 0.7
#: Scene images matched in full, inliers a pose needs, and the RANSAC threshold as a fraction of
#: max(width, height) when none is given (12 px at COLMAP's 1200 px default image, 2 px at 200 px).
TOP_K = 5
MIN_INLIERS = 20
MAX_ERROR_FRACTION = 0.01
MIN_MAX_ERROR_PX = 2.0
