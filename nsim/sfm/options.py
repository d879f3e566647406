"""How to run SfM: :class:`SfmOptions`, the one definition of every SfM setting and its bounds.

``nsim.sfm.colmap.run_sfm`` takes these options. The stage configs that pass SfM settings on, ``reconstruct``'s
``Config`` and ``evaluate``'s ``slam`` section, declare their fields with
``nsim.config.param_from(SfmOptions, name)``, so their bounds, choices and help are these.

This module is plain Python (no pycolmap, no cv2), so that a stage config can import it while
its module loads.
"""

from __future__ import annotations

from dataclasses import dataclass

from nsim.config import check_params, param

CAMERA_MODELS = ("SIMPLE_RADIAL", "OPENCV", "OPENCV_FISHEYE", "PINHOLE")
MATCHERS = ("sequential", "exhaustive")
DEVICES = ("cpu", "cuda")
#: Horizontal fields of view tried in turn for the initial focal length when intrinsics are unknown.
DEFAULT_HFOV_GUESSES_DEG = {
    "SIMPLE_RADIAL": (65.0, 45.0, 90.0),
    "OPENCV": (65.0, 45.0, 90.0),
    "PINHOLE": (65.0, 45.0, 90.0),
    "OPENCV_FISHEYE": (180.0, 140.0, 220.0),
}
FISHEYE_MODELS = ("OPENCV_FISHEYE",)
PP_REFINE_CHOICES = ("auto", "on", "off")


@dataclass(frozen=True)
class SfmOptions:
    """How to run SfM.

    camera_model: COLMAP model estimated when no camera is known (SIMPLE_RADIAL comes back as
        an nsim OPENCV camera with only k1). shared_intrinsics: one camera for all images.
    matcher: "sequential" for ordered video frames (each image against its ``overlap`` next
        ones and quadratically further ones, plus retrieval-based loop pairs with
        ``loop_detection``; also enables the pose-jump check), "exhaustive" for small or
        unordered sets. max_features: SIFT features per image.
    device: "cpu" or "cuda" (SIFT on the GPU when pycolmap has CUDA, else a warning and CPU).
    num_threads: extraction threads, and matching threads unless deterministic (-1: all cores). seed / deterministic: see
        the ``nsim.sfm.colmap`` docstring. min_registered_fraction: fewer registered images is an
        InputError (and fewer than two always). retry_below_fraction: map again with the next focal
        guess below this.
    refine_known_intrinsics: let bundle adjustment refine a ``known_camera``.
    hfov_guesses_deg: initial fields of view to try (None: ``DEFAULT_HFOV_GUESSES_DEG``).
    focal_prior_hfov_deg: a field of view the images themselves state (EXIF 35 mm-equivalent focal
        length, see ``nsim.sfm.frames.exif_hfov_deg``): tried first, as a focal-length prior.
    refine_principal_point: "off" keeps it at the image centre; "on" lets the final bundle
        adjustment refine it; "auto" refines it on a copy and keeps the result only when the data
        supports it (see ``nsim.sfm.colmap.PP_AUTO_MIN_IMAGES``, ``PP_AUTO_MIN_GAIN``, ``PP_AUTO_MAX_SHIFT``).

    Bounds (checked on construction, and by the config loader in the stage configs that mirror
    these fields): where the stage configs and this class once disagreed, max_features is
    >= 64 (not 16: the stage configs' bound; fewer features cannot chain a video's views) and
    min_registered_fraction is in [0, 1] (not (0, 1]: 0 is meaningful, "any two images").
    """

    camera_model: str = param("SIMPLE_RADIAL", choices=CAMERA_MODELS, help="COLMAP model estimated for the camera")
    shared_intrinsics: bool = param(True, help="one camera for all images")
    matcher: str = param("sequential", choices=MATCHERS,
                         help="sequential: ordered video frames; exhaustive: small or unordered sets")
    overlap: int = param(10, ge=1, help="sequential matching: each frame against this many next ones")
    loop_detection: bool = param(True, help="sequential matching: add retrieval-based loop-closure pairs")
    max_features: int = param(8192, ge=64, help="SIFT features per image")
    device: str = param("cpu", choices=DEVICES, help="where SIFT runs (cuda: when pycolmap has CUDA)")
    num_threads: int = param(-1, help="extraction threads, and matching threads unless deterministic (-1: all cores)")
    seed: int = 0
    deterministic: bool = param(True, help="matching, mapping and bundle adjustment on one thread (bit-for-bit repeatable)")
    min_registered_fraction: float = param(0.5, ge=0.0, le=1.0,
                                           help="fewer registered images (or fewer than two): SfM failed")
    retry_below_fraction: float = param(0.95, ge=0.0, le=1.0,
                                        help="map again with the next focal guess while fewer images register")
    refine_known_intrinsics: bool = param(False, help="let bundle adjustment refine a known camera")
    hfov_guesses_deg: tuple[float, ...] | None = param(None, help="initial horizontal fields of view to try")
    focal_prior_hfov_deg: float | None = param(None, gt=0.0, lt=180.0,
                                               help="a field of view the images state (EXIF), tried first")
    refine_principal_point: str = param("auto", choices=PP_REFINE_CHOICES,
                                        help="free the principal point in the final bundle adjustment "
                                             "(auto: when it lowers the error, see nsim.sfm.colmap)")

    def __post_init__(self) -> None:
        check_params(self)
        if self.hfov_guesses_deg is not None:
            limit = 360.0 if self.camera_model in FISHEYE_MODELS else 180.0
            if not self.hfov_guesses_deg or not all(0.0 < h < limit for h in self.hfov_guesses_deg):
                raise ValueError(f"hfov_guesses_deg: expected values in (0, {limit:g}), got {self.hfov_guesses_deg}")

    @property
    def hfov_guesses(self) -> tuple[float, ...]:
        guesses = self.hfov_guesses_deg or DEFAULT_HFOV_GUESSES_DEG[self.camera_model]
        if self.focal_prior_hfov_deg is not None:
            return (self.focal_prior_hfov_deg, *[g for g in guesses if g != self.focal_prior_hfov_deg])
        return guesses
