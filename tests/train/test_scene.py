"""Scene training: data and split, determinism, checkpoint resume (bit-identical), export, the tiny preset."""

from __future__ import annotations

import json
import logging
import shutil

import numpy as np
import pytest
import torch

from nsim.config import from_dict, load_config, read_preset
from nsim.errors import InputError
from nsim.train.scene import SceneData, SceneTrainer, scene_bounds, train_scene
from nsim.train.scene_config import TrainSceneConfig
from nsim.train.scene_eval import constant_color_psnr
from nsim.train.scene_export import export_scene

#: The micro preset (``nsim/configs/train_scene/micro.yaml``, as the stage tests use it) over the dataclass
#: defaults, with 8 steps, a checkpoint every 3 (the resume tests) and its own batch and grid sizes.
MICRO = {k: dict(v) for k, v in read_preset("train_scene", "micro").items()}
MICRO["optim"].update(steps=8, rays_per_batch=256, proposal_warmup_steps=4, proposal_update_every=2)
MICRO["output"].update(log_every=2, checkpoint_every=3, final_eval_views=2, occupancy_cell_m=0.25, obstacle_cell_m=0.2)


def micro_cfg(**sections) -> TrainSceneConfig:
    data = {k: dict(v) for k, v in MICRO.items()}
    for k, v in sections.items():
        data.setdefault(k, {}).update(v)
    return from_dict(TrainSceneConfig, data)


def test_data_and_split(tiny_data):
    assert tiny_data.images.shape == (32, 48, 64, 3) and tiny_data.images.dtype == np.uint8
    train, held = tiny_data.split(8)
    assert held.tolist() == [0, 8, 16, 24] and len(train) == 28 and not set(train) & set(held)
    assert tiny_data.read_depth_z(3).shape == (48, 64)
    box = scene_bounds(tiny_data, micro_cfg().data)
    centres = tiny_data.cam_to_world[:, :3, 3]
    assert (box[0] < centres.min(0)).all() and (box[1] > centres.max(0)).all()


def test_adam_beta2_reaches_the_optimiser(tiny_data):
    default = SceneTrainer(tiny_data, micro_cfg(), seed=0).optimizer
    ngp = SceneTrainer(tiny_data, micro_cfg(optim={"adam_beta2": 0.99}), seed=0).optimizer
    assert all(g["betas"] == (0.9, 0.999) for g in default.param_groups)
    assert all(g["betas"] == (0.9, 0.99) for g in ngp.param_groups)
    with pytest.raises(Exception, match="adam_beta2"):
        micro_cfg(optim={"adam_beta2": 1.0})


def test_missing_transforms_is_input_error(tmp_path):
    with pytest.raises(InputError, match="transforms.json"):
        SceneData.load(tmp_path)


def test_batch_is_a_pure_function_of_seed_and_step(tiny_data):
    a = SceneTrainer(tiny_data, micro_cfg(), seed=3)
    b = SceneTrainer(tiny_data, micro_cfg(), seed=3)
    ra, ta, _ = a.batch(17)
    rb, tb, _ = b.batch(17)
    assert torch.equal(ra.origins, rb.origins) and torch.equal(ra.dirs, rb.dirs) and torch.equal(ta, tb)
    rc, _, _ = a.batch(18)
    assert not torch.equal(ra.dirs, rc.dirs)
    assert ra.image_index is not None and set(ra.image_index.tolist()) <= set(a.train_ids.tolist())


