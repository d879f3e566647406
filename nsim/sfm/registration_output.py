"""A robot recording's registration into a scene's frame, as files: ``registration.json`` (the
odometry-to-world transform, clock offset, per-frame localisation and residuals, the rules),
the world trajectory (TUM + integer-nanosecond stamps) and a labelled preview
(``nsim register-log``'s artifact; the stage localises, registers and calls these). ``inputs``,
``cfg`` and ``plan``: the stage's inputs, config and checked plan (read for their fields).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np


def _stats(fit) -> dict[str, Any]:
    return {"median_m": _num(fit.median_m), "rms_m": _num(fit.rms_m), "median_deg": _num(fit.median_deg),
            "rms_deg": _num(fit.rms_deg), "inliers": fit.num_inliers, "used": int(fit.used.sum())}


def write_registration(out_dir: Path, inputs, cfg, plan, records: list[dict], reg,
                       body_to_world: np.ndarray, poses_path: Path) -> dict[str, Any]:
    """Write the artifact's files (module docstring); returns registration.json's content."""
    from nsim.config import to_dict
    from nsim.io.canonical import canonical_floats
    from nsim.io.tum import Trajectory, write_tum

    np.save(out_dir / "trajectory_world_ns.npy", plan.traj_ns.astype(np.int64), allow_pickle=False)
    write_tum(out_dir / "trajectory_world.tum", Trajectory.from_poses(plan.traj_ns / 1e9, body_to_world))
    ref = reg.refined
    final = ref if ref is not None else reg
    rigid = {"odom_to_world": reg.odom_to_world.tolist(), "scale": reg.scale, "clock_offset_s": reg.clock_offset_s,
             "clock_offset_std_s": _num(reg.clock_offset_std_s), **_stats(reg)}
    frames, k = [], 0
    for r in records:
        loc, f = r["loc"], {"camera": r["camera"], "index": r["index"], "stamp_ns": r["stamp_ns"],
                            "localised": r["loc"] is not None}
        if loc is not None:
            f |= {"inliers": loc.num_inliers, "matches": loc.num_matches, "reprojection_error_px": loc.median_error_px,
                  "cam_to_world": loc.cam_to_world.tolist(), "used": bool(reg.used[k]),
                  "rigid": {"residual_m": _num(reg.residual_m[k]), "residual_deg": _num(reg.residual_deg[k]),
                            "inlier": bool(reg.inliers[k])}}
            if ref is not None:
                f["refined"] = {"residual_m": _num(ref.residual_m[k]), "residual_deg": _num(ref.residual_deg[k]),
                                "inlier": bool(ref.inliers[k])}
            k += 1
        frames.append(f)
    doc: dict[str, Any] = {
        "format": 1,
        "inputs": inputs.ids(),
        "world": "the poses artifact's scene world (metres, z up)",
        "odom_frame": plan.doc.get("odom_frame"), "body_frame": plan.doc.get("body_frame"),
        "odom_to_world": (ref.odom_to_world if ref is not None else reg.odom_to_world).tolist(),
        "odom_to_world_meaning": "maps odometry-frame points to world points; body_to_world = odom_to_world @ "
                                 "body_to_odom at the first pose (the refined trajectory's drift is zero there)",
        "scale": reg.scale,
        "clock_offset_s": final.clock_offset_s, "clock_offset_std_s": _num(final.clock_offset_std_s),
        "clock_offset_meaning": "camera stamp minus odometry time of capture",
        "residual": _stats(final),
        "rigid": rigid,
        "refined": None if ref is None else {
            "odom_to_world_std_m": _num(ref.odom_to_world_std_m), "odom_to_world_std_deg": _num(ref.odom_to_world_std_deg),
            "scale_error": ref.scale_error, "yaw_bias_deg_per_m": ref.yaw_bias_deg_per_m,
            "max_drift_m": float(ref.drift_m.max()), "max_drift_deg": float(ref.drift_deg.max()),
            "nodes": len(ref.nodes), "rounds": ref.rounds},
        "trajectory": {"file": "trajectory_world.tum", "stamps": "trajectory_world_ns.npy", "poses": len(plan.traj_ns),
                       "source": "refined" if ref is not None else "rigid",
                       "meaning": "body_to_world at the recording's odometry stamps"},
        "localised": {"tried": len(records), "localised": sum(r["loc"] is not None for r in records),
                      "per_camera": {c: {"tried": sum(r["camera"] == c for r in records),
                                         "localised": sum(r["camera"] == c and r["loc"] is not None for r in records)}
                                     for c in plan.cameras}},
        "frames": frames,
        "options": to_dict(cfg),
    }
    # numbers to 10 significant digits, no -0 (nsim.io.canonical): the same bytes from another CPU's last bits
    doc = canonical_floats(doc)
    (out_dir / "registration.json").write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n")
    write_preview(out_dir / "preview.png", poses_path, plan, records, reg, body_to_world, cfg.preview_max_points)
    return doc


def _num(x: float) -> float | None:
    """JSON has no NaN or inf: those become null."""
    return float(x) if math.isfinite(x) else None


def write_preview(path: Path, poses_path: Path, plan, records: list[dict], reg, body_to_world: np.ndarray,
                  max_points: int) -> None:
    """Top view (sparse points, trajectories, localised centres by residual), residual histogram, drift."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import pycolmap

    from nsim.sfm.colmap import colmap_log_level

    with colmap_log_level():
        model = pycolmap.Reconstruction(poses_path / "sparse")
    xyz = np.array([p.xyz for p in model.points3D.values()], dtype=np.float64).reshape(-1, 3)
    rgb = np.array([p.color for p in model.points3D.values()], dtype=np.float64).reshape(-1, 3) / 255.0
    if len(xyz) > max_points:
        keep = np.linspace(0, len(xyz) - 1, max_points).astype(np.int64)
        xyz, rgb = xyz[keep], rgb[keep]
    final = reg.refined if reg.refined is not None else reg
    ok = [r for r in records if r["loc"] is not None]
    centres = np.array([r["loc"].cam_to_world[:3, 3] for r in ok]).reshape(-1, 3)
    res_cm = final.residual_m * 100.0
    fig, axes = plt.subplots(1, 3, figsize=(15, 5), gridspec_kw={"width_ratios": [2, 1, 1]})
    ax = axes[0]
    ax.scatter(xyz[:, 0], xyz[:, 1], s=2, c=rgb, alpha=0.6, linewidths=0)
    rigid = reg.to_world(plan.body_to_odom)
    ax.plot(rigid[:, 0, 3], rigid[:, 1, 3], "--", color="0.4", lw=1, label="odometry, rigid fit")
    if reg.refined is not None:
        ax.plot(body_to_world[:, 0, 3], body_to_world[:, 1, 3], "-", color="k", lw=1.2, label="odometry, refined")
    inl = final.inliers
    sc = ax.scatter(centres[inl, 0], centres[inl, 1], c=res_cm[inl], s=14, cmap="viridis", label="localised (inlier)")
    ax.scatter(centres[~inl, 0], centres[~inl, 1], c="r", marker="x", s=14, label="localised (outlier or unused)")
    ax.plot(*body_to_world[0, :2, 3], "k^", label="start")
    fig.colorbar(sc, ax=ax, label="camera residual (cm)", fraction=0.046)
    # the view: the run and the bulk of the points (a few stray points would shrink everything else)
    span = np.concatenate([np.percentile(xyz[:, :2], [1, 99], axis=0) if len(xyz) else np.zeros((0, 2)),
                           body_to_world[:, :2, 3], rigid[:, :2, 3]])
    lo, hi = span.min(axis=0) - 0.5, span.max(axis=0) + 0.5
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x (m, scene world)")
    ax.set_ylabel("y (m, scene world)")
    ax.legend(fontsize=7, loc="best")
    ax.set_title(f"{len(ok)}/{len(records)} frames localised; residual median {final.median_m * 100:.1f} cm / "
                 f"{final.median_deg:.2f} deg\nclock offset {final.clock_offset_s * 1000:.1f} ms", fontsize=9)
    ax = axes[1]
    used = np.isfinite(res_cm)
    bins = np.linspace(0.0, max(float(np.nanmax(res_cm)) if used.any() else 1.0, 1e-3), 30)
    ax.hist([res_cm[inl], res_cm[used & ~inl]], bins=bins, stacked=True, color=["C0", "C3"],
            label=["inliers", "outliers"])
    ax.set_xlabel("camera centre residual (cm)")
    ax.set_ylabel("frames")
    ax.legend(fontsize=8)
    ax.set_title("residuals" + (" after the drift refinement" if reg.refined is not None else ""), fontsize=9)
    ax = axes[2]
    t = (plan.traj_ns - plan.traj_ns[0]) / 1e9
    if reg.refined is not None:
        ax.plot(t, reg.refined.drift_m * 100.0, label="position (cm)")
        ax.plot(t, reg.refined.drift_deg, label="heading and tilt (deg)")
        ax.legend(fontsize=8)
        ax.set_title("drift taken up: refined minus rigid", fontsize=9)
    else:
        ax.set_title("no drift refinement", fontsize=9)
    ax.set_xlabel("odometry time (s)")
    fig.tight_layout()
    fig.savefig(path, dpi=80, metadata={"Software": None})
    plt.close(fig)


