"""TUM RGB-D trajectories: one pose per line, `timestamp tx ty tz qx qy qz qw`.

A pose maps body to world (body_to_world, i.e. the body's position and orientation in the world). TUM
stores the quaternion xyzw on disk; nsim holds it wxyz (`orientations_quat_wxyz`) everywhere else.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from nsim.errors import InputError
from nsim.io import atomic_path
from nsim.io.canonical import round_decimals

log = logging.getLogger(__name__)

TUM_HEADER = "# timestamp tx ty tz qx qy qz qw"
QUAT_NORM_TOLERANCE = 1e-3


@dataclass(frozen=True)
class Trajectory:
    """N stamped body-to-world poses.

    timestamps_s: (N,) float64 seconds; positions_xyz: (N, 3) float64 metres;
    orientations_quat_wxyz: (N, 4) float64 unit quaternions, scalar first.
    """

    timestamps_s: np.ndarray
    positions_xyz: np.ndarray
    orientations_quat_wxyz: np.ndarray

    def __post_init__(self) -> None:
        n = np.shape(self.timestamps_s)[0] if np.ndim(self.timestamps_s) == 1 else -1
        for name, shape in (
            ("timestamps_s", (n,)),
            ("positions_xyz", (n, 3)),
            ("orientations_quat_wxyz", (n, 4)),
        ):
            value = np.asarray(getattr(self, name), dtype=np.float64)
            if value.shape != shape:
                raise ValueError(
                    f"Trajectory.{name}: expected shape {shape} (N = len(timestamps_s)), got {value.shape}"
                )
            object.__setattr__(self, name, value)

    def __len__(self) -> int:
        return len(self.timestamps_s)

    def poses_se3(self) -> np.ndarray:
        """(N, 4, 4) float64 body-to-world rigid transforms."""
        poses = np.tile(np.eye(4), (len(self), 1, 1))
        if len(self):
            poses[:, :3, :3] = Rotation.from_quat(self.orientations_quat_wxyz, scalar_first=True).as_matrix()
        poses[:, :3, 3] = self.positions_xyz
        return poses

    @classmethod
    def from_poses(cls, timestamps_s: np.ndarray, poses_se3: np.ndarray) -> Trajectory:
        """Build from (N,) timestamps and (N, 4, 4) body-to-world poses; quaternions get w >= 0."""
        poses_se3 = np.asarray(poses_se3, dtype=np.float64)
        if poses_se3.ndim != 3 or poses_se3.shape[1:] != (4, 4):
            raise ValueError(f"Trajectory.from_poses: expected (N, 4, 4) poses, got {poses_se3.shape}")
        quat_wxyz = np.empty((len(poses_se3), 4))
        if len(poses_se3):
            rotation = Rotation.from_matrix(poses_se3[:, :3, :3])
            quat_wxyz = rotation.as_quat(canonical=True, scalar_first=True)
        return cls(np.asarray(timestamps_s, dtype=np.float64), poses_se3[:, :3, 3].copy(), quat_wxyz)


def read_tum(path: str | os.PathLike) -> Trajectory:
    """Read a TUM trajectory file; `#` comment lines and blank lines are skipped.

    Raises InputError naming the file and line for a wrong column count, a non-numeric or non-finite
    value, a quaternion whose norm is off 1 by more than 1e-3 (kept as read, not renormalised), a
    timestamp before the previous one, or a file with no poses. A pose that repeats the previous pose's
    timestamp (real ground-truth files have them: TUM's fr2/desk has one) is dropped with a warning
    naming the count and the first line, as trajectory tools such as evo accept such files.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(f"{path}: cannot read as text ({err})") from None
    rows, line_numbers = [], []
    for number, line in enumerate(text.splitlines(), start=1):
        tokens = line.split()
        if not tokens or tokens[0].startswith("#"):
            continue
        if len(tokens) != 8:
            raise InputError(f"{path}:{number}: expected 8 columns '{TUM_HEADER[2:]}', got {len(tokens)}")
        try:
            rows.append([float(t) for t in tokens])
        except ValueError:
            raise InputError(f"{path}:{number}: non-numeric value in {line.strip()!r}") from None
        line_numbers.append(number)
    if not rows:
        raise InputError(f"{path}: no poses")
    data = np.array(rows)

    def check(bad: np.ndarray, message: str) -> None:
        if bad.any():
            raise InputError(f"{path}:{line_numbers[int(np.argmax(bad))]}: {message}")

    check(~np.isfinite(data).all(axis=1), "non-finite value (NaN or inf)")
    norms = np.linalg.norm(data[:, 4:], axis=1)
    check(
        np.abs(norms - 1.0) > QUAT_NORM_TOLERANCE,
        f"quaternion is not unit (norm off 1 by > {QUAT_NORM_TOLERANCE})",
    )
    check(np.r_[False, np.diff(data[:, 0]) < 0], "timestamp is before the previous pose's")
    repeat = np.r_[False, np.diff(data[:, 0]) == 0]
    if repeat.any():
        first = line_numbers[int(np.argmax(repeat))]
        log.warning("%s: %d pose(s) repeat the previous pose's timestamp (first at line %d); kept the first pose "
                    "of each timestamp", path, int(repeat.sum()), first)
        data = data[~repeat]
    return Trajectory(data[:, 0], data[:, 1:4], data[:, [7, 4, 5, 6]])


def write_tum(path: str | os.PathLike, traj: Trajectory) -> Path:
    """Write `traj` atomically as a TUM file with a header comment; stamps as `repr` (exact round trip), positions
    and quaternions rounded to 1e-9 (``nsim.io.canonical``: the same bytes on every CPU, no ``-0``)."""
    data = np.column_stack(
        [traj.timestamps_s, round_decimals(traj.positions_xyz), round_decimals(traj.orientations_quat_wxyz[:, [1, 2, 3, 0]])]
    )
    lines = [TUM_HEADER] + [" ".join(map(repr, row)) for row in data.tolist()]
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n")
    return path


def associate(traj_a: Trajectory, traj_b: Trajectory, max_dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Match poses by timestamp: nearest pairs first, each pose used at most once, |dt| <= max_dt_s.

    The greedy global matching of TUM's `associate.py`. Returns (idx_a, idx_b): (M,) int64 indices into
    `traj_a` and `traj_b`, sorted by idx_a; ties in |dt| go to the lower idx_a, then the lower idx_b.
    """
    if not max_dt_s >= 0:
        raise ValueError(f"associate: max_dt_s must be >= 0, got {max_dt_s}")
    t_a, t_b = traj_a.timestamps_s, traj_b.timestamps_s
    order_b = np.argsort(t_b, kind="stable")
    # Candidate window per pose of a, widened so float rounding never drops a pair; filtered exactly below.
    lo = np.searchsorted(t_b[order_b], t_a - 2 * max_dt_s, side="left")
    hi = np.searchsorted(t_b[order_b], t_a + 2 * max_dt_s, side="right")
    counts = hi - lo
    cand_a = np.repeat(np.arange(len(t_a)), counts)
    cand_b = order_b[np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts - lo, counts)]
    dt = np.abs(t_a[cand_a] - t_b[cand_b])
    within = dt <= max_dt_s
    cand_a, cand_b, dt = cand_a[within], cand_b[within], dt[within]
    used_a = np.zeros(len(t_a), dtype=bool)
    used_b = np.zeros(len(t_b), dtype=bool)
    pairs = []
    for k in np.lexsort((cand_b, cand_a, dt)).tolist():
        i, j = cand_a[k], cand_b[k]
        if not (used_a[i] or used_b[j]):
            used_a[i] = used_b[j] = True
            pairs.append((i, j))
    matched = np.array(sorted(pairs), dtype=np.int64).reshape(-1, 2)
    return matched[:, 0], matched[:, 1]
