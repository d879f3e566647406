"""A baked surface: the scene NeRF's surface as a triangle mesh fitted to its median depths, coloured by a
hash-grid texture read once a ray. The fast half of ``nsim bake`` (``BakeConfig.surface``).

Why a surface (issue 25, measured on the ``cpu``-preset robot-lab scene, 4 held-out views, one thread): the NeRF
costs about 75 us a ray, the volume bake's march 12-15 us and its field window 30 us, so 10x the NeRF leaves
some 7 us a ray in all. A mesh is found by Embree in about 0.5 us a ray and one texture lookup costs about 2 us.
Where the colour is read matters more than how it is stored: a texture read at the volume bake's median depth
scores 27-29 dB, one read at a mesh fitted to the NeRF's median depths 33.2 dB against the images, where the
NeRF itself scores 32.5 (``bench/baked_colour.py`` and the README have the figures). The same texel seen from
two views must land on the same point, which only one sharp surface gives.

Baking (``bake_surface``: arrays in, arrays out)
    1. Mesh (``mesh_of_bricks``): marching cubes (``nsim.volume.density_mesh.marching_cubes``) at ``surface_level``
       (1/m) of the volume bake's density lattice, one slab of bricks at a time, the slabs' shared vertices
       welded. Pieces under ``surface_min_area_m2`` are dropped (floaters).
    2. Fit (``fit_mesh``): the target is the NeRF's median depth on the training rays (every
       ``surface_stride``-th pixel of each training image both ways, rays whose accumulation reaches 0.5).
       Each vertex ``k`` moves along its normal ``n_k`` by ``delta_k``; a ray hitting face ``f`` (normal
       ``n_f``) with barycentric weights ``b_k`` then meets it ``sum_k b_k delta_k (n_k . n_f) / (d . n_f)``
       farther along (first order). ``surface_fit_passes`` Gauss-Newton passes; each casts the rays, keeps
       those whose hit lies within ``surface_fit_gate_m`` of the target (the same surface) and that do not
       graze their face (``|d . n_f| > 0.2``), solves the ridge-regularised normal equations
       ``(A^T A + surface_fit_ridge I + surface_fit_smooth L^T L) delta = A^T r`` (``L``: the mesh's uniform
       graph Laplacian, ``I - D^-1 W``) by conjugate gradients and clips each step to ``surface_fit_step_m``.
    3. Texture (``fit_texture``): ``rgb = sigmoid(MLP(hash(u)))`` with instant-NGP's multiresolution hash
       grid (``nsim.fields.hash_encoding``; ``texture_levels`` levels of ``2^texture_log2_size`` rows, finest
       ``texture_max_resolution`` cells across the scene box) and a ``texture_width``-wide decoder, fitted by
       Adam to the training images' pixels of those rays at their mesh hits (``texture_from: images``; or to the
       NeRF's colours there, ``nerf``, 0.6 dB worse on the robot-lab scene). View-independent: one lookup a ray.

Rendering (``render_surface``: rays in, a ``RenderOutput`` out)
    Embree (``embreex``, CPU) casts each ray from ``near`` to ``far`` against the mesh (two-sided); a hit's
    colour is the texture at the hit point (on the scene's device), its accumulation 1, its depth and median
    depth the hit's range; a miss has accumulation 0 and the background's colour. With samples (the people's
    merge, ``nsim.volume.compositing``): one opaque sample at the hit.

Shapes: vertices ``(V, 3)`` float32 world metres, faces ``(F, 3)`` int32; rays ``(R,)``.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from nsim.errors import ConfigError
from nsim.fields.hash_encoding import HashEncoding
from nsim.fields.mlp import MLP
from nsim.volume.rays import Rays
from nsim.volume.samples import RaySamples, RenderOutput

log = logging.getLogger(__name__)

OPAQUE_SIGMA = 1e6
"""Density (1/m) of the one sample a surface hit gives the people's merge: opaque over ``OPAQUE_THICKNESS_M``."""
OPAQUE_THICKNESS_M = 1e-4
GRAZING = 0.2
"""Fit: rays meeting their face at ``|d . n_f|`` below this are left out (their depth is ill-conditioned)."""
SLAB_NODES = 1 << 25
"""Marching cubes: lattice nodes per slab of bricks (bounds the dense volume held at once)."""


