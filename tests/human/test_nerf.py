"""The human NeRF model: skinning weights, inverse LBS round trips, box sampling, merging with other samples."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from nsim.config import load_config
from nsim.human.gait import walk_cycle
from nsim.human.motion import LocomotionLoop
from nsim.human.nerf import (
    HumanModel,
    HumanModelConfig,
    bone_distances,
    bone_segments,
    empty_samples,
    load_human_model,
    merge_samples,
    point_segment_distance,
    ray_capsule_interval,
    render_merged,
    save_human_model,
)
from nsim.human.skeleton import forward_kinematics, nsim_skeleton
from nsim.volume.compositing import composite
from nsim.volume.samples import RaySamples


@pytest.fixture(autouse=True)
def _one_thread():
    torch.set_num_threads(1)


SMALL = HumanModelConfig(hash_levels=4, hash_log2_table_size=10, hash_max_resolution=64, hidden_dim=16,
                         color_hidden_dim=16, samples_per_ray=16)


@pytest.fixture(scope="module")
def skeleton():
    return nsim_skeleton(1.75)


@pytest.fixture(scope="module")
def walk_poses(skeleton):
    """Four walking poses (J, 4, 4) at different phases and places, facing different ways."""
    loop = LocomotionLoop.from_clip(walk_cycle(1.3, 1.75))
    root, quats = loop.pose_at(np.array([0.1, 0.35, 0.6, 0.85]), np.array([[0, 0], [1, 0.5], [-2, 1], [0.3, -1]]),
                               np.array([0.0, 0.7, -2.0, 3.0]))
    return forward_kinematics(skeleton, quats, root)


def model(cfg: HumanModelConfig = SMALL, skeleton=None, seed: int = 0) -> HumanModel:
    return HumanModel(cfg, skeleton if skeleton is not None else nsim_skeleton(1.75), torch.Generator().manual_seed(seed))


def near_bone_points(skeleton, n_per_bone: int = 40, jitter_m: float = 0.015, seed: int = 0) -> torch.Tensor:
    """Rest-pose points along the middle 60 % of every bone, jittered."""
    a, b, _ = bone_segments(skeleton)
    rng = np.random.default_rng(seed)
    u = rng.uniform(0.2, 0.8, (len(a), n_per_bone, 1))
    pts = a[:, None] + u * (b - a)[:, None] + rng.normal(0.0, jitter_m, (len(a), n_per_bone, 3))
    return torch.tensor(pts.reshape(-1, 3), dtype=torch.float32)


def opaque(m: HumanModel, log_sigma: float = 8.0) -> HumanModel:
    """Make the field's density ``exp(log_sigma - 1)`` everywhere in the canonical box (and colour 0.5)."""
    with torch.no_grad():
        for layer in (m.field.density_mlp.layers[-1], m.field.color_mlp.layers[-1]):
            layer.weight.zero_()
        m.field.density_mlp.layers[-1].bias.fill_(log_sigma)
        m.field.color_mlp.layers[-1].bias.zero_()
    return m


# ---------------------------------------------------------------------- skinning weights
def test_bone_distances_and_initial_weights(skeleton):
    j = skeleton.index
    rest = skeleton.rest_positions_m()
    mid_forearm = 0.5 * (rest[j("left_elbow")] + rest[j("left_wrist")])
    d = bone_distances(torch.tensor(mid_forearm[None]), skeleton)[0]
    assert float(d[j("left_elbow")]) == pytest.approx(0.0, abs=1e-9)
    assert int(torch.argmin(d)) == j("left_elbow")
    m = model(skeleton=skeleton)
    with torch.no_grad():
        w = m.canonical_weights(torch.tensor(mid_forearm[None], dtype=torch.float32))[0]
    assert int(torch.argmax(w)) == j("left_elbow") and float(w[j("left_elbow")]) > 0.9
    # far from the body no bone claims a point (the background channel of the initial softmax)
    far = torch.tensor([[0.0, 0.0, 0.98]]) + torch.tensor([[0.0, 0.0, 0.0]])
    far[0, 0] = float(m.canonical_box[1, 0]) - 1e-3
    with torch.no_grad():
        assert float(m.canonical_weights(far).sum()) < 1e-2


