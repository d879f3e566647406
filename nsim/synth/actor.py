"""An articulated, textured person for the test room, ray cast exactly (vectorised numpy).

``Actor(height_m, seed)`` is the nsim body (``nsim.human.skeleton.nsim_skeleton``) dressed as
rigid *parts* attached to its joints: capsules along the limbs, ellipsoids for the pelvis,
abdomen, chest, head and nose. Each part lives in its joint's frame, so a pose is given by the
joint-to-world transforms ``(J, 4, 4)`` from ``forward_kinematics`` (any pose, any root
transform; parts overlap at the joints, like a mannequin).

Appearance (seeded, deterministic): skin, shirt, trousers, shoes and hair are photographs
shipped with scikit-image (``nsim.synth.textures.load_photo``) turned into low-contrast
fabric, skin or hair textures and tinted from small palettes; the chest carries a printed
photograph on the *front* only, and the head has a face (eyes, brows, mouth, nose) in front
and hair at the back, so front and back views differ. Texture coordinates are in metres on the
part's surface (around x along), sampled bilinearly.

Shading matches the room's (``nsim.synth.raycast``): ``albedo * (ambient + sun + lamp)``,
Lambertian, no shadows. Surfaces are seen from outside: a ray that starts inside a part does
not hit that part.

``composite_actors(room_t, room_rgb, hits)`` merges actor hits into a room rendering (nearest
surface wins) and gives the per-pixel actor index, which is the person mask.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from nsim.human.skeleton import REFERENCE_HEIGHT_M, Skeleton, nsim_skeleton
from nsim.synth.raycast import DEFAULT_LIGHTING, Lighting
from nsim.synth.textures import load_photo, sample_texture

_CAPSULE, _ELLIPSOID = 0, 1

# Palettes (linear-ish sRGB albedo in [0, 1]).
SKIN_TONES = ((0.87, 0.70, 0.58), (0.76, 0.57, 0.45), (0.60, 0.43, 0.32), (0.42, 0.29, 0.21), (0.93, 0.78, 0.68))
SHIRT_COLOURS = ((0.70, 0.12, 0.12), (0.15, 0.35, 0.65), (0.20, 0.55, 0.30), (0.85, 0.65, 0.15),
                 (0.55, 0.25, 0.60), (0.90, 0.90, 0.88))
TROUSER_COLOURS = ((0.12, 0.18, 0.35), (0.15, 0.15, 0.16), (0.45, 0.38, 0.28), (0.30, 0.32, 0.30))
HAIR_COLOURS = ((0.08, 0.06, 0.05), (0.30, 0.18, 0.10), (0.55, 0.40, 0.22), (0.20, 0.20, 0.20))
SHOE_COLOURS = ((0.10, 0.10, 0.10), (0.85, 0.85, 0.85), (0.35, 0.22, 0.12))
PRINT_PHOTOS = ("astronaut", "rocket", "chelsea", "coffee", "stereo_motorcycle")
_FABRIC_PHOTOS = {"skin": "gravel", "shirt": "brick", "trousers": "gravel", "shoes": "text", "hair": "grass"}
_FABRIC_CONTRAST = {"skin": 0.12, "shirt": 0.25, "trousers": 0.45, "shoes": 0.2, "hair": 0.8}
_METRES_PER_TEXEL = {"skin": 0.002, "shirt": 0.0015, "trousers": 0.0015, "shoes": 0.002, "hair": 0.0008}
MATERIALS = ("skin", "shirt", "trousers", "shoes", "hair")


@dataclass(frozen=True)
class Part:
    """One rigid primitive in the frame of joint ``joint``.

    kind: "capsule" (segment ``a_m -> b_m``, ``radius_m``) or "ellipsoid" (centre ``a_m``, semi-axes ``axes_m``).
    material: one of ``MATERIALS``; the "chest" and "head" parts also get the print and the face.
    """

    name: str
    joint: int
    kind: str
    a_m: tuple[float, float, float]
    b_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    radius_m: float = 0.0
    axes_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    material: str = "skin"

    def bounding_sphere(self) -> tuple[np.ndarray, float]:
        """Centre ``(3,)`` (joint frame) and radius of a sphere around the part."""
        a = np.asarray(self.a_m)
        if self.kind == "capsule":
            b = np.asarray(self.b_m)
            return 0.5 * (a + b), 0.5 * float(np.linalg.norm(b - a)) + self.radius_m
        return a, float(max(self.axes_m))


def actor_parts(skeleton: Skeleton) -> tuple[Part, ...]:
    """The parts of the nsim body ``skeleton`` (its joint names), sized by its height."""
    s = skeleton.height_m() / (REFERENCE_HEIGHT_M - 0.03)
    j = skeleton.index
    off = skeleton.offsets_m
    end = skeleton.end_sites_m

    def v(x: float, y: float, z: float) -> tuple[float, float, float]:
        return (x * s, y * s, z * s)

    def tup(a: np.ndarray) -> tuple[float, float, float]:
        return (float(a[0]), float(a[1]), float(a[2]))

    parts = [
        Part("pelvis", j("pelvis"), "ellipsoid", v(-0.01, 0.0, -0.03), axes_m=v(0.11, 0.165, 0.12), material="trousers"),
        Part("abdomen", j("spine2"), "ellipsoid", v(0.0, 0.0, -0.03), axes_m=v(0.105, 0.15, 0.14), material="shirt"),
        Part("chest", j("spine3"), "ellipsoid", v(0.0, 0.0, 0.04), axes_m=v(0.115, 0.175, 0.15), material="shirt"),
        Part("neck", j("neck"), "capsule", (0.0, 0.0, 0.0), tup(off[j("head")]), radius_m=0.05 * s, material="skin"),
        Part("head", j("head"), "ellipsoid", v(0.015, 0.0, 0.07), axes_m=v(0.1, 0.08, 0.115), material="skin"),
        Part("nose", j("head"), "ellipsoid", v(0.11, 0.0, 0.055), axes_m=v(0.028, 0.016, 0.03), material="skin"),
    ]
    for side in ("left", "right"):
        parts += [
            Part(f"{side}_shoulder_pad", j(f"{side}_collar"), "capsule", (0.0, 0.0, 0.0),
                 tup(off[j(f"{side}_shoulder")]), radius_m=0.06 * s, material="shirt"),
            Part(f"{side}_upper_arm", j(f"{side}_shoulder"), "capsule", (0.0, 0.0, 0.0),
                 tup(off[j(f"{side}_elbow")]), radius_m=0.046 * s, material="shirt"),
            Part(f"{side}_forearm", j(f"{side}_elbow"), "capsule", (0.0, 0.0, 0.0),
                 tup(off[j(f"{side}_wrist")]), radius_m=0.037 * s, material="skin"),
            Part(f"{side}_hand", j(f"{side}_wrist"), "capsule", (0.0, 0.0, 0.0),
                 tup(off[j(f"{side}_hand")] + np.nan_to_num(end[j(f"{side}_hand")]) * 0.8),
                 radius_m=0.032 * s, material="skin"),
            Part(f"{side}_thigh", j(f"{side}_hip"), "capsule", (0.0, 0.0, 0.0), tup(off[j(f"{side}_knee")]),
                 radius_m=0.075 * s, material="trousers"),
            Part(f"{side}_shin", j(f"{side}_knee"), "capsule", (0.0, 0.0, 0.0), tup(off[j(f"{side}_ankle")]),
                 radius_m=0.055 * s, material="trousers"),
            Part(f"{side}_foot", j(f"{side}_ankle"), "capsule", v(-0.05, 0.0, -0.045),
                 tup(off[j(f"{side}_foot")]), radius_m=0.033 * s, material="shoes"),
            Part(f"{side}_toes", j(f"{side}_foot"), "capsule", (0.0, 0.0, 0.0),
                 tup(np.nan_to_num(end[j(f"{side}_foot")])), radius_m=0.03 * s, material="shoes"),
        ]
    return tuple(parts)


@dataclass(frozen=True)
class ActorHits:
    """Nearest actor hit per ray (N rays).

    t: (N,) float64 distance along the unit ray; inf for a miss.
    hit: (N,) bool.
    rgb: (N, 3) float32 shaded colour in [0, 1]; 0 for a miss.
    normal: (N, 3) float64 unit outward normal (world); 0 for a miss.
    part_id: (N,) int64 index into ``Actor.part_names``; -1 for a miss.
    """

    t: np.ndarray
    hit: np.ndarray
    rgb: np.ndarray
    normal: np.ndarray
    part_id: np.ndarray


@lru_cache(maxsize=32)
def _fabric(photo: str, rgb: tuple[float, float, float], contrast: float) -> np.ndarray:
    """A photo's luminance, normalised to mean 1, as ``rgb * (1 + contrast * (lum - 1))``: (H, W, 3) float32."""
    img = load_photo(photo)
    lum = img @ np.array([0.299, 0.587, 0.114], dtype=np.float32)
    lum = lum / max(float(lum.mean()), 1e-6)
    out = np.asarray(rgb, dtype=np.float32) * (1.0 + contrast * (lum[..., None] - 1.0))
    out = np.clip(out, 0.0, 1.0).astype(np.float32)
    out.setflags(write=False)
    return out


