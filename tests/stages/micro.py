"""What the stage tests share: a 64x48 test-room capture and a micro scene NeRF that trains in seconds."""

from __future__ import annotations

CAPTURE = ["width=64", "height=48", "n_frames=24", "supersample=1", "video=false"]

MICRO_SCENE = {
    "field": {"hash_levels": 4, "hash_log2_table_size": 10, "hash_max_resolution": 128, "hidden_dim": 16,
              "color_hidden_dim": 16, "color_hidden_layers": 1, "appearance_dim": 4, "sh_degree": 2, "backend": "torch"},
    "sampler": {"proposal_samples": [16, 8], "final_samples": 8, "proposal_hash_levels": 3,
                "proposal_hash_log2_table_size": 10, "proposal_hash_max_resolutions": [32, 64], "proposal_hidden_dim": 8},
    "optim": {"steps": 30, "rays_per_batch": 128, "num_threads": 1},
    "output": {"log_every": 10, "checkpoint_every": 100, "eval_views": 1, "final_eval_views": 1,
               "occupancy_cell_m": 0.3, "obstacle_cell_m": 0.25},
}


def micro_scene(**sections) -> dict:
    """``MICRO_SCENE`` with some sections updated, e.g. ``micro_scene(optim={"steps": 40})``."""
    out = {k: dict(v) for k, v in MICRO_SCENE.items()}
    for k, v in sections.items():
        out.setdefault(k, {}).update(v)
    return out


def capture_and_micro_scene(root, ws) -> None:
    """Through the CLI: the micro capture tagged ``capture/t`` and a micro scene trained on it, ``scene/t``."""
    import yaml

    from nsim.cli import main

    args = ["--workspace", str(ws), "capture", "synth"]
    for kv in CAPTURE:
        args += ["--set", kv]
    assert main([*args, "--tag", "capture/t"]) == 0
    cfg_file = root / "micro.yaml"
    cfg_file.write_text(yaml.safe_dump(MICRO_SCENE))
    assert main(["--workspace", str(ws), "--device", "cpu", "train-scene", "--poses", "capture/t", "--preset", "tiny",
                 "--config", str(cfg_file), "--tag", "scene/t"]) == 0
