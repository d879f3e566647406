"""``render_rays`` keeps only per-ray outputs: the same values as the chunks, memory of tens of bytes a ray."""

from __future__ import annotations

import gc
import weakref
from pathlib import Path

import pytest
import torch
from torch import nn

from nsim.config import from_dict
from nsim.fields.scene_field import SceneFieldConfig
from nsim.rendering.model import SamplerConfig, SceneModel
from nsim.rendering.occupancy import OccupancyGrid
from nsim.rendering.renderer import PER_RAY_FIELDS, MarchConfig, march, render_rays
from nsim.volume.rays import Rays, make_rays
from nsim.volume.samples import RenderOutput
from tests.rendering.reference import BoxField, ToyModel

AABB = torch.tensor([[0.0, 0.0, 0.0], [4.0, 3.0, 2.0]])
FIELD = SceneFieldConfig(hash_levels=4, hash_log2_table_size=10, hash_max_resolution=64, hidden_dim=16, color_hidden_dim=16,
                         color_hidden_layers=1, appearance_dim=4, sh_degree=2, backend="torch", contract=False)


def _model(**sampler) -> SceneModel:
    base = {"proposal_samples": [16], "proposal_hash_max_resolutions": [64], "final_samples": 8, "proposal_hash_levels": 2, "grid_cell_m": 0.25,
            "grid_step_m": 0.05, "grid_samples_per_ray": 10_000, "grid_stop_transmittance": 0.0}
    cfg = from_dict(SamplerConfig, {**base, **sampler})
    model = SceneModel(FIELD, cfg, AABB, 4, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():  # a density with structure: raise the output bias so rays terminate
        model.field.density_mlp.layers[-1].bias[0] += 3.0
    return model.eval()


def _rays(n: int, seed: int = 0) -> Rays:
    g = torch.Generator().manual_seed(seed)
    origins = torch.tensor([0.5, 1.5, 1.0]) + (torch.rand(n, 3, generator=g) - 0.5) * 0.4
    dirs = torch.nn.functional.normalize(torch.randn(n, 3, generator=g) + torch.tensor([2.0, 0.0, 0.0]), dim=-1)
    return make_rays(origins, dirs, 0.1, 30.0, AABB)


def _chunks_concatenated(render, rays: Rays, chunk: int) -> dict[str, torch.Tensor]:
    """The old path: every chunk's whole output, then the per-ray fields concatenated."""
    outs = [render(rays[a : a + chunk]) for a in range(0, len(rays), chunk)]
    return {f: torch.cat([getattr(o, f).expand(len(o.rgb), -1) if f == "background" else getattr(o, f) for o in outs])
            for f in PER_RAY_FIELDS}


@pytest.mark.parametrize("kind", ["proposal", "grid", "march", "march_last_sample"])
def test_matches_reference(kind):
    """Bit for bit the per-ray outputs of the chunks rendered one by one and concatenated."""
    rays = _rays(203)
    chunk = 37  # 6 chunks, the last one short
    if kind.startswith("march"):
        box = BoxField(lo=[2.5, 1.0, 0.0], hi=[3.0, 2.5, 1.2], sigma_in=80.0)
        model = ToyModel(box, AABB.tolist(), background="last_sample" if kind == "march_last_sample" else "constant")
        grid = OccupancyGrid.bake(lambda x: model.field.density(x)[0], AABB, 0.1, 1.0)
        cfg = MarchConfig(step_m=0.02)
        out = render_rays(model, rays, "march", grid, cfg, chunk=chunk)
        ref = _chunks_concatenated(lambda r: march(model, r, grid, cfg), rays, chunk)
    else:
        model = _model(kind=kind)
        out = render_rays(model, rays, "proposal", chunk=chunk)
        ref = _chunks_concatenated(lambda r: model.render(r), rays, chunk)
    for f in PER_RAY_FIELDS:
        assert torch.equal(getattr(out, f), ref[f]), f
    assert out.weights is None and out.samples is None and out.bins is None


def test_one_chunk_equals_many():
    model = _model(kind="proposal")
    rays = _rays(300, seed=1)
    whole = render_rays(model, rays, chunk=1000)
    parts = render_rays(model, rays, chunk=7)
    for f in PER_RAY_FIELDS:
        assert torch.equal(getattr(parts, f), getattr(whole, f)), f


def test_empty_rays():
    for samples in (False, True):
        out = render_rays(_model(kind="proposal"), _rays(0), return_samples=samples)
        assert out.rgb.shape == (0, 3) and out.depth.shape == (0,) and out.background.shape == (0, 3)
        assert (out.samples is not None) == samples


class _HeavyModel(nn.Module):
    """A ``SceneModel`` stand-in whose ``render`` is cheap but returns per-sample tensors as large as a
    real model's (``samples`` per ray: weights, bins, proposal weights; about 1.3 KB a ray), and keeps a
    weak reference to each chunk's weights so a test can see whether an earlier chunk's are still held."""

    def __init__(self, samples: int = 128) -> None:
        super().__init__()
        self.samples = samples
        self.register_buffer("background", torch.zeros(3))
        self.earlier: list[weakref.ref] = []
        self.held_at_render: list[int] = []  # per call: how many earlier chunks' weights were still alive

    def render(self, rays: Rays, appearance="mean", return_samples=False) -> RenderOutput:
        self.held_at_render.append(sum(r() is not None for r in self.earlier))
        n, s = len(rays), self.samples
        weights = torch.full((n, s), 1.0 / s)  # full, not zeros: the pages are written, as a real render's
        out = RenderOutput(rgb=rays.dirs.abs(), depth=rays.far - rays.near, depth_median=rays.far.clone(),
                           accumulation=weights.sum(-1), weights=weights, background=self.background.expand(n, 3),
                           bins=torch.full((n, s + 1), 2.0), proposal_weights=[torch.full((n, s // 2), 0.5)])
        self.earlier.append(weakref.ref(weights))
        return out


def test_no_chunk_output_outlives_its_chunk():
    model = _HeavyModel(samples=8)
    out = render_rays(model, _rays(100), chunk=10)
    assert model.held_at_render == [0] * 10  # the old path held all earlier chunks: [0, 1, 2, ..., 9]
    torch.testing.assert_close(out.depth_median, _rays(100).far)


def _rss_kb(key: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1])
    raise KeyError(key)


def test_big_image_peak_memory():
    """A 1024 x 1024-ray render grows the process's peak RSS by at most ~100 bytes a ray (the kept
    per-ray outputs are 36; a real model's per-sample output, ~1.3 KB a ray here, is dropped chunk by
    chunk). The old path peaked at over 2 KB a ray (every chunk's output, then the concatenated copy)."""
    clear = Path("/proc/self/clear_refs")
    n = 1024 * 1024
    rays = _rays(n)
    model = _HeavyModel(samples=128)
    render_rays(model, rays[:8192])  # warm-up: first-use allocations are not the render's
    gc.collect()
    try:
        clear.write_text("5")  # reset the peak RSS (VmHWM) to the current RSS (Linux >= 4.0)
    except OSError:
        pytest.skip("cannot reset the peak RSS here (/proc/self/clear_refs)")
    before = _rss_kb("VmHWM")
    out = render_rays(model, rays, chunk=8192)
    grown = (_rss_kb("VmHWM") - before) * 1024
    kept = sum(getattr(out, f).element_size() * getattr(out, f).numel() for f in PER_RAY_FIELDS)
    assert kept == 36 * n  # rgb, depth, depth_median, accumulation, background: float32
    assert grown < 100 * n, f"peak RSS grew by {grown / n:.0f} bytes a ray"
