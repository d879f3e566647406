"""Held-out scoring of a scene model: bounded-memory renders, and the left-half appearance fit.

Renders. :func:`render_image` renders a camera view (or a band of its columns) chunk by chunk and
copies from each chunk only what scoring needs -- colour, expected and median z-depth, opacity --
into preallocated ``(H, W, C)`` float32 arrays; a chunk's per-sample output (weights, bins, proposal
weights: about 1 KB a ray) is dropped before the next chunk starts, so a 1920x1080 view needs some
50 MB besides the model, not gigabytes. Pixel directions are computed per chunk from the camera
model (``Camera.unproject``), never as a whole-image table. Chunks may run on a thread pool (each
writes its own rows; the result does not depend on which thread ran what).

Appearance (NeRF-W's protocol, as nerfstudio-era papers score appearance-embedded models). A
held-out image has no trained appearance embedding. Two scores are kept: the whole image rendered
with the *mean* embedding of the training images (``psnr``, ``ssim``, ``lpips``), and the
``*_half`` scores: the embedding is fitted to the image's LEFT half (columns ``[0, W // 2)``) --
only that vector trainable, Adam at a fixed learning rate for a fixed number of steps, starting from
the mean embedding, on a seeded random subset of the left half's pixels -- and the RIGHT half
(columns ``[W // 2, W)``) is then rendered with it and scored, so no scored pixel informed the fit.
``psnr_half_mean_embedding`` scores the same right half with the mean embedding, for comparison.

Both cost little beyond the one render. The embedding only enters the colour MLP, and there
through its first, linear layer (:class:`AppearanceFit`): with the rays' samples, compositing
weights and that layer's per-sample part computed once, a colour under another code is ``W_code @
code`` added, the rest of the colour MLP on the samples that carry weight, and a weighted sum. The
fit's Adam steps run only that, on samples whose compositing coefficient is at least ``1e-4`` (the
others keep their mean-embedding colour). The scored right half is coloured the same way from the
samples of the mean-embedding render, recolouring every sample with a coefficient of at least
``1e-6``: the renderer's colour under the fitted code to within ``S * 1e-6`` (S samples a ray), from
the same pass (tests compare both with the renderer).

Frames of a scene. :func:`score_views` scores held-out frames of a :class:`~nsim.train.scene_data.SceneData`
with a model at any ``EvalConfig.image_side``: the trainer's end-of-training scores, or a published
scene-checkpoint scored again later at another resolution (``bench/real_capture.py --score-side``)
with the same views, seeds and protocol.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from concurrent.futures import Executor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from nsim.config import param
from nsim.fields.encodings import spherical_harmonics
from nsim.geometry.cameras import dirs_to_world
from nsim.metrics.depth import DepthConfig
from nsim.rendering.model import SceneModel
from nsim.train.scene_data import SceneData, image_mean_rgb
from nsim.volume.rays import make_rays

LPIPS_NETS = ("alex", "vgg", "none")
PROTOCOL_HALF = "nerfstudio left-half embedding fit, right-half score"
KEEP_COEFFICIENT = 1e-4  # the fit: samples with a smaller compositing coefficient keep their mean-embedding colour
RECOLOUR_COEFFICIENT = 1e-6  # the scored colour: within S * 1e-6 of the renderer's (S samples a ray)
FIT_GROUP_VIEWS = 16  # held-out views whose appearance codes are fitted in one batch (bounds its memory)


@dataclass(frozen=True)
class EvalConfig:
    """Held-out scoring at the end of training (``eval.json``).

    image_side: the longer side of the scored (and saved) held-out images in pixels, never above the
    images' own size; 0: as captured (full resolution; renders are chunked, so memory stays bounded).
    fit_*: the left-half appearance fit of appearance-embedded models (module docstring); fit_steps 0
    skips it. lpips_net: LPIPS backbone of the scores (none: not computed; without weights: null and
    the reason in eval.json).
    """

    image_side: int = param(0, ge=0, help="longer side (px) of the scored held-out images; 0: as captured")
    fit_steps: int = param(200, ge=0, help="Adam steps of the held-out appearance fit (0: no half-image scores)")
    fit_lr: float = param(0.05, gt=0.0, help="the fit's fixed Adam learning rate")
    fit_rays: int = param(1024, ge=1, help="pixels of the left half the fit uses (a seeded random subset)")
    lpips_net: str = param("alex", choices=LPIPS_NETS)


# ====================================================================== rendering
@dataclass(frozen=True)
class ViewRays:
    """What makes a view's rays: intrinsics, pose (4, 4) float32 OpenCV axes, ray range and box."""

    camera: Any
    cam_to_world: Tensor
    near: float
    far: float
    aabb: Tensor | None


