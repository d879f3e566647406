"""Neural fields: multiresolution hash encoding, MLPs, scene contraction, the scene and proposal fields."""

from nsim.fields.contraction import box_to_unit, contract, normalise_to_box, unit_to_world, world_to_unit
from nsim.fields.encodings import spherical_harmonics
from nsim.fields.hash_encoding import HashEncoding, grid_layout, hash_grid_encode
from nsim.fields.mlp import MLP
from nsim.fields.scene_field import ProposalField, ProposalFieldConfig, SceneField, SceneFieldConfig

__all__ = [
    "MLP",
    "HashEncoding",
    "ProposalField",
    "ProposalFieldConfig",
    "SceneField",
    "SceneFieldConfig",
    "box_to_unit",
    "contract",
    "grid_layout",
    "hash_grid_encode",
    "normalise_to_box",
    "spherical_harmonics",
    "unit_to_world",
    "world_to_unit",
]
