import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from nsim.errors import InputError
from nsim.io.tum import Trajectory, associate, read_tum, write_tum


def make_traj(n: int, seed: int = 0, t0_s: float = 1305031102.175304) -> Trajectory:
    rng = np.random.default_rng(seed)
    timestamps_s = t0_s + np.cumsum(rng.uniform(0.01, 0.05, n))
    quat_wxyz = rng.normal(size=(n, 4))
    quat_wxyz /= np.linalg.norm(quat_wxyz, axis=1, keepdims=True)
    return Trajectory(timestamps_s, rng.normal(scale=5.0, size=(n, 3)), quat_wxyz)


def assert_traj_equal(actual: Trajectory, expected: Trajectory) -> None:
    """Stamps exact; positions and quaternions as written: rounded to 1e-9 (nsim.io.canonical)."""
    np.testing.assert_array_equal(actual.timestamps_s, expected.timestamps_s)
    np.testing.assert_allclose(actual.positions_xyz, expected.positions_xyz, rtol=0, atol=1e-9)
    np.testing.assert_allclose(actual.orientations_quat_wxyz, expected.orientations_quat_wxyz, rtol=0, atol=1e-9)


@pytest.mark.parametrize("n", [1, 200])
def test_roundtrip_exact(tmp_path, n):
    traj = make_traj(n)
    path = write_tum(tmp_path / "traj.txt", traj)
    assert path == tmp_path / "traj.txt"
    assert_traj_equal(read_tum(path), traj)
    assert [p.name for p in tmp_path.iterdir()] == ["traj.txt"]


def test_disk_quaternion_order_is_xyzw(tmp_path):
    traj = Trajectory(np.array([1.5]), np.array([[1.0, 2.0, 3.0]]), np.array([[0.5, 0.5, -0.5, 0.5]]))
    path = write_tum(tmp_path / "t.txt", traj)
    rows = [line for line in path.read_text().splitlines() if not line.startswith("#")]
    assert rows == ["1.5 1.0 2.0 3.0 0.5 -0.5 0.5 0.5"]


def test_comments_and_blank_lines_are_skipped(tmp_path):
    path = tmp_path / "t.txt"
    path.write_text("# header\n\n1.0 0 0 0 0 0 0 1\n   \n  # indented comment\n2.0\t1 2 3 0 0 1 0\n")
    traj = read_tum(path)
    np.testing.assert_array_equal(traj.timestamps_s, [1.0, 2.0])
    np.testing.assert_array_equal(traj.positions_xyz, [[0, 0, 0], [1, 2, 3]])
    np.testing.assert_array_equal(traj.orientations_quat_wxyz, [[1, 0, 0, 0], [0, 0, 0, 1]])


def test_poses_se3_matches_analytic_rotation():
    half = np.sqrt(0.5)  # 90 degrees about +z, wxyz
    traj = Trajectory(np.array([0.0]), np.array([[1.0, 2.0, 3.0]]), np.array([[half, 0.0, 0.0, half]]))
    pose = traj.poses_se3()[0]
    np.testing.assert_allclose(pose[:3, :3] @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-15)
    np.testing.assert_array_equal(pose[:3, 3], [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(pose[3], [0.0, 0.0, 0.0, 1.0])


def test_from_poses_inverts_poses_se3():
    traj = make_traj(50)
    back = Trajectory.from_poses(traj.timestamps_s, traj.poses_se3())
    np.testing.assert_array_equal(back.timestamps_s, traj.timestamps_s)
    np.testing.assert_array_equal(back.positions_xyz, traj.positions_xyz)
    sign = np.sign(traj.orientations_quat_wxyz[:, :1])  # q and -q are the same rotation; w >= 0 on output
    np.testing.assert_allclose(back.orientations_quat_wxyz, sign * traj.orientations_quat_wxyz, atol=1e-12)
    assert (back.orientations_quat_wxyz[:, 0] >= 0).all()
    reference = Rotation.from_quat(traj.orientations_quat_wxyz[:, [1, 2, 3, 0]]).as_matrix()
    np.testing.assert_allclose(traj.poses_se3()[:, :3, :3], reference, atol=1e-12)


def test_empty_trajectory_poses():
    empty = Trajectory(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 4)))
    assert empty.poses_se3().shape == (0, 4, 4)
    assert len(Trajectory.from_poses(np.zeros(0), np.zeros((0, 4, 4)))) == 0