def pixel_rays(view: ViewRays, v: Tensor, u: Tensor, device: torch.device):
    """Rays through pixel centres ``(u, v)`` (column, row; ``(R,)`` each) of ``view``, and their
    camera-axes z component (z-depth = range * z). Pixels the camera cannot unproject look along +z."""
    uv = torch.stack([u, v], -1).double().numpy()
    d = torch.as_tensor(np.asarray(view.camera.dirs_through(uv, fill_invalid=True)), dtype=torch.float32).to(device)
    origins, dirs = dirs_to_world(d, view.cam_to_world.to(device).expand(len(d), 4, 4))
    return make_rays(origins, dirs, view.near, view.far, view.aabb), d[:, 2]


@torch.no_grad()
def render_image(model: SceneModel, view: ViewRays, chunk: int, cols: tuple[int, int] | None = None,
                 appearance: str | Tensor = "mean", pool: Executor | None = None,
                 recolour: Tensor | None = None, recolour_from: int = 0) -> dict[str, np.ndarray]:
    """Render ``view`` (all columns, or ``cols = (c0, c1)``) chunk by chunk into preallocated arrays:
    rgb (H, Wc, 3) in [0, 1], depth_z and depth_median_z (H, Wc) z-depth, accumulation (H, Wc), float32.

    ``recolour``: another appearance embedding; the columns from ``recolour_from`` on are also
    coloured with it, from the same samples (:class:`AppearanceFit` recolouring every sample whose
    coefficient reaches ``RECOLOUR_COEFFICIENT``: the renderer's colour under that code to within
    ``S * 1e-6``, without a second pass), into ``rgb_recoloured (H, W - recolour_from, 3)``.
    ``pool``: chunks after the first run on it (the first runs here, so that anything compiled on
    first use is built once)."""
    h = view.camera.height
    c0, c1 = cols if cols is not None else (0, view.camera.width)
    wc = c1 - c0
    device = model.aabb.device
    out = {"rgb": np.empty((h, wc, 3), np.float32), "depth_z": np.empty((h, wc), np.float32),
           "depth_median_z": np.empty((h, wc), np.float32), "accumulation": np.empty((h, wc), np.float32)}
    flat = {k: a.reshape(h * wc, -1) for k, a in out.items()}
    if recolour is not None:
        recolour_from = max(recolour_from, c0)
        out["rgb_recoloured"] = np.empty((h, c1 - recolour_from, 3), np.float32)

    def one(a: int) -> None:
        b = min(a + chunk, h * wc)
        idx = torch.arange(a, b)
        v, u = idx // wc, c0 + idx % wc
        rays, z = pixel_rays(view, v, u, device)
        with torch.no_grad():  # per thread: the pool's threads do not inherit the caller's mode
            o = model.render(rays, appearance=appearance, return_samples=recolour is not None)
            flat["rgb"][a:b] = o.rgb.float().clamp(0.0, 1.0).cpu().numpy()
            flat["depth_z"][a:b, 0] = (o.depth.float() * z).cpu().numpy()
            flat["depth_median_z"][a:b, 0] = (o.depth_median.float() * z).cpu().numpy()
            flat["accumulation"][a:b, 0] = o.accumulation.float().cpu().numpy()
            if recolour is not None:
                sel = torch.nonzero(u >= recolour_from, as_tuple=True)[0]
                if len(sel):
                    fit = AppearanceFit(model, rays[sel], o.weights[sel], o.samples.t_starts[sel],
                                        o.samples.t_ends[sel], o.samples.rgb[sel], o.rgb[sel], keep=RECOLOUR_COEFFICIENT)
                    rgb = fit.colour(recolour).clamp(0.0, 1.0).cpu().numpy()
                    out["rgb_recoloured"][v[sel].numpy(), (u[sel] - recolour_from).numpy()] = rgb

    starts = list(range(0, h * wc, chunk))
    model.eval()
    if starts:
        one(starts[0])
    if pool is None:
        for a in starts[1:]:
            one(a)
    else:
        for f in [pool.submit(one, a) for a in starts[1:]]:
            f.result()
    return out


