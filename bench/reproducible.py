"""Which artifacts repeat bit for bit across CPU code paths, and how close the others come.

    python bench/reproducible.py [--quick] [--paths NAME,...] [--workdir DIR] [--keep]

Runs the tiny demo (``pipelines/demo.py --preset tiny``) once on this machine's native code path, then,
for every other code path, twice more:

* **end to end**: the whole tiny demo from nothing under that code path, in a fresh workspace; its refs
  (``capture/demo-pinhole``, ``scene/demo``, ...) are compared with the native run's ids. This is what a
  cluster node of another CPU model does: does the run cache hit, do the ids a CI check compares repeat?
* **stage by stage**: ``nsim verify --rebuild --json`` over a copy of the native workspace under that code
  path: each artifact's stage reruns from the *same* inputs, so a stage is judged on its own, not on the
  upstream artifacts it was given. Rebuilds that differ are compared file by file against the per-kind
  tolerances of ``nsim.workspace.compare`` (PSNR of images, depth and pose differences, metric deltas).

The native workspace is also rebuilt under the native code path (determinism on one machine) and the
demo's robot log (``capture robot-log``, a bag outside the workspace) is compared byte for byte.

A code path is a set of environment variables read at start-up (torch's ``ATEN_CPU_CAPABILITY``, numpy's
``NPY_DISABLE_CPU_FEATURES``, ``OMP_NUM_THREADS``) and calls made before the demo starts
(``cv2.setUseOptimized(False)``, ``torch.set_num_threads(1)``); what each process actually ran is read
back from the libraries themselves and printed (``code_paths``).

Prints a table, then one JSON object as the last line with keys ``stages`` (per stage: ``identical``, from
the same inputs under every code path; ``end_to_end_identical``; ``within_tolerance``; ``per_path``),
``bit_stable_share`` (the share of the stages that do not train whose rebuilds are identical under every
code path), ``rebuild_within_tolerance`` (every training stage's rebuild within tolerance),
``code_paths`` and ``ids`` (the native run's ids by ref). ``--quick`` runs three code paths: native,
``aten-default`` and ``numpy-baseline+opencv-unoptimized+one-thread``; the full run adds each of those
separately and all of them at once (about 4.5 minutes per code path on 2 cores).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from nsim.stages import bit_stable_stages  # noqa: E402

# numpy's dispatched SIMD groups above its x86-64 baseline (numpy >= 2.4 names; older numpy: its own names)
_NPY_GROUPS = ("AVX512_SPR", "AVX512_ICL", "X86_V4", "X86_V3", "AVX512_SKX", "AVX512_CLX", "AVX512_CNL", "AVX512F",
               "AVX512CD", "AVX2", "FMA3", "F16C", "AVX")

PROBE = r"""
import json, os, sys
out = {}
try:
    import numpy, numpy._core._multiarray_umath as um
    out["numpy_simd"] = sorted(k for k, v in um.__cpu_features__.items() if v and k in um.__cpu_dispatch__)
except Exception as e:  # older numpy layouts
    out["numpy_simd"] = f"unknown ({e})"