def test_trajectory_checks_shapes():
    with pytest.raises(ValueError, match="positions_xyz"):
        Trajectory(np.zeros(2), np.zeros((3, 3)), np.zeros((2, 4)))
    with pytest.raises(ValueError, match="orientations_quat_wxyz"):
        Trajectory(np.zeros(2), np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="timestamps_s"):
        Trajectory(np.float64(1.0), np.zeros((1, 3)), np.zeros((1, 4)))


GOOD = "1.0 0 0 0 0 0 0 1"


@pytest.mark.parametrize(
    "bad_line, match",
    [
        ("2.0 0 0 0 0 0 1", "expected 8 columns"),
        ("2.0 0 0 0 0 0 0 1 5", "expected 8 columns"),
        ("2.0 0 zero 0 0 0 0 1", "non-numeric"),
        ("2.0 0 nan 0 0 0 0 1", "non-finite"),
        ("2.0 0 0 0 0 0 0 inf", "non-finite"),
        ("2.0 0 0 0 0 0 0 1.01", "quaternion is not unit"),
        ("2.0 0 0 0 0 0 0 0", "quaternion is not unit"),
        ("0.5 0 0 0 0 0 0 1", "timestamp is before"),
    ],
)
def test_bad_line_is_input_error_naming_file_and_line(tmp_path, bad_line, match):
    path = tmp_path / "t.txt"
    path.write_text(f"# header\n{GOOD}\n\n{bad_line}\n3.0 0 0 0 0 0 0 1\n")
    with pytest.raises(InputError, match=f"t.txt:4: {match}"):
        read_tum(path)


def test_quaternion_within_tolerance_is_kept_as_read(tmp_path):
    path = tmp_path / "t.txt"
    path.write_text("1.0 0 0 0 0 0 0 1.0009\n")
    np.testing.assert_array_equal(read_tum(path).orientations_quat_wxyz, [[1.0009, 0, 0, 0]])


@pytest.mark.parametrize("content, match", [("", "no poses"), ("# only a comment\n\n", "no poses")])
def test_empty_file_is_input_error(tmp_path, content, match):
    path = tmp_path / "t.txt"
    path.write_text(content)
    with pytest.raises(InputError, match=f"t.txt: {match}"):
        read_tum(path)


def test_missing_file_is_input_error(tmp_path):
    with pytest.raises(InputError, match="nope.txt: no such file"):
        read_tum(tmp_path / "nope.txt")


def stamps(timestamps_s) -> Trajectory:
    n = len(timestamps_s)
    return Trajectory(
        np.asarray(timestamps_s, dtype=float), np.zeros((n, 3)), np.tile([1.0, 0, 0, 0], (n, 1))
    )


def test_associate_known_offsets():
    t_a = np.arange(10) * 0.1 + 100.0
    # b: every other pose of a, 4 ms late, plus one 30 ms early and one far off (never matched).
    t_b = np.sort(np.r_[t_a[::2] + 0.004, t_a[5] - 0.03, 200.0])
    idx_a, idx_b = associate(stamps(t_a), stamps(t_b), max_dt_s=0.02)
    np.testing.assert_array_equal(idx_a, [0, 2, 4, 6, 8])
    np.testing.assert_allclose(t_b[idx_b] - t_a[idx_a], 0.004, atol=1e-9)
    idx_a, idx_b = associate(stamps(t_a), stamps(t_b), max_dt_s=0.05)
    np.testing.assert_array_equal(idx_a, [0, 2, 4, 5, 6, 8])
    np.testing.assert_allclose(t_b[idx_b][3], t_a[5] - 0.03)
    assert idx_a.dtype == idx_b.dtype == np.int64