# ====================================================================== the appearance fit
class AppearanceFit:
    """Ray colours as a function of one appearance embedding, with the geometry held fixed.

    For rays ``(R,)`` the renderer's colour is ``sum_s a_rs c_rs(code) + b_r``: ``a`` the compositing
    weights (plus, for ``sampler.background: last_sample``, the light left ``1 - acc`` on the ray's last
    sample), ``b`` the constant background's share. Samples with ``a >= keep`` are recoloured for
    each code; the others keep the colour of the render this was built from, in ``b``.
    """

    def __init__(self, model: SceneModel, rays, weights: Tensor, t_starts: Tensor, t_ends: Tensor, sample_rgb: Tensor,
                 rendered_rgb: Tensor, keep: float = KEEP_COEFFICIENT) -> None:
        """From a render of ``rays`` with ``return_samples``: its weights, samples' intervals and colours
        ``(R, S[, 3])`` and ray colours ``(R, 3)``. ``keep``: the coefficient below which a sample keeps
        its colour from that render (0: every sample is recoloured -- the renderer's colour exactly)."""
        self.model = model
        with torch.no_grad():
            weights = weights.float()
            n, k = weights.shape
            acc = weights.sum(-1)
            coef = weights.clone()
            const = torch.zeros(n, 3, device=weights.device)
            bg_const = model.background.float().expand(n, 3)
            if model.sampler_cfg.kind == "grid":  # padded samples: empty intervals after each ray's own
                nonempty = t_ends > t_starts
                has = nonempty.any(-1)
                last = (nonempty.long() * torch.arange(k, device=weights.device)).amax(-1)
            else:  # the proposal sampler: every ray has k samples, its last is its background
                has = torch.ones(n, dtype=torch.bool, device=weights.device)
                last = torch.full((n,), k - 1, device=weights.device)
            if model.sampler_cfg.background == "last_sample":
                rows = torch.nonzero(has, as_tuple=True)[0]
                coef[rows, last[rows]] += 1.0 - acc[rows]
                const[~has] = ((1.0 - acc)[:, None] * bg_const)[~has]
            else:
                const = (1.0 - acc)[:, None] * bg_const
            kept = coef > 0.0 if keep <= 0.0 else coef >= keep
            const = const + (coef * (~kept).float())[..., None].mul(sample_rgb.float()).sum(1)
            self.ray, self.slot = torch.nonzero(kept, as_tuple=True)
            self.coef = coef[self.ray, self.slot]
            mid = 0.5 * (t_starts + t_ends)[self.ray, self.slot]
            x = rays.origins[self.ray] + rays.dirs[self.ray] * mid[:, None]
            _, geo = model.field.density(x)
            # SceneField.color = sigmoid(MLP([sh(dirs), geo, code])): the MLP's first layer is linear, so
            # its output is a per-sample part (computed here, once) plus W_code @ code (one vector a step)
            field = model.field
            layers = field.color_mlp.layers
            a = field.cfg.appearance_dim
            sh = spherical_harmonics(rays.dirs[self.ray], field.cfg.sh_degree).to(geo.dtype)
            w = layers[0].weight.detach().float()
            self.base = torch.cat([sh, geo], -1).float() @ w[:, :-a].T + layers[0].bias.detach().float()
            self.w_code = w[:, -a:]
            self.later = layers[1:]
            self.const = const
            self.n = n
            self.rendered = rendered_rgb.float()  # the render's own colour (the tests compare)

    @classmethod
    def of(cls, model: SceneModel, rays, code: Tensor, keep: float = KEEP_COEFFICIENT) -> AppearanceFit:
        """Render ``rays`` under ``code`` (no jitter) and build from that."""
        with torch.no_grad():
            o = model.render(rays, appearance=code, return_samples=True)
        s = o.samples
        return cls(model, rays, o.weights, s.t_starts, s.t_ends, s.rgb, o.rgb, keep)

    def colour(self, code: Tensor) -> Tensor:
        """Ray colours ``(R, 3)`` under ``code (appearance_dim,)``."""
        h = self.base + self.w_code @ code.float()
        for layer in self.later:  # the MLP: ReLU before every later layer, none after the last
            h = torch.nn.functional.linear(torch.relu(h), layer.weight.detach().float(), layer.bias.detach().float())
        rgb = torch.sigmoid(h)
        return self.const.index_add(0, self.ray, self.coef[:, None] * rgb)

    def fit(self, target: Tensor, code: Tensor, steps: int, lr: float) -> Tensor:
        """The code after ``steps`` full-batch Adam steps on the colour MSE against ``target (R, 3)``."""
        return fit_codes([self], [target], code, steps, lr)[0]


