"""The micro train-scene preset (``nsim/configs/train_scene/micro.yaml``) builds what the tests built by hand.

Before the preset, ``tests/stages/micro.py`` and ``tests/train/test_scene.py`` each spelled out a
micro scene NeRF as a dict; both now start from the preset. These are those two dicts as they were,
so that the switch changed no test's config (nor any test artifact's id).
"""

from __future__ import annotations

from nsim.config import from_dict, load_config, preset_path
from nsim.train.scene_config import TrainSceneConfig
from tests.stages.micro import MICRO_SCENE, micro_scene
from tests.train.test_scene import MICRO, micro_cfg

STAGES_BEFORE = {
    "field": {"hash_levels": 4, "hash_log2_table_size": 10, "hash_max_resolution": 128, "hidden_dim": 16,
              "color_hidden_dim": 16, "color_hidden_layers": 1, "appearance_dim": 4, "sh_degree": 2, "backend": "torch"},
    "sampler": {"proposal_samples": [16, 8], "final_samples": 8, "proposal_hash_levels": 3,
                "proposal_hash_log2_table_size": 10, "proposal_hash_max_resolutions": [32, 64], "proposal_hidden_dim": 8},
    "optim": {"steps": 30, "rays_per_batch": 128, "num_threads": 1},
    "output": {"log_every": 10, "checkpoint_every": 100, "eval_views": 1, "final_eval_views": 1,
               "occupancy_cell_m": 0.3, "obstacle_cell_m": 0.25},
}


TRAIN_BEFORE = {
    "field": {"hash_levels": 4, "hash_log2_table_size": 10, "hash_max_resolution": 128, "hidden_dim": 16,
              "color_hidden_dim": 16, "color_hidden_layers": 1, "appearance_dim": 4, "sh_degree": 2, "backend": "torch"},
    "sampler": {"proposal_samples": [16, 8], "final_samples": 8, "proposal_hash_levels": 3,
                "proposal_hash_log2_table_size": 10, "proposal_hash_max_resolutions": [32, 64], "proposal_hidden_dim": 8},
    "optim": {"steps": 8, "rays_per_batch": 256, "num_threads": 1, "proposal_warmup_steps": 4, "proposal_update_every": 2},
    "output": {"log_every": 2, "checkpoint_every": 3, "eval_views": 1, "final_eval_views": 2,
               "occupancy_cell_m": 0.25, "obstacle_cell_m": 0.2},
}


def test_stage_tests_build_the_same_dict():
    assert MICRO_SCENE == STAGES_BEFORE
    assert micro_scene() == STAGES_BEFORE
    updated = micro_scene(optim={"steps": 40})
    assert updated["optim"] == {**STAGES_BEFORE["optim"], "steps": 40} and MICRO_SCENE["optim"]["steps"] == 30


def test_trainer_tests_build_the_same_dict():
    assert MICRO == TRAIN_BEFORE
    assert micro_cfg() == from_dict(TrainSceneConfig, TRAIN_BEFORE)
    assert micro_cfg(optim={"steps": 5}).optim.steps == 5 and MICRO["optim"]["steps"] == 8


def test_stage_tests_train_the_same_config(tmp_path):
    """The stage tests' ``--preset tiny --config micro.yaml`` resolves as ``--config`` of the old dict did."""
    import yaml

    old = tmp_path / "micro.yaml"
    old.write_text(yaml.safe_dump(STAGES_BEFORE))
    before = load_config(TrainSceneConfig, stage="train_scene", preset="tiny", config_file=old)
    now = load_config(TrainSceneConfig, stage="train_scene", preset="tiny",
                      config_file=preset_path("train_scene", "micro"))
    assert now == before
    # and the preset on its own is the trainer tests' base (the dataclass defaults under it)
    assert load_config(TrainSceneConfig, stage="train_scene", preset="micro") == from_dict(TrainSceneConfig, MICRO_SCENE)