def test_associate_is_unique_and_nearest_first():
    idx_a, idx_b = associate(stamps([0.0, 0.9, 1.05]), stamps([1.0]), max_dt_s=0.2)
    np.testing.assert_array_equal(idx_a, [2])  # 1.05 is nearer to 1.0 than 0.9 is
    np.testing.assert_array_equal(idx_b, [0])


def test_associate_empty_and_no_matches():
    idx_a, idx_b = associate(stamps([0.0, 1.0]), stamps([5.0]), max_dt_s=0.1)
    assert idx_a.shape == idx_b.shape == (0,)
    idx_a, _ = associate(stamps([]), stamps([5.0]), max_dt_s=0.1)
    assert idx_a.shape == (0,)
    with pytest.raises(ValueError):
        associate(stamps([0.0]), stamps([0.0]), max_dt_s=-1.0)


def associate_reference(t_a, t_b, max_dt_s):
    """TUM associate.py, written out plainly: all pairs, nearest first, each stamp used once."""
    pairs = sorted(
        (abs(a - b), i, j) for i, a in enumerate(t_a) for j, b in enumerate(t_b) if abs(a - b) <= max_dt_s
    )
    used_a, used_b, matches = set(), set(), []
    for _, i, j in pairs:
        if i not in used_a and j not in used_b:
            used_a.add(i)
            used_b.add(j)
            matches.append((i, j))
    return sorted(matches)


@pytest.mark.parametrize("seed", range(5))
def test_associate_matches_reference(seed):
    rng = np.random.default_rng(seed)
    t_a = np.sort(rng.uniform(0, 10, 80))
    t_b = rng.uniform(0, 10, 60)  # unsorted on purpose: associate must not rely on order
    traj_b = Trajectory(t_b, np.zeros((60, 3)), np.tile([1.0, 0, 0, 0], (60, 1)))
    idx_a, idx_b = associate(stamps(t_a), traj_b, max_dt_s=0.07)
    assert list(zip(idx_a.tolist(), idx_b.tolist(), strict=True)) == associate_reference(t_a, t_b, 0.07)
    assert len(set(idx_b.tolist())) == len(idx_b)


def test_a_repeated_timestamp_keeps_the_first_pose_and_warns(tmp_path, caplog):
    """TUM's fr2/desk ground truth repeats one stamp: the file is read, the later pose dropped, with a warning."""
    path = tmp_path / "gt.txt"
    path.write_text("1.0 0 0 0 0 0 0 1\n2.0 1 0 0 0 0 0 1\n2.0 9 9 9 0 0 0 1\n3.0 2 0 0 0 0 0 1\n")
    with caplog.at_level("WARNING"):
        traj = read_tum(path)
    assert traj.timestamps_s.tolist() == [1.0, 2.0, 3.0]
    assert traj.positions_xyz[:, 0].tolist() == [0.0, 1.0, 2.0]
    assert "1 pose(s) repeat" in caplog.text and "line 3" in caplog.text


def test_positions_one_bit_apart_write_the_same_bytes(tmp_path):
    traj = make_traj(50)
    nudged = Trajectory(traj.timestamps_s, np.nextafter(traj.positions_xyz, -np.inf),
                        np.nextafter(traj.orientations_quat_wxyz, np.inf))
    a = write_tum(tmp_path / "a.txt", traj).read_bytes()
    b = write_tum(tmp_path / "b.txt", nudged).read_bytes()
    assert a == b
    zero = Trajectory(np.array([0.0]), np.array([[-1e-13, 0.0, -0.0]]), np.array([[1.0, -0.0, 0.0, -1e-12]]))
    assert write_tum(tmp_path / "z.txt", zero).read_text().splitlines()[-1] == "0.0 0.0 0.0 0.0 0.0 0.0 0.0 1.0"