def _embree():
    try:
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh
    except ImportError:  # pragma: no cover - embreex is a dependency; this guards broken installs
        raise ConfigError("the baked surface casts rays with Embree: pip install embreex") from None
    return rtcore_scene, TriangleMesh


class MeshCaster:
    """Embree's ray caster over one triangle mesh (two-sided), on the CPU. vertices ``(V, 3)``, faces ``(F, 3)``."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        rtcore_scene, triangle_mesh = _embree()
        self.vertices = np.ascontiguousarray(vertices, dtype=np.float32)
        self.faces = np.ascontiguousarray(faces, dtype=np.int32)
        self._scene = rtcore_scene.EmbreeScene()
        if len(self.faces):
            triangle_mesh(self._scene, self.vertices, self.faces)

    def cast(self, origins: np.ndarray, dirs: np.ndarray, t_max: np.ndarray) -> dict[str, np.ndarray]:
        """Nearest hit of rays ``origins + t dirs`` (``(R, 3)``, unit dirs) with ``0 <= t <= t_max (R,)``:
        ``t (R,)`` (``inf`` for a miss), ``face (R,)`` int32 (-1 for a miss), barycentric ``u, v (R,)`` (the hit is
        ``(1 - u - v) p0 + u p1 + v p2`` of the face's corners)."""
        n = len(origins)
        if n == 0 or len(self.faces) == 0:
            return {"t": np.full(n, np.inf, np.float32), "face": np.full(n, -1, np.int32),
                    "u": np.zeros(n, np.float32), "v": np.zeros(n, np.float32)}
        res = self._scene.run(np.ascontiguousarray(origins, dtype=np.float32),
                              np.ascontiguousarray(dirs, dtype=np.float32),
                              dists=np.ascontiguousarray(np.minimum(t_max, 3e38), dtype=np.float32), output=1)
        face = res["primID"].astype(np.int32)
        return {"t": np.where(face >= 0, res["tfar"], np.inf).astype(np.float32), "face": face,
                "u": res["u"], "v": res["v"]}

    def cast_rays(self, rays: Rays) -> tuple[Tensor, Tensor]:
        """``range (R,)`` along each ray (``inf`` for a miss, on the rays' device) and ``hit (R,)`` bool, casting
        from ``near`` to ``far``."""
        o = rays.origins.detach().cpu().numpy()
        d = rays.dirs.detach().cpu().numpy()
        near = rays.near.detach().cpu().numpy()
        far = rays.far.detach().cpu().numpy()
        res = self.cast(o + d * near[:, None], d, np.maximum(far - near, 0.0))
        t = torch.as_tensor(res["t"] + near.astype(np.float32)).to(rays.origins.device)
        return t, torch.isfinite(t)


class SurfaceTexture(nn.Module):
    """``rgb (R, 3) = sigmoid(MLP(hash((x - lo) / (hi - lo))))`` for world points ``x (R, 3)`` in the box ``aabb (2, 3)``."""

    def __init__(self, aabb: Tensor, levels: int, log2_table_size: int, max_resolution: int, width: int,
                 base_resolution: int = 16, generator: torch.Generator | None = None) -> None:
        super().__init__()
        self.register_buffer("aabb", aabb.detach().float().clone())
        self.settings = {"levels": int(levels), "log2_table_size": int(log2_table_size),
                         "max_resolution": int(max_resolution), "width": int(width),
                         "base_resolution": int(base_resolution)}
        self.encoding = HashEncoding(levels, 2, log2_table_size, base_resolution, max_resolution, generator=generator)
        self.decoder = MLP(self.encoding.n_output_dims, width, 1, 3, generator)

    def forward(self, x: Tensor) -> Tensor:
        u = (x - self.aabb[0]) / (self.aabb[1] - self.aabb[0])
        return torch.sigmoid(self.decoder(self.encoding(u)))

    @staticmethod
    def file_stems() -> dict[str, str]:
        """File stem -> parameter name: ``texture_table`` and ``texture_layer<k>_{weight,bias}`` (one hidden layer)."""
        names = {"texture_table": "encoding.table"}
        for k in range(2):
            names.update({f"texture_layer{k}_{w}": f"decoder.layers.{k}.{w}" for w in ("weight", "bias")})
        return names

    def arrays(self) -> dict[str, np.ndarray]:
        """The parameters by file stem (:meth:`file_stems`), float32."""
        state = self.state_dict()
        return {stem: state[name].detach().cpu().numpy().astype(np.float32) for stem, name in self.file_stems().items()}

    @classmethod
    def from_arrays(cls, aabb: Tensor, settings: dict[str, Any], arrays: dict[str, np.ndarray]) -> SurfaceTexture:
        """The texture :meth:`arrays` wrote (``ValueError`` naming what does not fit)."""
        tex = cls(aabb, int(settings["levels"]), int(settings["log2_table_size"]), int(settings["max_resolution"]),
                  int(settings["width"]), int(settings.get("base_resolution", 16)))
        names = cls.file_stems()
        own = tex.state_dict()
        for stem, name in names.items():
            arr = arrays[stem]
            if tuple(arr.shape) != tuple(own[name].shape):
                raise ValueError(f"{stem}.npy has shape {tuple(arr.shape)}, the texture's settings give "
                                 f"{tuple(own[name].shape)}")
            if not np.isfinite(arr).all():
                raise ValueError(f"{stem}.npy holds non-finite values")
        tex.load_state_dict({**{name: torch.as_tensor(np.array(arrays[stem])) for stem, name in names.items()},
                             "aabb": tex.aabb})
        return tex.eval().requires_grad_(False)


@dataclass
class BakedSurface:
    """A fitted mesh and its texture (module docstring); ``stats``: what baking measured (``baked.json``)."""

    vertices: np.ndarray
    faces: np.ndarray
    texture: SurfaceTexture
    stats: dict = dataclasses.field(default_factory=dict)
    _caster: MeshCaster | None = dataclasses.field(default=None, init=False, repr=False)

    @property
    def caster(self) -> MeshCaster:
        """Embree's scene over the mesh, built on first use."""
        if self._caster is None:
            self._caster = MeshCaster(self.vertices, self.faces)
        return self._caster

    def to(self, device) -> BakedSurface:
        """The texture on ``device`` (the mesh stays on the CPU, where Embree casts)."""
        out = BakedSurface(self.vertices, self.faces, self.texture.to(device), self.stats)
        out._caster = self._caster
        return out

    def nbytes(self) -> int:
        texture = sum(t.numel() * t.element_size() for t in self.texture.parameters())
        return int(self.vertices.nbytes + self.faces.nbytes + texture)


# -- baking -------------------------------------------------------------------------------------------------


def mesh_of_bricks(brick_index: np.ndarray, density: np.ndarray, bricks_per_side: int, lo_m: np.ndarray,
                   voxel_m: np.ndarray, level: float, min_area_m2: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The ``level`` iso-surface of a brick lattice (``nsim.rendering.baked``'s layout: ``brick_index (X, Y, Z)``,
    ``density (N, (B + 1)^3)``, lattice point ``(a, b, c)`` of the brick in cell ``(i, j, k)`` at ``lo_m + ((i, j,
    k) B + (a, b, c)) voxel_m``); space without a brick counts as density 0. Marching cubes one slab of bricks
    along x at a time (``SLAB_NODES``), the slabs' shared vertices welded. Returns ``vertices (V, 3)`` float32 and
    ``faces (F, 3)`` int32; none when the level is not crossed."""
    from nsim.volume import density_mesh as meshing

    b = int(bricks_per_side)
    p = b + 1
    nx, ny, nz = brick_index.shape
    voxel = np.asarray(voxel_m, dtype=np.float64)
    plane = (ny * b + 1) * (nz * b + 1)
    slab = max(1, min(nx, SLAB_NODES // max(1, plane * b)))
    verts, faces, n_verts = [], [], 0
    for x0 in range(0, nx, slab):
        x1 = min(nx, x0 + slab)
        sub = brick_index[x0:x1]
        cells = np.argwhere(sub >= 0)
        if not len(cells):
            continue
        vol = np.zeros(((x1 - x0) * b + 1, ny * b + 1, nz * b + 1), np.float32)
        pts = density[sub[sub >= 0]].reshape(-1, p, p, p)
        for a in range(p):
            for c in range(p):
                vol[cells[:, 0, None] * b + a, cells[:, 1, None] * b + c, cells[:, 2, None] * b + np.arange(p)] = \
                    pts[:, a, c, :]
        # marching cubes on an isotropic lattice, then stretched to the (nearly equal) per-axis voxel
        lattice = meshing.Lattice(lo_m=(0.0, 0.0, 0.0), cell_m=1.0, shape=vol.shape)
        try:
            v, f = meshing.marching_cubes(vol, level, lattice)
        except meshing.EmptySurface:
            continue
        v = (v + [x0 * b, 0.0, 0.0]) * voxel + np.asarray(lo_m, dtype=np.float64)
        verts.append(v)
        faces.append(f + n_verts)
        n_verts += len(v)
    if not faces:
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32)
    v = np.concatenate(verts)
    f = np.concatenate(faces)
    # weld: the slabs' boundary planes are computed from the same nodes on both sides, so their vertices agree
    key = np.round(v / voxel.min() * 1024.0).astype(np.int64)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    v, f = v[first], inverse.reshape(-1)[f]
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    if min_area_m2 > 0:
        v, f, _ = meshing.drop_small_components(v, f, min_area_m2)
    v, f = meshing.keep_faces(v, f, np.ones(len(f), bool))
    return v.astype(np.float32), f.astype(np.int32)


def fit_mesh(vertices: np.ndarray, faces: np.ndarray, origins: np.ndarray, dirs: np.ndarray, t_max: np.ndarray,
             target: np.ndarray, passes: int, ridge: float, gate_m: float, step_m: float,
             smooth: float = 0.0) -> tuple[np.ndarray, dict]:
    """Move each vertex along its normal so that the mesh's hit ranges of rays ``origins, dirs (R, 3)`` (cast up to
    ``t_max (R,)``) match ``target (R,)`` (module docstring, step 2). Returns the vertices ``(V, 3)`` float32 and
    per-pass statistics (rays used, median |residual| before the pass, median |step|)."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spl

    from nsim.volume import density_mesh as meshing

    v = vertices.astype(np.float64)
    passes_out = []
    lap = None
    if smooth > 0:  # the uniform graph Laplacian over the mesh's edges: a vertex's step against its neighbours' mean
        e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
        e = np.unique(np.sort(e, axis=1), axis=0)
        w = sp.csr_matrix((np.ones(2 * len(e)), (np.concatenate([e[:, 0], e[:, 1]]), np.concatenate([e[:, 1], e[:, 0]]))),
                          shape=(len(v), len(v)))
        deg = np.asarray(w.sum(1)).ravel()
        lap = sp.identity(len(v), format="csr") - sp.diags(1.0 / np.maximum(deg, 1.0)) @ w
        lap = smooth * (lap.T @ lap)
    for k in range(passes):
        normals = meshing.vertex_normals(v, faces)
        hit = MeshCaster(v, faces).cast(origins, dirs, t_max)
        use = np.nonzero((hit["face"] >= 0) & (np.abs(target - hit["t"]) < gate_m))[0]
        tri = faces[hit["face"][use]]
        nf = meshing.face_normals(v, tri)
        nf /= np.linalg.norm(nf, axis=1, keepdims=True) + 1e-12
        dn = (dirs[use] * nf).sum(1)
        ok = np.abs(dn) > GRAZING
        use, tri, nf, dn = use[ok], tri[ok], nf[ok], dn[ok]
        res = (target[use] - hit["t"][use]).astype(np.float64)
        bary = np.stack([1.0 - hit["u"][use] - hit["v"][use], hit["u"][use], hit["v"][use]], 1)
        coef = bary * (normals[tri] * nf[:, None, :]).sum(-1) / dn[:, None]
        n = len(use)
        a = sp.csr_matrix((coef.ravel(), (np.repeat(np.arange(n), 3), tri.ravel())), shape=(n, len(v)))
        m = (a.T @ a) + ridge * sp.identity(len(v), format="csr")
        if lap is not None:
            m = m + lap
        delta, _ = spl.cg(m, a.T @ res, maxiter=300, rtol=1e-6)
        delta = np.clip(delta, -step_m, step_m)
        v = v + delta[:, None] * normals
        stat = {"rays": int(n), "residual_median_m": float(np.median(np.abs(res))) if n else 0.0,
                "step_median_m": float(np.median(np.abs(delta[delta != 0]))) if np.any(delta != 0) else 0.0}
        passes_out.append(stat)
        log.info("bake: surface fit pass %d/%d: %d rays, median |residual| %.2f mm, median step %.2f mm", k + 1,
                 passes, n, 1e3 * stat["residual_median_m"], 1e3 * stat["step_median_m"])
    return v.astype(np.float32), {"passes": passes_out}


def fit_texture(texture: SurfaceTexture, points: Tensor, colours: Tensor, steps: int, batch: int, lr: float,
                generator: torch.Generator, on_step=None) -> float:
    """Fit ``texture`` to ``colours (N, 3)`` at world ``points (N, 3)`` by Adam (learning rate decaying tenfold over
    the ``steps``), batches of ``batch`` drawn with ``generator``. Returns the last batch's PSNR (dB)."""
    # imported here: the nsim.metrics package costs a renderer (which never fits) a second to import
    from nsim.metrics.image import psnr_from_mse

    if len(points) == 0:
        raise ValueError("fit_texture: no points to fit the texture to")
    opt = torch.optim.Adam([{"params": texture.encoding.parameters(), "eps": 1e-15},
                            {"params": texture.decoder.parameters()}], lr=lr)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: 0.1 ** (s / max(1, steps)))
    loss = torch.tensor(float("nan"))
    texture.train()
    with torch.enable_grad():
        for s in range(steps):
            idx = torch.randint(0, len(points), (batch,), generator=generator).to(points.device)
            loss = ((texture(points[idx]) - colours[idx]) ** 2).mean()
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            sched.step()
            if on_step is not None:
                on_step(s)
    texture.eval().requires_grad_(False)
    return psnr_from_mse(max(float(loss.detach()), 1e-12))