@pytest.mark.parametrize("mode", ["mixture", "blend"])
def test_rest_pose_warp_is_identity(skeleton, mode):
    m = model(HumanModelConfig(**{**SMALL.__dict__, "skinning": mode}), skeleton)
    x = near_bone_points(skeleton)
    with torch.no_grad():
        wp = m.warp(x, skeleton.rest_transforms())
    torch.testing.assert_close(wp.x_c[:, 0], x, atol=1e-5, rtol=0)


def test_lbs_round_trip_canonical_posed_canonical(skeleton, walk_poses):
    """Forward LBS to a walking pose and back: points near bones come back (best hypothesis)."""
    m = model(skeleton=skeleton)
    x = near_bone_points(skeleton)
    with torch.no_grad():
        for T in walk_poses:
            xp = m.canonical_to_posed(x, T)
            wp = m.warp(xp, T)
            best = torch.linalg.vector_norm(wp.x_c - x[:, None], dim=-1).amin(1)
            top = torch.linalg.vector_norm(wp.x_c[:, 0] - x, dim=-1)
            # exact along a bone, blended (so not rigidly invertible) within a few cm of a joint
            assert float(torch.quantile(best, 0.5)) < 0.002
            assert float(torch.quantile(best, 0.95)) < 0.015
            assert float(torch.quantile(top, 0.5)) < 0.005
            assert float(wp.weights[:, 0].median()) > 0.5


def test_inverse_skinning_is_exact_for_rigid_parts(skeleton, walk_poses):
    """A point on a bone moved rigidly by its joint maps back exactly to its rest position."""
    m = model(skeleton=skeleton)
    j = skeleton.index("right_knee")
    rest = skeleton.rest_transforms()
    p_rest = 0.5 * (rest[j, :3, 3] + rest[skeleton.index("right_ankle"), :3, 3])
    for T in walk_poses:
        G = T[j] @ np.linalg.inv(rest[j])
        p = G[:3, :3] @ p_rest + G[:3, 3]
        with torch.no_grad():
            wp = m.warp(torch.tensor(p[None], dtype=torch.float32), T)
        assert int(wp.joint[0, 0]) == j
        np.testing.assert_allclose(wp.x_c[0, 0].numpy(), p_rest, atol=1e-5)


