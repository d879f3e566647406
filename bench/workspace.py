"""Workspace throughput: publish and verify in MB/s, and the latency of a cache hit.

    python bench/workspace.py [--quick]

Publishes artifacts of random bytes (a few large files, as a checkpoint, and many small
ones, as rendered frames) into a fresh workspace, re-hashes them with verify, and times
the action-key lookup of a repeated action. Prints a table, then one JSON object.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from nsim.workspace.store import Store  # noqa: E402


def publish(store: Store, name: str, files: dict[str, bytes]) -> tuple[str, float]:
    key = store.action_key("bench", 1, {"name": name})
    t0 = time.perf_counter()
    with store.publish(kind="render", stage="bench", version=1, key=key, config={"name": name}) as out:
        for rel, data in files.items():
            p = out.dir / rel
            p.parent.mkdir(parents=True, exist_ok=True)
            p.write_bytes(data)
    return out.artifact.id, time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="tiny sizes (seconds)")
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    big_mb, n_big, n_small, small_kb = (4, 2, 200, 16) if args.quick else (64, 4, 2000, 64)
    shapes = {
        "large files": {f"weights_{i}.bin": rng.bytes(big_mb << 20) for i in range(n_big)},
        "small files": {f"frames/{i:05d}.png": rng.bytes(small_kb << 10) for i in range(n_small)},
    }
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        store = Store(Path(tmp) / "ws")
        for label, files in shapes.items():
            mb = sum(len(v) for v in files.values()) / 2**20
            art_id, t_pub = publish(store, label, files)
            t0 = time.perf_counter()
            assert store.verify(art_id) == []
            t_ver = time.perf_counter() - t0
            results[label] = {"mb": round(mb, 1), "files": len(files), "publish_mb_s": mb / t_pub, "verify_mb_s": mb / t_ver}
        key = store.action_key("bench", 1, {"name": "large files"})
        lat = []
        for _ in range(200 if args.quick else 2000):
            t0 = time.perf_counter()
            hit = store.lookup(key)
            lat.append(time.perf_counter() - t0)
            assert hit is not None
        # the full path a stage takes on a hit: key digest + lookup
        full = []
        for _ in range(200 if args.quick else 2000):
            t0 = time.perf_counter()
            store.lookup(store.action_key("bench", 1, {"name": "large files"}))
            full.append(time.perf_counter() - t0)
    print(f"{'shape':<12} {'MB':>7} {'files':>6} {'publish MB/s':>13} {'verify MB/s':>12}")
    for label, r in results.items():
        print(f"{label:<12} {r['mb']:>7.1f} {r['files']:>6} {r['publish_mb_s']:>13.1f} {r['verify_mb_s']:>12.1f}")
    med_us = statistics.median(lat) * 1e6
    full_us = statistics.median(full) * 1e6
    print(f"cache-hit lookup: median {med_us:.0f} us; key digest + lookup: median {full_us:.0f} us")
    out = {
        "bench": "workspace",
        "quick": args.quick,
        "publish_mb_s_large": round(results["large files"]["publish_mb_s"], 1),
        "verify_mb_s_large": round(results["large files"]["verify_mb_s"], 1),
        "publish_mb_s_small": round(results["small files"]["publish_mb_s"], 1),
        "verify_mb_s_small": round(results["small files"]["verify_mb_s"], 1),
        "cache_hit_lookup_us": round(med_us, 1),
        "cache_hit_key_and_lookup_us": round(full_us, 1),
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