def fit_codes(fits: list[AppearanceFit], targets: list[Tensor], code: Tensor, steps: int, lr: float) -> Tensor:
    """One code per fit, each after ``steps`` full-batch Adam steps from ``code (A,)`` on the colour
    MSE of its own rays against its ``targets[v] (R_v, 3)``: ``(V, A)``.

    All views in one pass: their kept samples in one batch, each coloured with its own view's code,
    and the loss the sum of the views' MSEs. A view's loss involves only its own code and Adam
    updates every element on its own, so this is V separate fits, in one batch of samples instead
    of V small ones (the same numbers up to the order of floating-point sums)."""
    if len(fits) != len(targets) or not fits:
        raise ValueError(f"fit_codes: {len(fits)} fits and {len(targets)} targets")
    ref = fits[0]
    base = torch.cat([f.base for f in fits])  # (S, H): every view's kept samples, view after view
    counts = [len(f.base) for f in fits]
    offsets = np.cumsum([0] + [f.n for f in fits[:-1]])
    ray = torch.cat([f.ray + int(o) for f, o in zip(fits, offsets, strict=True)])
    coef = torch.cat([f.coef for f in fits])[:, None]
    const = torch.cat([f.const for f in fits])
    target = torch.cat([t.float() for t in targets])
    # each view's mean over its own R_v x 3 values: the sum of the views' MSEs
    per_ray = torch.cat([torch.full((f.n, 1), 1.0 / (3 * f.n), device=base.device) for f in fits])
    layers = [(layer.weight.detach().float(), layer.bias.detach().float()) for layer in ref.later]
    codes = code.detach().float().expand(len(fits), -1).clone().requires_grad_(True)
    opt = torch.optim.Adam([codes], lr=lr)
    with torch.autocast(base.device.type, enabled=False):
        for _ in range(steps):
            proj = codes @ ref.w_code.T  # (V, H); expanded per view, so its gradient is a plain sum
            h = base + torch.cat([proj[v].expand(n, -1) for v, n in enumerate(counts)])
            for w, b in layers:  # the colour MLP: ReLU before every later layer, none after the last
                h = torch.nn.functional.linear(torch.relu(h), w, b)
            colour = const.index_add(0, ray, coef * torch.sigmoid(h))
            loss = (((colour - target) ** 2) * per_ray).sum()
            (grad,) = torch.autograd.grad(loss, [codes])  # the model's own .grad stays untouched
            codes.grad = grad
            opt.step()
    return codes.detach()