# -- rendering ----------------------------------------------------------------------------------------------


@torch.no_grad()
def render_surface(surface: BakedSurface, rays: Rays, background_rgb: Tensor, colour: bool = True,
                   return_samples: bool = False) -> RenderOutput:
    """Render ``rays`` from the surface (module docstring). ``colour=False`` (a LiDAR): no texture lookups (rgb
    is the background)."""
    n = len(rays)
    device = rays.origins.device
    t, hit = surface.caster.cast_rays(rays)
    acc = hit.float()
    bg = background_rgb.to(device).expand(n, 3)
    rgb = bg.clone()
    idx = torch.nonzero(hit, as_tuple=True)[0]
    if colour and idx.numel():
        x = rays.origins[idx] + rays.dirs[idx] * t[idx, None]
        rgb[idx] = surface.texture(x).to(rgb.dtype)
    depth = torch.where(hit, t, rays.far)
    samples = None
    if return_samples:
        t0 = torch.where(hit, t, rays.far)[:, None]
        samples = RaySamples(t0, t0 + torch.where(hit, OPAQUE_THICKNESS_M, 0.0)[:, None],
                             torch.where(hit, OPAQUE_SIGMA, 0.0)[:, None], rgb[:, None, :].clone())
    return RenderOutput(rgb=rgb, depth=depth, depth_median=depth.clone(), accumulation=acc, weights=acc[:, None],
                        samples=samples, background=bg)


__all__ = ["BakedSurface", "MeshCaster", "SurfaceTexture", "fit_mesh", "fit_texture", "mesh_of_bricks",
           "render_surface"]