def _orthonormal_basis(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    axis = axis / np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(axis, e1)


def _ray_capsule(o: np.ndarray, d: np.ndarray, a: np.ndarray, b: np.ndarray, r: float) -> np.ndarray:
    """Entry distance ``(n,)`` of rays ``o, d (n, 3)`` (unit d) into the capsule; inf where missed or behind."""
    ba = b - a
    oa = o - a
    baba = float(ba @ ba)
    bard = d @ ba
    baoa = oa @ ba
    rdoa = np.einsum("ij,ij->i", d, oa)
    oaoa = np.einsum("ij,ij->i", oa, oa)
    qa = baba - bard * bard
    qb = baba * rdoa - baoa * bard
    qc = baba * oaoa - baoa * baoa - r * r * baba
    h = qb * qb - qa * qc
    t = np.full(o.shape[0], np.inf)
    ok = (h >= 0.0) & (qa > 1e-12)
    with np.errstate(invalid="ignore", divide="ignore"):
        t_cyl = (-qb - np.sqrt(np.where(ok, h, 0.0))) / np.where(ok, qa, 1.0)
    y = baoa + t_cyl * bard
    body = ok & (y > 0.0) & (y < baba) & (t_cyl >= 0.0)
    t = np.where(body, t_cyl, t)
    # end caps: the sphere at the end the ray approaches
    for centre in (a, b):
        oc = o - centre
        bq = np.einsum("ij,ij->i", oc, d)
        cq = np.einsum("ij,ij->i", oc, oc) - r * r
        hq = bq * bq - cq
        t_s = -bq - np.sqrt(np.maximum(hq, 0.0))
        cap = (hq >= 0.0) & (t_s >= 0.0) & (t_s < t)
        t = np.where(cap, t_s, t)
    return t


def _ray_ellipsoid(o: np.ndarray, d: np.ndarray, c: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """Entry distance ``(n,)`` of rays into the axis-aligned ellipsoid (centre ``c``, semi-axes); inf if missed."""
    o2 = (o - c) / axes
    d2 = d / axes
    qa = np.einsum("ij,ij->i", d2, d2)
    qb = np.einsum("ij,ij->i", o2, d2)
    qc = np.einsum("ij,ij->i", o2, o2) - 1.0
    h = qb * qb - qa * qc
    t = (-qb - np.sqrt(np.maximum(h, 0.0))) / qa
    return np.where((h >= 0.0) & (t >= 0.0), t, np.inf)


class Actor:
    """A textured person of height ``height_m`` with seeded appearance ``seed`` (see the module docstring).

    Attributes: ``skeleton`` (``nsim_skeleton(height_m)``), ``parts``, ``part_names``,
    ``appearance`` (the chosen colours and print).
    """

    def __init__(self, height_m: float = REFERENCE_HEIGHT_M, seed: int = 0) -> None:
        self.height_m = float(height_m)
        self.seed = int(seed)
        self.skeleton = nsim_skeleton(height_m)
        self.parts = actor_parts(self.skeleton)
        self.part_names = tuple(p.name for p in self.parts)
        rng = np.random.default_rng([self.seed, 7_001])
        pick = lambda options: options[int(rng.integers(len(options)))]  # noqa: E731
        self.appearance = {
            "skin": pick(SKIN_TONES), "shirt": pick(SHIRT_COLOURS), "trousers": pick(TROUSER_COLOURS),
            "shoes": pick(SHOE_COLOURS), "hair": pick(HAIR_COLOURS), "print": pick(PRINT_PHOTOS),
        }
        self._textures = {m: _fabric(_FABRIC_PHOTOS[m], tuple(self.appearance[m]), _FABRIC_CONTRAST[m])
                          for m in MATERIALS}
        self._print = load_photo(self.appearance["print"])
        self._offsets = rng.uniform(0.0, 1.0, size=(len(self.parts), 2))  # texture offsets per part (metres)
        # flat per-part arrays
        self._joint = np.array([p.joint for p in self.parts])
        self._kind = np.array([_CAPSULE if p.kind == "capsule" else _ELLIPSOID for p in self.parts])
        self._sphere = [p.bounding_sphere() for p in self.parts]
        self._basis = []
        for p in self.parts:
            if p.kind == "capsule":
                axis = np.asarray(p.b_m) - np.asarray(p.a_m)
                e1, e2 = _orthonormal_basis(axis if np.linalg.norm(axis) > 0 else np.array([0.0, 0.0, 1.0]))
                self._basis.append((axis, e1, e2))
            else:
                self._basis.append(None)

    def _check_pose(self, joint_transforms: np.ndarray) -> np.ndarray:
        T = np.asarray(joint_transforms, dtype=np.float64)
        if T.shape != (self.skeleton.num_joints, 4, 4) or not np.all(np.isfinite(T)):
            raise ValueError(f"Actor: joint_transforms: expected finite ({self.skeleton.num_joints}, 4, 4), "
                             f"got {T.shape}")
        return T

    def bounding_box(self, joint_transforms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World axis-aligned box ``lo, hi (3,)`` containing every part at this pose (from bounding spheres)."""
        T = self._check_pose(joint_transforms)
        centres = np.array([T[p.joint, :3, :3] @ c + T[p.joint, :3, 3] for p, (c, _) in zip(self.parts, self._sphere,
                                                                                             strict=True)])
        radii = np.array([r for _, r in self._sphere])[:, None]
        return (centres - radii).min(axis=0), (centres + radii).max(axis=0)

    def intersect(self, origins: np.ndarray, dirs: np.ndarray, joint_transforms: np.ndarray,
                  lighting: Lighting = DEFAULT_LIGHTING, lamp_xyz_m: np.ndarray | None = None) -> ActorHits:
        """Cast rays ``origins (N, 3)``, unit ``dirs (N, 3)`` (world) at the actor posed by ``joint_transforms (J, 4, 4)``.

        lamp_xyz_m: world position of the room's lamp (``Lighting.lamp_xyz_m(spec)``); None leaves the
        lamp term out (ambient and sun only). Returns ``ActorHits``.
        """
        o = np.asarray(origins, dtype=np.float64)
        d = np.asarray(dirs, dtype=np.float64)
        if o.ndim != 2 or o.shape[1] != 3 or d.shape != o.shape:
            raise ValueError(f"Actor.intersect: expected origins and dirs of shape (N, 3), got {o.shape}, {d.shape}")
        T = self._check_pose(joint_transforms)
        n = o.shape[0]
        t_best = np.full(n, np.inf)
        part_best = np.full(n, -1, dtype=np.int64)
        # cull: rays that miss the actor's box
        lo, hi = self.bounding_box(T)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / np.where(d == 0.0, 1e-300, d)
            t0, t1 = (lo - o) * inv, (hi - o) * inv
        t_near = np.minimum(t0, t1).max(axis=1)
        t_far = np.maximum(t0, t1).min(axis=1)
        cand = np.nonzero((t_near <= t_far) & (t_far >= 0.0))[0]
        if cand.size:
            oc, dc = o[cand], d[cand]
            tc = np.full(cand.size, np.inf)
            pc = np.full(cand.size, -1, dtype=np.int64)
            for k, part in enumerate(self.parts):
                R, p = T[part.joint, :3, :3], T[part.joint, :3, 3]
                centre, radius = self._sphere[k]
                w = (R @ centre + p) - oc
                proj = np.einsum("ij,ij->i", w, dc)
                near = np.nonzero((np.einsum("ij,ij->i", w, w) - proj * proj <= radius * radius) & (proj > -radius))[0]
                if near.size == 0:
                    continue
                ol = (oc[near] - p) @ R  # R^T (o - p), row-wise
                dl = dc[near] @ R
                if part.kind == "capsule":
                    t = _ray_capsule(ol, dl, np.asarray(part.a_m), np.asarray(part.b_m), part.radius_m)
                else:
                    t = _ray_ellipsoid(ol, dl, np.asarray(part.a_m), np.asarray(part.axes_m))
                better = t < tc[near]
                tc[near[better]] = t[better]
                pc[near[better]] = k
            t_best[cand] = tc
            part_best[cand] = pc
        hit = part_best >= 0
        rgb = np.zeros((n, 3), dtype=np.float32)
        normal = np.zeros((n, 3))
        for k in np.unique(part_best[hit]):
            idx = np.nonzero(part_best == k)[0]
            part = self.parts[k]
            R, p = T[part.joint, :3, :3], T[part.joint, :3, 3]
            pw = o[idx] + t_best[idx, None] * d[idx]
            pl = (pw - p) @ R
            nl, albedo = self._surface(k, pl)
            nw = nl @ R.T
            normal[idx] = nw
            rgb[idx] = albedo * _shade(pw, nw, lighting, lamp_xyz_m)[:, None]
        np.clip(rgb, 0.0, 1.0, out=rgb)
        return ActorHits(t=t_best, hit=hit, rgb=rgb, normal=normal, part_id=part_best)

    def _surface(self, k: int, pl: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Local unit normals ``(n, 3)`` and albedo ``(n, 3)`` float32 of part ``k`` at local points ``pl (n, 3)``."""
        part = self.parts[k]
        tex = self._textures[part.material]
        mpt = _METRES_PER_TEXEL[part.material]
        off = self._offsets[k]
        if part.kind == "capsule":
            a = np.asarray(part.a_m)
            axis, e1, e2 = self._basis[k]
            L2 = float(axis @ axis)
            along = np.clip(((pl - a) @ axis) / max(L2, 1e-12), 0.0, 1.0)
            foot = a + along[:, None] * axis
            nrm = pl - foot
            nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
            rel = pl - a
            angle = np.arctan2(rel @ e2, rel @ e1)
            uv = np.stack([angle * part.radius_m, (rel @ axis) / np.sqrt(max(L2, 1e-12))], axis=1)
        else:
            c, ax = np.asarray(part.a_m), np.asarray(part.axes_m)
            q = (pl - c) / ax
            nrm = q / ax
            nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
            angle = np.arctan2(q[:, 1], q[:, 0])
            uv = np.stack([angle * 0.5 * (ax[0] + ax[1]), -(pl[:, 2] - c[2])], axis=1)
        albedo = sample_texture(tex, uv + off, mpt, mode="wrap")
        if part.name == "chest":
            albedo = self._chest_print(pl - np.asarray(part.a_m), np.asarray(part.axes_m), albedo)
        elif part.name == "head":
            albedo = self._face(pl, np.asarray(part.a_m), np.asarray(part.axes_m), albedo)
        return nrm, albedo

    def _chest_print(self, rel: np.ndarray, axes: np.ndarray, albedo: np.ndarray) -> np.ndarray:
        """The printed photo on the front of the chest (local +x side), framed by a thin white border."""
        half_w, half_h, z0 = 0.55 * axes[1], 0.38 * axes[2], 0.05 * axes[2]
        y, z = rel[:, 1], rel[:, 2] - z0
        front = rel[:, 0] > 0.3 * axes[0]
        inside = front & (np.abs(y) < half_w) & (np.abs(z) < half_h)
        if not inside.any():
            return albedo
        img = self._print
        h, w = img.shape[:2]
        # the photo fills the print area (aspect cropped to the centre), seen upright from the front
        side = min(w / (2 * half_w), h / (2 * half_h))  # texels per metre
        mpt = 1.0 / side
        uv = np.stack([(half_w - y) * side + (w - 2 * half_w * side) / 2,
                       (half_h - z) * side + (h - 2 * half_h * side) / 2], axis=1) * mpt
        photo = sample_texture(img, uv[inside], mpt, mode="clamp")
        border = (np.abs(y[inside]) > half_w - 0.008) | (np.abs(z[inside]) > half_h - 0.008)
        photo[border] = 0.95
        out = albedo.copy()
        out[inside] = photo
        return out

    def _face(self, pl: np.ndarray, c: np.ndarray, axes: np.ndarray, albedo: np.ndarray) -> np.ndarray:
        """Eyes, brows and mouth on the front of the head (local +x), hair on the top and back."""
        q = (pl - c) / axes  # on the unit sphere
        out = albedo.copy()
        hair_rgb = self._textures["hair"]
        hair = (q[:, 2] > 0.45) | ((q[:, 0] < 0.15) & (q[:, 2] > -0.35))
        if hair.any():
            uv = np.stack([np.arctan2(q[hair, 1], q[hair, 0]) * axes[0], -pl[hair, 2]], axis=1)
            out[hair] = sample_texture(hair_rgb, uv, _METRES_PER_TEXEL["hair"], mode="wrap")
        front = q[:, 0] > 0.55
        for sy in (1.0, -1.0):
            dy, dz = q[:, 1] - 0.36 * sy, q[:, 2] - 0.12
            r2 = (dy / 0.15) ** 2 + (dz / 0.08) ** 2
            out[front & (r2 < 1.0)] = (0.95, 0.95, 0.93)  # white of the eye
            out[front & ((dy / 0.07) ** 2 + (dz / 0.07) ** 2 < 1.0)] = (0.18, 0.11, 0.06)  # iris
            brow = front & (np.abs(dy) < 0.17) & (np.abs(q[:, 2] - 0.3) < 0.035)
            out[brow] = np.asarray(self.appearance["hair"], dtype=np.float32) * 0.8
        mouth = front & (np.abs(q[:, 1]) < 0.24) & (np.abs(q[:, 2] + 0.42) < 0.045)
        out[mouth] = (0.62, 0.25, 0.24)
        return out


def _shade(points: np.ndarray, normals: np.ndarray, lighting: Lighting, lamp_xyz_m: np.ndarray | None) -> np.ndarray:
    """The room's Lambertian shading term ``(n,)`` float32 (see ``nsim.synth.raycast.Lighting``)."""
    sun = np.asarray(lighting.sun_dir_xyz, dtype=np.float64)
    sun = sun / np.linalg.norm(sun)
    shade = lighting.ambient + lighting.sun_intensity * np.maximum(normals @ sun, 0.0)
    if lamp_xyz_m is not None:
        to_lamp = np.asarray(lamp_xyz_m, dtype=np.float64) - points
        r2 = np.einsum("ij,ij->i", to_lamp, to_lamp)
        n_dot_l = np.einsum("ij,ij->i", to_lamp, normals) / np.sqrt(np.maximum(r2, 1e-12))
        shade = shade + lighting.lamp_intensity * np.maximum(n_dot_l, 0.0) / (1.0 + r2 / lighting.lamp_falloff_m**2)
    return shade.astype(np.float32)


@dataclass(frozen=True)
class Composite:
    """Room and actors merged per ray (N rays).

    t: (N,) nearest distance (room or actor); rgb: (N, 3) float32;
    actor_index: (N,) int64 index into the ``hits`` sequence of the actor seen, -1 where the room is;
    part_id: (N,) int64 part of that actor, -1 where the room is.
    """

    t: np.ndarray
    rgb: np.ndarray
    actor_index: np.ndarray
    part_id: np.ndarray


def composite_actors(room_t: np.ndarray, room_rgb: np.ndarray, hits: Sequence[ActorHits]) -> Composite:
    """Merge actor hits into room rays: per ray, the nearest of the room and every actor wins.

    room_t: (N,) distances along the same unit rays (``RayHits.t``; inf or NaN for none);
    room_rgb: (N, 3); hits: one ``ActorHits`` per actor, cast on the same rays.
    The person mask of actor ``i`` is ``actor_index == i``.
    """
    t = np.where(np.isnan(room_t), np.inf, np.asarray(room_t, dtype=np.float64)).copy()
    rgb = np.array(room_rgb, dtype=np.float32, copy=True)
    actor = np.full(t.shape, -1, dtype=np.int64)
    part = np.full(t.shape, -1, dtype=np.int64)
    for i, h in enumerate(hits):
        closer = h.hit & (h.t < t)
        t[closer] = h.t[closer]
        rgb[closer] = h.rgb[closer]
        actor[closer] = i
        part[closer] = h.part_id[closer]
    t = np.where(np.isinf(t) & np.isnan(room_t), np.nan, t)
    return Composite(t=t, rgb=rgb, actor_index=actor, part_id=part)