import torch
out["torch_cpu_capability"] = torch.backends.cpu.get_cpu_capability()
out["torch_threads"] = torch.get_num_threads()
import cv2
out["opencv_optimized"] = bool(cv2.useOptimized())
out["opencv_threads"] = cv2.getNumThreads()
print("PROBE" + json.dumps(out))
"""


def numpy_disable_list() -> str:
    """The dispatched SIMD groups this numpy knows and this CPU has (numpy refuses names it does not know)."""
    code = ("import numpy._core._multiarray_umath as um;"
            "print(' '.join(k for k in um.__cpu_dispatch__ if um.__cpu_features__.get(k)))")
    try:
        have = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    except subprocess.CalledProcessError:
        have = []
    return " ".join(g for g in _NPY_GROUPS if g in have) or " ".join(have)


def code_paths(quick: bool) -> dict[str, dict]:
    npy = numpy_disable_list()
    single = {"env": {"ATEN_CPU_CAPABILITY": "default"}}
    numpy_base = {"env": {"NPY_DISABLE_CPU_FEATURES": npy}} if npy else {"env": {}}
    cv_off = {"prelude": "import cv2; cv2.setUseOptimized(False)"}
    one = {"env": {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"},
           "prelude": "import torch, cv2; torch.set_num_threads(1); cv2.setNumThreads(1)"}

    def merge(*parts: dict) -> dict:
        return {"env": {k: v for p in parts for k, v in p.get("env", {}).items()},
                "prelude": "; ".join(p["prelude"] for p in parts if p.get("prelude"))}

    paths = {"native": {"env": {}, "prelude": ""}, "aten-default": merge(single)}
    if quick:
        paths["numpy-baseline+opencv-unoptimized+one-thread"] = merge(numpy_base, cv_off, one)
        return paths
    paths.update({"numpy-baseline": merge(numpy_base), "opencv-unoptimized": merge(cv_off), "one-thread": merge(one),
                  "all": merge(single, numpy_base, cv_off, one)})
    return paths


def python_cmd(prelude: str, script: str, args: list[str]) -> list[str]:
    code = (f"import sys; sys.argv = {[script, *args]!r}; sys.path.insert(0, {str(REPO)!r})\n"
            + (prelude + "\n" if prelude else "")
            + f"import runpy; runpy.run_path({script!r}, run_name='__main__')")
    return [sys.executable, "-c", code]


def run_under(path: dict, script: str, args: list[str], log: Path) -> tuple[int, float]:
    env = {k: v for k, v in os.environ.items() if k not in ("ATEN_CPU_CAPABILITY", "NPY_DISABLE_CPU_FEATURES")}
    env.update(path.get("env", {}))
    env["PYTHONPATH"] = str(REPO)
    t0 = time.perf_counter()
    with open(log, "w") as f:
        code = subprocess.run(python_cmd(path.get("prelude", ""), script, args), env=env, stdout=f,
                              stderr=subprocess.STDOUT, cwd=REPO).returncode
    return code, time.perf_counter() - t0


def probe(path: dict, log: Path) -> dict:
    script = log.with_suffix(".probe.py")
    script.write_text(PROBE)
    run_under(path, str(script), [], log)
    line = next((ln for ln in log.read_text().splitlines() if ln.startswith("PROBE")), None)
    return json.loads(line[5:]) if line else {"error": log.read_text()[-500:]}


def refs_of(ws: Path) -> dict[str, str]:
    from nsim.workspace.store import Store

    return {name: art for name, art in Store(ws, create=False).refs().items() if not name.endswith("/latest")}


def stages_of(ws: Path, refs: dict[str, str]) -> dict[str, str]:
    """ref -> the stage that made its artifact."""
    from nsim.workspace.store import Store

    store = Store(ws, create=False)
    return {r: store.get(i).manifest["stage"] for r, i in refs.items()}


def bag_digests(ws: Path) -> dict[str, str]:
    from nsim.workspace.store import sha256_path

    root = ws / "robot_logs"
    return {p.name: sha256_path(p) for p in sorted(root.iterdir())} if root.is_dir() else {}


def summarise(ids: dict[str, str], stage_by_ref: dict[str, str], iso: dict[str, list[dict]],
              e2e: dict[str, dict[str, bool]], bags: dict[str, dict[str, str]]) -> dict:
    """Per stage: identical from the same inputs under every code path (the rebuilds), identical end to end
    (the whole demo under each code path), rebuilds within tolerance; and the shares the issue asks for."""
    stable = bit_stable_stages()
    stages: dict[str, dict] = {}
    order = list(dict.fromkeys(stage_by_ref[r] for r in ids))
    for stage in order:
        refs = [r for r in ids if stage_by_ref[r] == stage]
        arts = {ids[r] for r in refs}
        per_path = {}
        for name, report in iso.items():
            rows = [a for a in report if a["id"] in arts]
            worst = [f"{a['id'][:12]} {a.get('error') or a.get('worst') or ''}".strip() for a in rows
                     if not a.get("identical")]
            per_path[name] = {"identical": bool(rows) and all(a.get("identical") for a in rows),
                              "within_tolerance": bool(rows) and all(a.get("identical") or a.get("within_tolerance")
                                                                     for a in rows),
                              "end_to_end_identical": all(e2e[name][r] for r in refs) if name in e2e else None,
                              "worst": "; ".join(worst)}
        stages[stage] = {
            "bit_stable_expected": stable.get(stage),
            "identical": all(p["identical"] for p in per_path.values()),
            "end_to_end_identical": all(p["end_to_end_identical"] for p in per_path.values()
                                        if p["end_to_end_identical"] is not None),
            "within_tolerance": all(p["within_tolerance"] for p in per_path.values()),
            "refs": refs,
            "per_path": per_path,
        }
    native_bags = bags.get("native", {})
    same_bags = {n: b == native_bags for n, b in bags.items()}  # the bag is made end to end, never rebuilt
    stages["capture robot-log"] = {
        "bit_stable_expected": True,
        "identical": all(same_bags.values()),
        "end_to_end_identical": all(same_bags.values()),
        "within_tolerance": all(same_bags.values()),
        "refs": sorted(native_bags),
        "per_path": {n: {"identical": same} for n, same in same_bags.items()},
    }
    non_training = [s for s, row in stages.items() if row["bit_stable_expected"]]
    training = [s for s, row in stages.items() if row["bit_stable_expected"] is False]
    identical = [s for s in non_training if stages[s]["identical"]]
    return {
        "stages": stages,
        "bit_stable_stages": identical,
        "bit_stable_share": round(len(identical) / max(1, len(non_training)), 3),
        "rebuild_within_tolerance": all(stages[s]["within_tolerance"] for s in training),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="three code paths (native, aten-default, the rest at once)")
    ap.add_argument("--paths", default=None, help="comma-separated code paths to run (default: by --quick)")
    ap.add_argument("--workdir", type=Path, default=None, help="where the workspaces go (default: a temp dir)")
    ap.add_argument("--keep", action="store_true", help="keep the workspaces")
    args = ap.parse_args()

    paths = code_paths(args.quick)
    if args.paths:
        wanted = ["native", *[p for p in args.paths.split(",") if p != "native"]]
        full = code_paths(False) | code_paths(True)
        unknown = [p for p in wanted if p not in full]
        if unknown:
            print(f"error: --paths: unknown code path(s) {', '.join(unknown)} (known: {', '.join(full)})",
                  file=sys.stderr)
            return 2
        paths = {p: full[p] for p in wanted}
    work = args.workdir or Path(tempfile.mkdtemp(prefix="nsim-repro-"))
    work.mkdir(parents=True, exist_ok=True)
    demo = str(REPO / "pipelines" / "demo.py")
    cli = str(REPO / "nsim" / "cli.py")
    t_start = time.perf_counter()

    probes, e2e, iso, seconds = {}, {}, {}, {}
    native_ws = work / "native"
    ids: dict[str, str] = {}
    stage_by_ref: dict[str, str] = {}
    bags: dict[str, dict[str, str]] = {}
    for name, path in paths.items():
        tag = name.replace("+", "_")
        probes[name] = probe(path, work / f"{tag}.probe.log")
        ws = work / tag
        if ws.exists():
            shutil.rmtree(ws, ignore_errors=True)
        code, secs = run_under(path, demo, ["--preset", "tiny", "--workspace", str(ws)], work / f"{tag}.demo.log")
        seconds[f"{name} demo"] = round(secs, 1)
        print(f"[repro] {name:<48} tiny demo {secs:6.1f} s (exit {code})", flush=True)
        if code != 0:
            print((work / f"{tag}.demo.log").read_text()[-3000:], file=sys.stderr)
            return 1
        refs = refs_of(ws)
        bags[name] = bag_digests(ws)
        if name == "native":
            ids = refs
            stage_by_ref = stages_of(ws, refs)
        else:
            e2e[name] = {r: refs.get(r) == i for r, i in ids.items()}
        # stage by stage: every artifact of the native run rebuilt from its own inputs under this code path
        copy = work / f"{tag}.rebuild"
        if copy.exists():
            shutil.rmtree(copy, ignore_errors=True)
        shutil.copytree(native_ws, copy, symlinks=True)
        report = work / f"{tag}.rebuild.json"
        code, secs = run_under(path, cli, ["--workspace", str(copy), "--no-progress", "verify", "--rebuild",
                                           "--json", str(report), *sorted(set(ids.values()))],
                               work / f"{tag}.rebuild.log")
        seconds[f"{name} rebuild"] = round(secs, 1)
        print(f"[repro] {name:<48} rebuild   {secs:6.1f} s (exit {code})", flush=True)
        if not report.is_file():
            print((work / f"{tag}.rebuild.log").read_text()[-3000:], file=sys.stderr)
            return 1
        iso[name] = json.loads(report.read_text())["artifacts"]
        if not args.keep and name != "native":
            shutil.rmtree(copy, ignore_errors=True)

    result = summarise(ids, stage_by_ref, iso, e2e, bags)
    result["code_paths"] = {n: {"env": p.get("env", {}), "calls": p.get("prelude", ""), "read_back": probes[n]}
                            for n, p in paths.items()}
    result["ids"] = ids
    result["seconds"] = seconds
    result["wall_s"] = round(time.perf_counter() - t_start, 1)

    print()
    print(f"{'stage':<16} {'identical':>9} {'end to end':>10} {'within tol':>10}  worst difference")
    for stage, row in result["stages"].items():
        worst = "; ".join(f"{p}: {v['worst']}" for p, v in row["per_path"].items() if v.get("worst"))
        print(f"{stage:<16} {str(row['identical']):>9} {str(row['end_to_end_identical']):>10} "
              f"{str(row['within_tolerance']):>10}  {worst[:140]}")
    print(f"bit-stable share of the stages that do not train: {result['bit_stable_share']:.2f} "
          f"({', '.join(result['bit_stable_stages'])}); stages that train (judged by tolerance): "
          f"{', '.join(s for s, st in bit_stable_stages().items() if not st)}")
    if not args.keep and args.workdir is None:
        shutil.rmtree(work, ignore_errors=True)
    print(json.dumps(result, sort_keys=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