def test_appearance_mean_share_drops_that_share_of_rays_to_the_mean_code(tiny_data):
    plain = SceneTrainer(tiny_data, micro_cfg(optim={"rays_per_batch": 4096}), seed=3)
    dropout = SceneTrainer(tiny_data, micro_cfg(optim={"appearance_mean_share": 0.25, "rays_per_batch": 4096}), seed=3)
    rp, tp, _ = plain.batch(5)
    rd, td, _ = dropout.batch(5)
    # the same pixels and rays; only the appearance index of about a quarter of them is -1 (the mean code)
    assert torch.equal(rp.dirs, rd.dirs) and torch.equal(tp, td) and len(rd.image_index) == 4096
    dropped = rd.image_index < 0
    assert 0.22 < dropped.float().mean().item() < 0.28
    assert (rd.image_index[dropped] == -1).all()
    again, _, _ = SceneTrainer(tiny_data, micro_cfg(optim={"appearance_mean_share": 0.25, "rays_per_batch": 4096}),
                               seed=3).batch(5)
    assert torch.equal(again.image_index, rd.image_index)  # seeded by (seed, step)
    assert not (plain.batch(6)[0].image_index < 0).any()
    # the dropped rays draw with the training images' mean code, and its gradient reaches every training code
    model = dropout.model
    codes = model.field.appearance_codes(rd.image_index, len(rd.image_index), "mean", model.train_mask)
    mean = model.field.appearance.weight[model.train_mask].mean(0)
    torch.testing.assert_close(codes[dropped], mean.expand(int(dropped.sum()), -1))
    kept = ~dropped
    torch.testing.assert_close(codes[kept], model.field.appearance.weight[rd.image_index[kept]])
    codes[dropped].sum().backward()
    grad = model.field.appearance.weight.grad
    assert (grad[model.train_mask].abs().sum(-1) > 0).all() and (grad[~model.train_mask] == 0).all()
    with pytest.raises(Exception, match="appearance_mean_share"):
        micro_cfg(optim={"appearance_mean_share": 1.0})


def _state(trainer):
    return {k: v.clone() for k, v in trainer.model.state_dict().items()}


def test_resume_is_bit_identical(tiny_data, tmp_path):
    cfg = micro_cfg()
    whole = train_scene(tiny_data, cfg, tmp_path / "whole", seed=5).trainer
    # "killed" after step 5: the checkpoint of step 3 is the last one on disk; resuming redoes steps 4, 5
    part = train_scene(tiny_data, cfg, tmp_path / "part", seed=5, stop_after=5).trainer
    assert part.step == 5
    resumed = train_scene(tiny_data, cfg, tmp_path / "part", seed=5)
    assert resumed.resumed_from == 3 and resumed.trainer.step == cfg.optim.steps
    for (k, va), (_, vb) in zip(_state(whole).items(), _state(resumed.trainer).items(), strict=True):
        assert torch.equal(va, vb), k
    sa, sb = whole.optimizer.state_dict()["state"], resumed.trainer.optimizer.state_dict()["state"]
    for key in sa:
        assert torch.equal(sa[key]["exp_avg"], sb[key]["exp_avg"]) and torch.equal(sa[key]["exp_avg_sq"], sb[key]["exp_avg_sq"])
    assert [h["loss"] for h in whole.history] == [h["loss"] for h in resumed.trainer.history]


def test_resume_from_an_older_checkpoint_in_process(tiny_data, tmp_path):
    """Train N steps, save, rebuild a fresh trainer from the checkpoint, continue: same as uninterrupted."""
    cfg = micro_cfg()
    ref = SceneTrainer(tiny_data, cfg, seed=1)
    for _ in range(5):
        ref.train_step()
    a = SceneTrainer(tiny_data, cfg, seed=1)
    for _ in range(2):
        a.train_step()
    a.save_checkpoint(tmp_path / "c.pt")
    del a
    b = SceneTrainer(tiny_data, cfg, seed=1)
    b.load_checkpoint(tmp_path / "c.pt")
    for _ in range(3):
        b.train_step()
    for (k, va), (_, vb) in zip(_state(ref).items(), _state(b).items(), strict=True):
        assert torch.equal(va, vb), k