def left_half_pixels(height: int, width: int, n: int, generator: torch.Generator) -> tuple[Tensor, Tensor]:
    """``n`` distinct pixels ``(v, u)`` of the left half (columns ``[0, width // 2)``), drawn with
    ``generator`` (all of them when the half has no more), in row-major order."""
    half = width // 2
    total = height * half
    idx = torch.arange(total) if n >= total else torch.sort(torch.randperm(total, generator=generator)[:n]).values
    return idx // half, idx % half


# ====================================================================== scores
def image_scores(pred: np.ndarray, gt: np.ndarray, lpips_net: str, device: str = "cpu") -> dict[str, Any]:
    """PSNR, SSIM (and LPIPS unless ``lpips_net`` is none) of (H, W, 3) images in [0, 1] (``nsim.metrics``).
    LPIPS is None when it cannot run (no weights; image too small), with the reason under ``lpips_na``."""
    from nsim.errors import InputError
    from nsim.metrics.image import psnr, ssim
    from nsim.metrics.lpips import lpips_or_na
    from nsim.metrics.results_table import NotAvailable

    row: dict[str, Any] = {"psnr": psnr(pred, gt), "ssim": ssim(pred, gt)}
    if lpips_net != "none":
        try:
            value = lpips_or_na(pred, gt, net=lpips_net, device=device)
        except InputError as err:  # too small for the network
            value = NotAvailable(str(err))
        if isinstance(value, NotAvailable):
            row["lpips"], row["lpips_na"] = None, value.reason
        else:
            row["lpips"] = float(value)
    return row


def fits_half(model: SceneModel, cfg: EvalConfig, width: int) -> bool:
    """Whether ``final`` scoring fits a held-out appearance code (an embedded model, fit steps, a left half)."""
    return model.field.appearance is not None and cfg.fit_steps > 0 and width // 2 >= 1


def mean_code(model: SceneModel) -> Tensor:
    """The mean appearance embedding of the training images ``(A,)``."""
    return model.field.appearance_codes(None, 1, "mean", model.train_mask)[0].detach()


def left_half_fit(model: SceneModel, view: ViewRays, gt: np.ndarray, cfg: EvalConfig,
                  generator: torch.Generator) -> tuple[AppearanceFit, Tensor]:
    """What fits a held-out view's code: the :class:`AppearanceFit` of ``cfg.fit_rays`` left-half pixels of
    ``view`` (drawn with ``generator``) under the mean code, and their colours in ``gt (H, W, 3)`` [0, 1]."""
    h, w = gt.shape[:2]
    device = model.aabb.device
    model.eval()
    v, u = left_half_pixels(h, w, cfg.fit_rays, generator)
    rays, _ = pixel_rays(view, v, u, device)
    target = torch.as_tensor(gt[v.numpy(), u.numpy()], device=device)
    return AppearanceFit.of(model, rays, mean_code(model)), target