# ---------------------------------------------------------------------- samples in the box
def test_differentiated_warp_matches_its_every_joint_twin(skeleton, walk_poses):
    """Where the warp is differentiated (poses refined, skinning weights learned), only the chosen hypotheses are
    formed again with their gradients: the same canonical points, weights and rotations, and the same gradients
    for the poses and the weight volume, as forming every joint's candidate with its gradient (the plain twin)."""
    m = model(skeleton=skeleton)
    T = torch.tensor(np.stack(walk_poses[:2]), dtype=torch.float32, requires_grad=True)
    x = torch.cat([m.canonical_to_posed(near_bone_points(skeleton, 6, 0.03, seed=p), T.detach()[p]) for p in (0, 1)]).detach()
    idx = torch.arange(2).repeat_interleave(len(x) // 2)
    g = torch.Generator().manual_seed(0)
    r = [torch.randn(s, generator=g) for s in ((len(x), 2, 3), (len(x), 2), (len(x), 2, 3, 3))]

    def twin():
        y, logw, rot_inv = m.candidates(x, T, idx)
        top, joint = torch.topk(logw, 2, dim=1)
        return torch.gather(y, 1, joint[..., None].expand(-1, -1, 3)), torch.exp(top), rot_inv[idx[:, None], joint]

    grads = []
    for f in (lambda: (lambda w: (w.x_c, w.weights, w.rot_pc))(m.warp(x, T, idx)), twin):
        out = f()
        loss = sum((o * rr).sum() for o, rr in zip(out, r, strict=True))
        grads.append(torch.autograd.grad(loss, [T, m.blend_log_weights]))
        grads[-1] = (*grads[-1], *[o.detach() for o in out])
    for a, b in zip(*grads, strict=True):
        torch.testing.assert_close(a, b, atol=2e-4, rtol=1e-4)
    assert float(grads[0][0].abs().max()) > 0 and float(grads[0][1].abs().max()) > 0


def test_render_samples_only_inside_the_posed_box(skeleton, walk_poses):
    m = model(skeleton=skeleton)
    T = walk_poses[1]
    box = m.posed_box(T)[0]
    centre = box.mean(0)
    origins = torch.tensor([[5.0, 4.0, 1.0], [5.0, 4.0, 1.0], [5.0, 4.0, 1.0]]) + torch.tensor([0.0, 0.0, 0.0])
    toward = centre - origins[0]
    dirs = torch.stack([toward, -toward, torch.tensor([0.0, 0.0, 1.0])])
    dirs = dirs / dirs.norm(dim=-1, keepdim=True)
    with torch.no_grad():
        s = m.render_samples(origins, dirs, T, near=0.0, far=100.0)
    assert s.t_starts.shape == (3, SMALL.samples_per_ray) and s.rgb.shape == (3, SMALL.samples_per_ray, 3)
    # the ray through the centre: samples span its entry and exit of the box, in order
    pts = origins[0] + dirs[0] * (0.5 * (s.t_starts[0] + s.t_ends[0]))[:, None]
    assert bool(((pts >= box[0] - 1e-4) & (pts <= box[1] + 1e-4)).all())
    assert bool((torch.diff(s.t_starts[0]) > 0).all()) and bool((s.t_ends[0] > s.t_starts[0]).all())
    # rays that miss the box (pointing away, or up past it): empty intervals, no density
    for r in (1, 2):
        assert bool((s.t_ends[r] == s.t_starts[r]).all()) and bool((s.sigma[r] == 0).all())


def test_render_samples_without_the_box_test_queries_every_ray_and_gives_the_same_samples(skeleton, walk_poses):
    m = opaque(model(skeleton=skeleton), 3.0)
    T = walk_poses[1]
    o, d = _rays_through_body(m, T, 6)
    o = torch.cat([o, o])
    d = torch.cat([d, -d])  # the second half points away: they miss the box
    calls = []
    real = m.query
    m.query = lambda x, *a, **k: (calls.append(len(x)), real(x, *a, **k))[1]
    with torch.no_grad():
        culled = m.render_samples(o, d, T, near=0.0, far=100.0)
        n_culled = sum(calls)
        calls.clear()
        every = m.render_samples(o, d, T, near=0.0, far=100.0, box_test=False)
    S = SMALL.samples_per_ray
    assert n_culled == 6 * S and sum(calls) == 12 * S  # the ray-box test skips the 6 rays that miss
    assert float(culled.sigma[:6].max()) > 0 and bool((culled.sigma[6:] == 0).all())
    for f in ("t_starts", "t_ends", "sigma", "rgb"):
        assert torch.equal(getattr(culled, f), getattr(every, f)), f


def test_ray_capsule_interval_matches_marching_along_the_ray():
    """Entry and exit of rays into capsules (zero-length ones: spheres) against the points of a fine march that
    lie within the radius; a ray that passes further off misses (``t0 > t1``)."""
    g = torch.Generator().manual_seed(0)
    R, B, radius = 60, 4, 0.3
    o = torch.randn(R, 3, generator=g) * 2.0
    a = torch.randn(R, B, 3, generator=g) * 0.5
    b = a + torch.randn(R, B, 3, generator=g) * 0.4
    b[:, 0] = a[:, 0]
    d = a[:, 1] + 0.4 * torch.randn(R, 3, generator=g) - o  # towards the segments: many hit, some miss
    d = d / d.norm(dim=-1, keepdim=True)
    t0, t1 = ray_capsule_interval(o, d, a, b, radius)
    ts = torch.linspace(-8.0, 8.0, 8001)
    hits = 0
    for r in range(R):
        pts = o[r] + d[r] * ts[:, None]
        for k in range(B):
            inside = point_segment_distance(pts, a[r, k:k + 1], b[r, k:k + 1])[:, 0] <= radius
            if inside.any():
                hits += 1
                assert abs(float(ts[inside].min() - t0[r, k])) < 3e-3 and abs(float(ts[inside].max() - t1[r, k])) < 3e-3
            else:
                assert float(t1[r, k] - t0[r, k]) < 3e-3
    assert hits > 20


def test_samples_near_the_bones_only(skeleton, walk_poses):
    """With ``sample_bone_radius_m`` every sample lies within that distance of a posed bone (and inside the box);
    the ray's samples are denser than over the whole box; a ray through the box that passes no bone that close
    is empty."""
    cfg = HumanModelConfig(**{**SMALL.__dict__, "sample_bone_radius_m": 0.15})
    near, whole = model(cfg, skeleton), model(skeleton=skeleton)
    T = walk_poses[1]
    o, d = _rays_through_body(near, T, 8)
    a, b = near.posed_bones(T)
    box = near.posed_box(T)[0]
    corner = box[1] - 0.005  # inside the box, more than the padding less 5 mm from every bone
    o = torch.cat([o, corner[None] + torch.tensor([[3.0, 0.0, 0.0]])])
    d = torch.cat([d, torch.tensor([[-1.0, 0.0, 0.0]])])
    with torch.no_grad():
        s = near.render_samples(o, d, T, near=0.0, far=100.0)
        w = whole.render_samples(o, d, T, near=0.0, far=100.0)
    mid = 0.5 * (s.t_starts + s.t_ends)
    pts = o[:8, None] + d[:8, None] * mid[:8, :, None]
    dist = point_segment_distance(pts.reshape(-1, 3), a[0], b[0]).amin(-1)
    assert float(dist.max()) <= 0.15 + 1e-4
    assert bool(((pts >= box[0] - 1e-4) & (pts <= box[1] + 1e-4)).all())
    assert bool(((s.t_ends - s.t_starts)[:8] < (w.t_ends - w.t_starts)[:8]).all())
    assert bool((s.t_ends[8] == s.t_starts[8]).all()) and bool((w.t_ends[8] > w.t_starts[8]).all())


def test_a_model_saved_before_the_bone_sampling_loads_as_it_was(skeleton, walk_poses, tmp_path):
    """``human.json`` of a model written before ``sample_bone_radius_m`` existed (no such key) loads with it off:
    the same samples as before."""
    import json

    m = model(skeleton=skeleton)
    save_human_model(tmp_path, m)
    meta = json.loads((tmp_path / "human.json").read_text())
    del meta["model"]["sample_bone_radius_m"]
    (tmp_path / "human.json").write_text(json.dumps(meta))
    back = load_human_model(tmp_path)
    assert back.cfg.sample_bone_radius_m is None
    o, d = _rays_through_body(m, walk_poses[0], 4)
    with torch.no_grad():
        torch.testing.assert_close(back.render_samples(o, d, walk_poses[0]).sigma, m.render_samples(o, d, walk_poses[0]).sigma)


def test_render_samples_respects_near_far(skeleton, walk_poses):
    m = model(skeleton=skeleton)
    T = walk_poses[0]
    centre = m.posed_box(T)[0].mean(0)
    o = centre[None] + torch.tensor([[3.0, 0.0, 0.0]])
    d = torch.tensor([[-1.0, 0.0, 0.0]])
    with torch.no_grad():
        s = m.render_samples(o, d, T, near=3.0, far=3.1)
        none = m.render_samples(o, d, T, near=0.0, far=1.0)  # ends before the box
    assert float(s.t_starts.min()) >= 3.0 - 1e-6 and float(s.t_ends.max()) <= 3.1 + 1e-6
    assert bool((none.t_ends == none.t_starts).all())


def test_several_poses_in_one_call_match_one_pose_at_a_time(skeleton, walk_poses):
    m = model(skeleton=skeleton)
    rng = np.random.default_rng(1)
    origins, dirs, index = [], [], []
    for p, T in enumerate(walk_poses):
        centre = T[0, :3, 3]
        o = centre + rng.normal(0, 0.2, (20, 3)) + np.array([3.0, 0.0, 0.0])
        d = centre + rng.normal(0, 0.2, (20, 3)) - o
        origins.append(o)
        dirs.append(d / np.linalg.norm(d, axis=1, keepdims=True))
        index.append(np.full(20, p))
    o = torch.tensor(np.concatenate(origins), dtype=torch.float32)
    d = torch.tensor(np.concatenate(dirs), dtype=torch.float32)
    idx = torch.tensor(np.concatenate(index))
    perm = torch.randperm(len(idx), generator=torch.Generator().manual_seed(0))  # interleave the poses
    with torch.no_grad():
        together = m.render_samples(o[perm], d[perm], walk_poses, pose_index=idx[perm])
        for p, T in enumerate(walk_poses):
            rows = torch.nonzero(idx[perm] == p)[:, 0]
            alone = m.render_samples(o[perm][rows], d[perm][rows], T)
            torch.testing.assert_close(together.sigma[rows], alone.sigma, atol=1e-5, rtol=1e-4)
            torch.testing.assert_close(together.rgb[rows], alone.rgb, atol=1e-5, rtol=1e-4)


# ---------------------------------------------------------------------- merging with the scene
def _rays_through_body(m: HumanModel, T: np.ndarray, n: int = 8) -> tuple[torch.Tensor, torch.Tensor]:
    """Rays from 3 m in front of the pelvis through the torso (they hit the body)."""
    pelvis = torch.tensor(T[0, :3, 3], dtype=torch.float32)
    targets = pelvis + torch.stack([torch.zeros(n), torch.linspace(-0.05, 0.05, n), torch.linspace(0.0, 0.3, n)], -1)
    origins = pelvis + torch.tensor([3.0, 0.0, 0.0])
    d = targets - origins
    return origins.expand(n, 3).contiguous(), d / d.norm(dim=-1, keepdim=True)


def wall(n: int, t_m: float, rgb=(1.0, 0.0, 0.0)) -> RaySamples:
    """An opaque wall at distance ``t_m`` along every ray: one thin, very dense interval."""
    t0 = torch.full((n, 1), t_m)
    return RaySamples(t0, t0 + 0.01, torch.full((n, 1), 1e4), torch.tensor(rgb).expand(n, 1, 3).clone())


def test_merge_with_empty_equals_rendering_alone(skeleton, walk_poses):
    m = opaque(model(skeleton=skeleton), 3.0)  # semi-transparent, so every sample matters
    o, d = _rays_through_body(m, walk_poses[0])
    bg = torch.tensor([0.2, 0.4, 0.6])
    with torch.no_grad():
        s = m.render_samples(o, d, walk_poses[0])
    alone = render_merged(s, background_rgb=bg)
    merged = render_merged(s, empty_samples(len(o)), background_rgb=bg)
    torch.testing.assert_close(merged.rgb, alone.rgb)
    torch.testing.assert_close(merged.alpha[0], alone.alpha[0])
    assert 0.05 < float(alone.accumulation.mean()) < 0.999
    # the plain twin: nsim.volume.compositing.composite of the merged samples gives the same colour
    both, _ = merge_samples(s, wall(len(o), 100.0))
    torch.testing.assert_close(render_merged(s, wall(len(o), 100.0), background_rgb=bg).rgb,
                               composite(both, bg).rgb, atol=1e-6, rtol=1e-5)


def test_human_in_front_of_a_wall_occludes_it(skeleton, walk_poses):
    m = opaque(model(skeleton=skeleton))
    o, d = _rays_through_body(m, walk_poses[0])
    with torch.no_grad():
        s = m.render_samples(o, d, walk_poses[0])
    behind = render_merged(s, wall(len(o), 6.0))
    assert float(behind.alpha[0].min()) > 0.99 and float(behind.alpha[1].max()) < 0.01
    torch.testing.assert_close(behind.rgb, torch.full_like(behind.rgb, 0.5), atol=0.01, rtol=0)
    in_front = render_merged(s, wall(len(o), 1.0))  # now the wall is between camera and person
    assert float(in_front.alpha[0].max()) < 0.01
    torch.testing.assert_close(in_front.rgb, torch.tensor([[1.0, 0.0, 0.0]]).expand_as(in_front.rgb), atol=1e-3, rtol=0)


def test_merge_sorts_by_t_and_reports_sources():
    a = RaySamples(torch.tensor([[1.0, 3.0]]), torch.tensor([[2.0, 4.0]]), torch.ones(1, 2), torch.zeros(1, 2, 3))
    b = RaySamples(torch.tensor([[0.5, 2.5]]), torch.tensor([[1.0, 3.0]]), torch.ones(1, 2), torch.ones(1, 2, 3))
    merged, source = merge_samples(a, b)
    assert merged.t_starts.tolist() == [[0.5, 1.0, 2.5, 3.0]]
    assert source.tolist() == [[1, 0, 1, 0]]
    assert merged.rgb[0, :, 0].tolist() == [1.0, 0.0, 1.0, 0.0]


# ---------------------------------------------------------------------- rendering, saving, configs
def test_render_image_and_save_load(skeleton, walk_poses, tmp_path):
    from nsim.human.nerf import orbit_cameras

    m = opaque(model(skeleton=skeleton))
    cam, poses = orbit_cameras(walk_poses[0], skeleton, 2, 24, 32)
    out = m.render(cam, poses[0], walk_poses[0], background_rgb=(0.0, 0.0, 1.0))
    assert out["rgb"].shape == (32, 24, 3) and out["alpha"].shape == (32, 24)
    assert out["alpha"].max() > 0.99 and out["alpha"][0, 0] < 0.01  # the person in the middle, not the corner
    np.testing.assert_allclose(out["rgb"][0, 0], [0.0, 0.0, 1.0], atol=1e-3)
    save_human_model(tmp_path, m, extra={"note": "test"})
    back = load_human_model(tmp_path)
    again = back.render(cam, poses[0], walk_poses[0], background_rgb=(0.0, 0.0, 1.0))
    np.testing.assert_array_equal(again["rgb"], out["rgb"])
    assert back.skeleton.joint_names == skeleton.joint_names
    np.testing.assert_array_equal(back.skeleton.end_sites_m, skeleton.end_sites_m)


def test_nonrigid_offsets_start_at_zero(skeleton, walk_poses):
    cfg = HumanModelConfig(**{**SMALL.__dict__, "nonrigid": True})
    rigid, nonrigid = model(skeleton=skeleton), model(cfg, skeleton)
    x = near_bone_points(skeleton, 5)
    with torch.no_grad():
        a = rigid.warp(rigid.canonical_to_posed(x, walk_poses[2]), walk_poses[2])
        b = nonrigid.warp(nonrigid.canonical_to_posed(x, walk_poses[2]), walk_poses[2])
    torch.testing.assert_close(a.x_c, b.x_c)
    assert nonrigid.pose_codes(walk_poses[2]).shape == (1, 6 * 23)
    assert float(nonrigid.pose_codes(skeleton.rest_transforms()).abs().max()) < 1e-6


def test_field_types_and_presets(skeleton):
    from nsim.train.human import TrainHumanConfig

    for preset in ("tiny", "default"):
        cfg = load_config(TrainHumanConfig, stage="train_human", preset=preset)
        assert cfg.model.samples_per_ray >= 16
    m = model(HumanModelConfig(**{**SMALL.__dict__, "field": "mlp", "pe_frequencies": 4}), skeleton)
    sigma, rgb = m.field(torch.zeros(5, 3) + m.canonical_box.mean(0))
    assert sigma.shape == (5,) and rgb.shape == (5, 3) and bool(((rgb > 0) & (rgb < 1)).all())
    outside = m.canonical_box[1] + 0.1
    with torch.no_grad():
        assert float(m.field(outside[None])[0][0]) == 0.0