def test_training_leaves_the_thread_count_as_it_found_it(tiny_data, tmp_path):
    """The loop holds num_threads x batch_threads torch threads (the parts' worker threads keep num_threads
    each), set once; building a trainer, the steps and the export leave the count as they found it."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    seen = []
    try:
        cfg = micro_cfg(optim={"steps": 2, "batch_threads": 2}, output={"log_every": 1, "final_eval_views": 1},
                        eval={"fit_steps": 5})
        assert SceneTrainer(tiny_data, micro_cfg(optim={"num_threads": 3}), seed=0).loop_threads() == 3
        assert torch.get_num_threads() == 1  # building a trainer sets nothing
        result = train_scene(tiny_data, cfg, tmp_path / "work", seed=0,
                             on_log=lambda tr, stats: seen.append(torch.get_num_threads()))
        assert result.trainer.loop_threads() == 2 and seen == [2, 2]  # 1 thread x 2 parts, every step
        assert torch.get_num_threads() == 1
        export_scene(tmp_path / "out", result)
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)


def test_checkpoint_of_another_run_is_not_resumed(tiny_data, tmp_path):
    train_scene(tiny_data, micro_cfg(optim={"steps": 3}), tmp_path, seed=0)
    other = train_scene(tiny_data, micro_cfg(optim={"steps": 3}), tmp_path, seed=1)
    assert other.resumed_from is None
    with pytest.raises(InputError):
        SceneTrainer(tiny_data, micro_cfg(optim={"steps": 3}), seed=2).load_checkpoint(tmp_path / "last.pt")


@pytest.mark.parametrize("kind", ["torch_save_exec", "pickle_exec", "truncated"])
def test_planted_resume_checkpoint_runs_no_code(tiny_data, tmp_path, plant_checkpoint, caplog, kind):
    """A code-running pickle (or a broken file) at work_dir/last.pt is refused with a warning, and the
    run trains from scratch and replaces it with a real checkpoint."""
    cfg = micro_cfg(optim={"steps": 3})
    marker = tmp_path / "pwned"
    ckpt = plant_checkpoint(tmp_path / "work" / "last.pt", kind, marker)
    with caplog.at_level(logging.WARNING):
        result = train_scene(tiny_data, cfg, tmp_path / "work", seed=0)
    assert not marker.exists()
    assert any(r.levelno == logging.WARNING and str(ckpt) in r.getMessage() for r in caplog.records)
    assert result.resumed_from is None and result.trainer.step == 3
    SceneTrainer(tiny_data, cfg, seed=0).load_checkpoint(ckpt)  # replaced by this run's own checkpoint


def test_pose_refinement_and_depth_supervision_train(tiny_data, tiny_capture_dir, tmp_path):
    # sparse points from the ground-truth depth of a few frames stand in for SfM points
    from nsim.io.ply import write_ply

    pts = []
    for i in (1, 5, 9):
        depth = tiny_data.read_depth_z(i)
        cam = tiny_data.cameras[tiny_data.camera_index[i]]
        dirs = cam.pixel_dirs_cam()
        p_cam = dirs / dirs[..., 2:3] * depth[..., None]
        c2w = tiny_data.cam_to_world[i]
        pts.append((p_cam.reshape(-1, 3) @ c2w[:3, :3].T + c2w[:3, 3])[::37])
    root = tmp_path / "capture"
    shutil.copytree(tiny_capture_dir, root)
    write_ply(root / "sparse_points.ply", np.concatenate(pts))
    data = SceneData.load(root)
    assert data.points_xyz is not None and data.digest != SceneData.load(tiny_capture_dir).digest
    cfg = micro_cfg(optim={"steps": 4, "pose_refinement": True}, loss={"depth_weight": 0.1, "depth_rays_per_batch": 32})
    tr = SceneTrainer(data, cfg)
    stats = [tr.train_step() for _ in range(4)]
    assert all(np.isfinite(s.loss) for s in stats) and "depth" in stats[-1].extra
    assert tr.pose_refine.twists.abs().sum() > 0  # the poses moved
    assert scene_bounds(data, cfg.data).shape == (2, 3)


def test_export_and_reload(tiny_data, tmp_path):
    from nsim.rendering.model import load_model
    from nsim.rendering.occupancy import OccupancyGrid
    from nsim.rendering.renderer import render_camera, render_lidar
    from nsim.sensors.lidar import LidarConfig

    cfg = micro_cfg(optim={"steps": 4})
    result = train_scene(tiny_data, cfg, tmp_path / "work", seed=0)
    out = tmp_path / "out"
    summary = export_scene(out, result)
    for name in ("model.pt", "scene.json", "bounds.json", "occupancy_grid.npy", "occupancy_grid.json", "obstacles.png", "obstacles.json",
                 "curves.png", "history.json", "eval.json", "eval/frame_00000.png"):
        assert (out / name).is_file(), name
    assert summary["steps"] == 4 and "eval_psnr" in summary
    ev = json.loads((out / "eval.json").read_text())
    assert len(ev["views"]) == 2 and "abs_rel_median" in ev["views"][0]
    model = load_model(out)
    for (k, va), (_, vb) in zip(result.model.state_dict().items(), model.state_dict().items(), strict=True):
        assert torch.equal(va.cpu(), vb), k
    grid = OccupancyGrid.load(out / "occupancy_grid.npy")
    cam = tiny_data.cameras[0]
    view = render_camera(model, cam, tiny_data.cam_to_world[3], method="march", grid=grid, return_samples=True)
    assert view.rgb.shape == (48, 64, 3) and view.depth_z.shape == (48, 64) and view.samples is not None
    prop = render_camera(model, cam, tiny_data.cam_to_world[3], method="proposal")
    assert np.isfinite(prop.rgb).all()
    lidar = LidarConfig(channels=4, azimuth_samples=32, vertical_fov_deg=(-10.0, 10.0))
    pose = np.eye(4)
    pose[:3, 3] = tiny_data.cam_to_world[3, :3, 3]
    ranges = render_lidar(model, pose, lidar, grid=grid)
    assert ranges.shape == (4, 32) and ranges.dtype == np.float32


@pytest.mark.slow
def test_tiny_preset_beats_constant_color(tiny_data, tmp_path):
    cfg = load_config(TrainSceneConfig, stage="train_scene", preset="tiny")
    result = train_scene(tiny_data, cfg, tmp_path, seed=0)
    ev = result.trainer.evaluate()
    baseline = constant_color_psnr(tiny_data, cfg.data.holdout_every)
    assert ev["mean"]["psnr"] >= baseline + 5.0, (ev["mean"], baseline)


@pytest.mark.slow
def test_kill_9_then_resume_is_bit_identical(tiny_capture_dir, tiny_data, tmp_path):
    """A training process killed with SIGKILL resumes from its last checkpoint to the same weights."""
    import os
    import signal
    import subprocess
    import sys
    import time

    steps = 30
    cfg = micro_cfg(optim={"steps": steps}, output={"checkpoint_every": 2, "log_every": 2})
    cfg_json = json.dumps({k: dict(v) for k, v in MICRO.items()} | {
        "optim": {**MICRO["optim"], "steps": steps}, "output": {**MICRO["output"], "checkpoint_every": 2, "log_every": 2}})
    script = (
        "import json, sys\n"
        "from nsim.config import from_dict\n"
        "from nsim.train.scene import SceneData, train_scene\n"
        "from nsim.train.scene_config import TrainSceneConfig\n"
        f"cfg = from_dict(TrainSceneConfig, json.loads({cfg_json!r}))\n"
        f"train_scene(SceneData.load({str(tiny_capture_dir)!r}), cfg, {str(tmp_path / 'work')!r}, seed=9)\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", script], cwd=str(tmp_path), env={**os.environ, "PYTHONPATH": os.getcwd()})
    ckpt = tmp_path / "work" / "last.pt"
    deadline = time.time() + 1800  # a guard against a hang only: the loop breaks at step 6
    while time.time() < deadline and proc.poll() is None:
        if ckpt.is_file() and torch.load(ckpt, weights_only=False)["step"] >= 6:
            break
        time.sleep(0.05)
    killed_at = torch.load(ckpt, weights_only=False)["step"] if ckpt.is_file() else None
    if proc.poll() is None:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        assert proc.returncode == -signal.SIGKILL
    assert killed_at is not None and killed_at < steps, "the process finished before it could be killed"
    resumed = train_scene(tiny_data, cfg, tmp_path / "work", seed=9)
    assert resumed.resumed_from is not None and resumed.resumed_from >= 6
    whole = train_scene(tiny_data, cfg, tmp_path / "whole", seed=9)
    for (k, va), (_, vb) in zip(_state(whole.trainer).items(), _state(resumed.trainer).items(), strict=True):
        assert torch.equal(va, vb), k


def test_export_repeats_byte_for_byte(tiny_data, tmp_path):
    """Same data, config and seed on CPU: the same files (so the stage's artifact id repeats)."""
    import hashlib

    cfg = micro_cfg(optim={"steps": 3}, output={"final_eval_views": 1})
    digests = []
    for run in ("a", "b"):
        result = train_scene(tiny_data, cfg, tmp_path / f"work_{run}", seed=2)
        export_scene(tmp_path / run, result)
        files = sorted(p for p in (tmp_path / run).rglob("*") if p.is_file())
        digests.append({p.relative_to(tmp_path / run).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest() for p in files})
    assert digests[0] == digests[1]


def test_grid_model_trains_resumes_and_reloads(tiny_data, tmp_path):
    from nsim.rendering.model import load_model
    from nsim.train.scene import train_scene
    from nsim.train.scene_export import export_scene

    cfg = micro_cfg(sampler={"kind": "grid", "grid_cell_m": 0.25, "grid_update_every": 2, "grid_warmup_steps": 4},
                    loss={"distortion_weight": 0.01})
    whole = train_scene(tiny_data, cfg, tmp_path / "whole", seed=2)
    assert len(whole.model.proposals) == 0 and whole.model.grid_occupied.float().mean() < 1.0
    assert all("distortion" in h for h in whole.trainer.history)
    train_scene(tiny_data, cfg, tmp_path / "part", seed=2, stop_after=5)
    resumed = train_scene(tiny_data, cfg, tmp_path / "part", seed=2)
    assert resumed.resumed_from == 3
    for (k, va), (_, vb) in zip(whole.model.state_dict().items(), resumed.model.state_dict().items(), strict=True):
        assert torch.equal(va, vb), k
    export_scene(tmp_path / "out", whole)
    back = load_model(tmp_path / "out")
    assert back.sampler_cfg.kind == "grid" and torch.equal(back.grid_occupied, whole.model.grid_occupied.cpu())



def test_random_background_composites_transparent_rays_over_noise(tiny_data):
    """With an empty field (density ~ 0, accumulation ~ 0) a ray's training colour is the
    background: black without the option (``background: constant``, loss = mean(target^2)), a
    uniform random colour with it (expected loss = 1/12 + mean((target - 1/2)^2)), also over a
    ``last_sample`` background; reruns are identical."""
    empty = {"density_bias": -20.0}
    losses = {"interlevel_weight": 0.0, "distortion_weight": 0.0}
    optim = {"rays_per_batch": 4096}
    black_bg = {"background": "constant"}
    plain = SceneTrainer(tiny_data, micro_cfg(field=empty, loss=losses, optim=optim, sampler=black_bg), seed=0)
    noisy = SceneTrainer(tiny_data, micro_cfg(field=empty, loss={**losses, "random_background": True}, optim=optim,
                                              sampler=black_bg), seed=0)
    last = SceneTrainer(tiny_data, micro_cfg(field=empty, loss={**losses, "random_background": True}, optim=optim,
                                             sampler={"background": "last_sample"}), seed=0)
    assert last.train_step().loss == pytest.approx(noisy.train_step().loss, rel=1e-4)
    noisy = SceneTrainer(tiny_data, micro_cfg(field=empty, loss={**losses, "random_background": True}, optim=optim,
                                              sampler=black_bg), seed=0)
    _, target, _ = plain.batch(0)
    target = target.double()
    black = float(torch.mean(target**2))
    expected = 1.0 / 12.0 + float(torch.mean((target - 0.5) ** 2))
    assert plain.train_step().loss == pytest.approx(black, rel=1e-4)
    got = noisy.train_step().loss
    assert got == pytest.approx(expected, rel=0.05) and abs(got - black) > 0.02
    again = SceneTrainer(tiny_data, micro_cfg(field=empty, loss={**losses, "random_background": True}, optim=optim), seed=0)
    assert again.train_step().loss == got


def test_checkpoint_keeps_the_training_images_mean_colour(tiny_data, tmp_path):
    """``image_mean_rgb`` in scene.json (``nsim render``'s fill): the mean colour of the training
    images only (held-out frames excluded); checkpoints without it load with None."""
    from nsim.rendering.model import load_model
    from nsim.train.scene import train_scene
    from nsim.train.scene_export import export_scene

    cfg = micro_cfg(optim={"steps": 2})
    result = train_scene(tiny_data, cfg, tmp_path / "run", seed=0)
    train_ids, held = tiny_data.split(cfg.data.holdout_every)
    assert len(held) > 0
    want = tiny_data.images[np.asarray(train_ids)].reshape(-1, 3).astype(np.float64).mean(0) / 255.0
    assert not np.allclose(want, tiny_data.images.reshape(-1, 3).mean(0) / 255.0, atol=1e-7)  # the split matters
    export_scene(tmp_path / "out", result)
    assert np.allclose(load_model(tmp_path / "out").image_mean_rgb, want, atol=1e-12)
    meta = json.loads((tmp_path / "out" / "scene.json").read_text())
    del meta["image_mean_rgb"]
    (tmp_path / "out" / "scene.json").write_text(json.dumps(meta))
    assert load_model(tmp_path / "out").image_mean_rgb is None


def _binary_entropy(acc):
    a = acc.clamp(1e-4, 1 - 1e-4)
    return -(a * torch.log(a) + (1 - a) * torch.log1p(-a)).mean()


def test_opacity_term_is_the_binary_entropy_of_accumulation(tiny_data):
    """loss.opacity_weight adds w * mean(-a log a - (1 - a) log(1 - a)) over the rays' accumulation a,
    from opacity_start of the steps on; its gradient pushes a half-transparent ray's accumulation
    towards 0 or 1, whichever is nearer."""
    w = 0.5
    base = {"interlevel_weight": 0.0, "distortion_weight": 0.0}
    plain = SceneTrainer(tiny_data, micro_cfg(loss=base), seed=0)
    opaque = SceneTrainer(tiny_data, micro_cfg(loss={**base, "opacity_weight": w, "opacity_start": 0.5}), seed=0)
    rays, target, _ = plain.batch(0)
    last = plain.cfg.optim.steps - 1
    with torch.no_grad():
        l0, _ = plain._part_loss(last, rays, target, None, 1.0, False, False, True, 1.0, {})
        early_extra, late_extra = {}, {}
        early, _ = opaque._part_loss(0, rays, target, None, 1.0, False, False, True, 1.0, early_extra)
        late, _ = opaque._part_loss(last, rays, target, None, 1.0, False, False, True, 1.0, late_extra)
        before = plain.model.render(rays, generator=None, anneal=1.0).accumulation.double()
    assert float(early) == float(l0) and "opacity" not in early_extra  # before opacity_start: no term
    entropy = float(_binary_entropy(before))
    assert entropy > 0.05  # the untrained micro scene is half-transparent: the term is not vacuous
    assert float(late) - float(l0) == pytest.approx(w * entropy, rel=1e-3)
    assert late_extra["opacity"] == pytest.approx(entropy, rel=1e-3)
    # a small step down the term's gradient alone: rays above 1/2 gain accumulation, rays below
    # lose it (a denser and a thinner initial field, so that both kinds of ray occur)
    checked = set()
    for bias in (-1.0, -6.0, -9.0):
        tr = SceneTrainer(tiny_data, micro_cfg(field={"density_bias": bias}, loss={**base, "opacity_weight": w}), seed=0)
        params = [q for grp in tr.optimizer.param_groups for q in grp["params"]]
        acc = tr.model.render(rays, generator=None, anneal=1.0).accumulation
        grads = torch.autograd.grad(_binary_entropy(acc), params, allow_unused=True)
        with torch.no_grad():
            for q, g in zip(params, grads, strict=True):
                if g is not None:
                    q -= 1e-2 * g / (g.abs().max() + 1e-12)
            after = tr.model.render(rays, generator=None, anneal=1.0).accumulation.double()
        acc = acc.detach().double()
        assert float(_binary_entropy(after)) < float(_binary_entropy(acc))
        for side, sel, sign in (("hi", acc > 0.6, 1.0), ("lo", acc < 0.4, -1.0)):
            if sel.sum() >= 10:
                assert sign * float((after[sel] - acc[sel]).mean()) > 0, (bias, side)
                checked.add(side)
    assert checked == {"hi", "lo"}


def test_split_batch_gradient_is_the_whole_batch_gradient(tiny_data):
    """optim.batch_threads: the parts' losses are scaled by their share, so their gradients sum to the whole batch's."""
    tr = SceneTrainer(tiny_data, micro_cfg(loss={"distortion_weight": 0.01}), seed=0)
    rays, target, _ = tr.batch(0)
    params = [q for grp in tr.optimizer.param_groups for q in grp["params"]]

    def grads(sl, share):  # no jitter (generator None): the same samples however the batch is cut
        loss, _ = tr._part_loss(0, rays[sl], target[sl], None, 1.0, True, False, True, share, {})
        return torch.autograd.grad(loss, params, allow_unused=True)

    whole = grads(slice(0, 256), 1.0)
    halves = [grads(slice(0, 100), 100 / 256), grads(slice(100, 256), 156 / 256)]
    checked = 0
    for g_all, g_a, g_b in zip(whole, *halves, strict=True):
        if g_all is None:
            continue
        torch.testing.assert_close(g_a + g_b, g_all, rtol=1e-4, atol=1e-7)
        checked += 1
    assert checked == len(params)  # field and proposal fields alike (proposals train at step 0)


def test_split_batch_threads_are_deterministic(tiny_data):
    cfg = micro_cfg(optim={"steps": 6, "batch_threads": 2, "pose_refinement": True})
    states = []
    for _ in range(2):
        tr = SceneTrainer(tiny_data, cfg, seed=3)
        stats = [tr.train_step() for _ in range(5)]
        assert tr._parts_warm and all(np.isfinite(s.loss) for s in stats)
        states.append({k: v.clone() for k, v in tr.model.state_dict().items()})
        assert tr.pose_refine.twists.abs().sum() > 0
    assert all(torch.equal(states[0][k], states[1][k]) for k in states[0])
    ref = SceneTrainer(tiny_data, micro_cfg(optim={"steps": 6, "pose_refinement": True}), seed=3)
    for _ in range(5):
        ref.train_step()
    # the same run on one thread differs only by the parts' jitter draws: learning happened in both
    assert not all(torch.equal(states[0][k], v) for k, v in ref.model.state_dict().items())