def score_view(model: SceneModel, view: ViewRays, gt_u8: np.ndarray, gt_depth: np.ndarray | None, chunk: int,
               cfg: EvalConfig, final: bool, generator: torch.Generator | None = None,
               pool: Executor | None = None, on_render: Callable[[np.ndarray], None] | None = None,
               code: Tensor | None = None, depth_cfg: DepthConfig | None = None) -> dict[str, Any]:
    """Scores of one held-out view (see the module docstring); ``final`` adds LPIPS and the half-image
    scores (these need ``generator`` for the fit's pixels, or the fitted ``code (A,)`` itself:
    :func:`score_views` fits many views' codes at once). ``on_render(rgb)``: called with the
    mean-embedding render (to save it) before it is dropped. Depth AbsRel (with ``gt_depth``) is
    ``nsim.metrics.depth``'s, per view (``view_abs_rel``), with ``depth_cfg``'s bounds in the scene's units
    (default: the metric's own, in metres)."""
    from nsim.metrics.depth import view_abs_rel
    from nsim.metrics.image import psnr

    device = model.aabb.device
    gt = gt_u8.astype(np.float32) / 255.0
    h, w = gt.shape[:2]
    half = w // 2
    if not (final and fits_half(model, cfg, w)):
        code = None
    elif code is None:
        fit, target = left_half_fit(model, view, gt, cfg, generator)
        code = fit.fit(target, mean_code(model), cfg.fit_steps, cfg.fit_lr)
    if code is not None:
        code = code.to(device)
    # one pass: the mean-embedding image, and its right half again under the fitted code
    pred = render_image(model, view, chunk, pool=pool, recolour=code, recolour_from=half)
    row = image_scores(pred["rgb"], gt, cfg.lpips_net if final else "none", str(device))
    if gt_depth is not None:
        depth_cfg = DepthConfig() if depth_cfg is None else depth_cfg
        row["abs_rel_expected"] = view_abs_rel(pred["depth_z"], gt_depth, depth_cfg)
        row["abs_rel_median"] = view_abs_rel(pred["depth_median_z"], gt_depth, depth_cfg)
    if on_render is not None:
        on_render(pred["rgb"])
    if code is not None:
        scores = image_scores(pred["rgb_recoloured"], gt[:, half:], cfg.lpips_net, str(device))
        row.update({f"{k}_half": val for k, val in scores.items()})
        row["psnr_half_mean_embedding"] = psnr(pred["rgb"][:, half:], gt[:, half:])
        row["appearance_fit_shift"] = float(torch.linalg.vector_norm(code - mean_code(model)))
    return row


def frame_view(model: SceneModel, cam_to_world, camera) -> ViewRays:
    """What renders a frame at its pose ``cam_to_world (4, 4)`` (OpenCV axes) through ``camera`` (any
    size): the model's own ray range (``sampler.near_m / far_m``) and, when it clips rays to its box, the box."""
    s = model.sampler_cfg
    c2w = torch.as_tensor(np.asarray(cam_to_world), dtype=torch.float32).cpu()
    return ViewRays(camera, c2w, s.near_m, s.far_m, model.aabb if s.clip_rays_to_box else None)


def score_views(model: SceneModel, data, views: list[int], cfg: EvalConfig, chunk: int,
                fit_generator: Callable[[int], torch.Generator], final: bool = True, pool: Executor | None = None,
                image_dir: Path | None = None, seed_note: str = "with a generator seeded by (seed, frame)") -> dict[str, Any]:
    """Scores of frames ``views`` of ``data`` (:class:`~nsim.train.scene_data.SceneData`) at
    ``cfg.image_side`` (0: as captured), ``FIT_GROUP_VIEWS`` views at a time: their ground truth read once at
    that size, their appearance codes fitted together (:func:`fit_codes`), then each scored
    (:func:`score_view`). ``fit_generator(frame)``: the generator of that frame's fit pixels.
    ``image_dir``: each render beside its ground truth is written there (``frame_NNNNN.png``, under a
    label strip ``<image name> render | ground truth``, ``nsim.io.labels``).
    Returns ``views`` (one row each), ``mean``, ``resolution`` (scored and captured ``[w, h]``) and ``protocol``."""
    from nsim.io.images import to_uint8, write_image
    from nsim.io.labels import add_label
    from nsim.train.scene_data import units_per_metre

    depth_cfg = DepthConfig().in_units(units_per_metre(data)[0])  # the scene's units, as its training's lengths
    rows = []
    scored = None
    fitting = final and cfg.fit_steps > 0 and model.field.appearance is not None
    for g in range(0, len(views), FIT_GROUP_VIEWS):  # a group's ground truth read once: its codes fitted together, then scored
        group = []
        for i in views[g : g + FIT_GROUP_VIEWS]:
            camera = data.eval_camera(i, cfg.image_side)
            group.append((i, camera, frame_view(model, data.cam_to_world[i], camera), data.eval_image(i, camera)))
        codes: dict[int, Tensor] = {}
        fits, targets, fitted = [], [], []
        for i, camera, view, gt in group if fitting else ():
            if fits_half(model, cfg, camera.width):
                fit, target = left_half_fit(model, view, gt.astype(np.float32) / 255.0, cfg, fit_generator(int(i)))
                fits.append(fit)
                targets.append(target)
                fitted.append(i)
        if fits:
            codes = dict(zip(fitted, fit_codes(fits, targets, mean_code(model), cfg.fit_steps, cfg.fit_lr), strict=True))
        del fits, targets
        for i, camera, view, gt in group:
            scored = [camera.width, camera.height]
            save = None
            if image_dir is not None:
                def save(rgb, i=i, gt=gt):
                    write_image(Path(image_dir) / f"frame_{i:05d}.png",
                                add_label(np.concatenate([to_uint8(rgb), gt], axis=1),
                                          [f"{data.names[i]} render", "ground truth"]))
            row = score_view(model, view, gt, data.eval_depth_z(i, camera), chunk, cfg, final, fit_generator(int(i)),
                             pool, save, code=codes.get(i), depth_cfg=depth_cfg)
            rows.append({"frame": int(i), "name": data.names[i], **row})
    fh, fw = data.full_size_hw
    return {"views": rows, "mean": mean_scores(rows),
            "resolution": {"scored_wh": scored, "captured_wh": [fw, fh], "eval.image_side": cfg.image_side},
            "protocol": protocol(cfg, seed_note)}


def mean_scores(rows: list[dict[str, Any]]) -> dict[str, float]:
    """The mean of every numeric score over the views (views where a score is None or NaN are left out)."""
    keys = [k for k in rows[0] if k not in ("frame", "name")] if rows else []
    out = {}
    for k in keys:
        vals = [r[k] for r in rows if isinstance(r.get(k), (int, float)) and not isinstance(r.get(k), bool)
                and math.isfinite(r[k])]
        if vals:
            out[k] = float(np.mean(vals))
    return out


def constant_color_psnr(data: SceneData, holdout_every: int) -> float:
    """PSNR of the training images' mean colour on the held-out frames (the trivial baseline), at the
    training resolution."""
    from nsim.metrics.image import psnr

    train, held = data.split(holdout_every)
    mean = np.asarray(image_mean_rgb(data, train))
    return float(np.mean([psnr(np.broadcast_to(mean, data.images[i].shape), data.images[i] / 255.0) for i in held]))


def protocol(cfg: EvalConfig, seed_note: str) -> dict[str, str]:
    """eval.json's description of what each score is."""
    depth = DepthConfig()
    return {
        "psnr, ssim, lpips": "whole held-out image, rendered with the mean appearance embedding of the training images",
        "psnr_half, ssim_half, lpips_half": (f"{PROTOCOL_HALF}: the held-out image's embedding fitted on its left half "
                                             f"(columns [0, W // 2), {cfg.fit_rays} pixels drawn {seed_note}; "
                                             f"{cfg.fit_steps} full-batch Adam steps at lr {cfg.fit_lr:g} from the mean "
                                             "embedding, only the embedding trainable), scored on its right half"),
        "psnr_half_mean_embedding": "the same right half rendered with the mean embedding",
        "abs_rel_expected, abs_rel_median": ("z-depth AbsRel (nsim.metrics.depth) against the capture's depth "
                                             "(nearest pixel at the scored size): ground truth in "
                                             f"[{depth.min_depth_m:g}, {depth.max_depth_m:g}] m, predictions "
                                             "clamped into that range (for a scene of arbitrary scale, the same "
                                             "lengths in its units)"),
        "lpips_net": cfg.lpips_net,
    }

