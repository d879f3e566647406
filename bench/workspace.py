"""Workspace throughput (publish and verify in MB/s, cache-hit latency) and a kill soak.

    python bench/workspace.py [--quick] [--soak SECONDS] [--workspace DIR]

Throughput: publishes artifacts of random bytes (a few large files, as a checkpoint, and many
small ones, as rendered frames) into a fresh workspace, re-hashes them with verify, and times
the action-key lookup of a repeated action.

Soak (``--soak SECONDS``; ``--quick`` runs a 10 s one): 8 worker processes publish small
artifacts (content drawn from a small pool, so writers collide and hit the run cache), tag,
delete refs, read with checked ``Store.get`` and now and then run the CLI (``capture synth``,
``ls``, ``verify``, ``tag``), while one process loops ``gc --grace 0`` and the main process
SIGKILLs a random worker or the gc every 0.5-2 s and restarts it. Each worker logs every
finished operation (fsync'd) before going on. At the end one last gc runs and every ref whose
last logged state is known must name a whole object (else ``lost``); objects a ref reaches
must verify, no ref may be broken and a sample of logged publishes must republish to the
logged id (else ``unrecoverable``).

Prints a table, then one JSON object as the last line.
"""

from __future__ import annotations

import argparse
import contextlib
import fcntl
import hashlib
import json
import os
import random
import re
import resource
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import traceback
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from nsim.errors import NsimError, WorkspaceError  # noqa: E402
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


def throughput(quick: bool) -> dict:
    """Publish/verify MB/s and cache-hit latency; prints its table, returns the JSON fields."""
    rng = np.random.default_rng(0)
    big_mb, n_big, n_small, small_kb = (4, 2, 200, 16) if quick else (64, 4, 2000, 64)
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
        for _ in range(200 if quick else 2000):
            t0 = time.perf_counter()
            hit = store.lookup(key)
            lat.append(time.perf_counter() - t0)
            assert hit is not None
        # the full path a stage takes on a hit: key digest + lookup
        full = []
        for _ in range(200 if quick else 2000):
            t0 = time.perf_counter()
            store.lookup(store.action_key("bench", 1, {"name": "large files"}))
            full.append(time.perf_counter() - t0)
    print(f"{'shape':<12} {'MB':>7} {'files':>6} {'publish MB/s':>13} {'verify MB/s':>12}")
    for label, r in results.items():
        print(f"{label:<12} {r['mb']:>7.1f} {r['files']:>6} {r['publish_mb_s']:>13.1f} {r['verify_mb_s']:>12.1f}")
    med_us = statistics.median(lat) * 1e6
    full_us = statistics.median(full) * 1e6
    print(f"cache-hit lookup: median {med_us:.0f} us; key digest + lookup: median {full_us:.0f} us")
    return {
        "publish_mb_s_large": round(results["large files"]["publish_mb_s"], 1),
        "verify_mb_s_large": round(results["large files"]["verify_mb_s"], 1),
        "publish_mb_s_small": round(results["small files"]["publish_mb_s"], 1),
        "verify_mb_s_small": round(results["small files"]["verify_mb_s"], 1),
        "cache_hit_lookup_us": round(med_us, 1),
        "cache_hit_key_and_lookup_us": round(full_us, 1),
    }


# ------------------------------------------------------------------------------- soak
SOAK_WORKERS = 8
SOAK_POOL = 400  # distinct payloads: writers collide on content and on action keys
MAX_REFS = 16  # per worker: beyond this it deletes more often (gc needs garbage)
KILL_EVERY_S = (0.5, 2.0)
CAPTURE_EVERY_S = 15.0  # at most one `nsim capture synth` at a time, started at most this often
CAPTURE_SPARE = 0.8  # the killer spares a worker inside a capture stage this often (else few finish)
STOP_WAIT_S = 3.0
# The writers run niced, as background load: on a small machine the gc and the CLI stage would
# otherwise get a tenth of a core each (few gc runs, captures that never finish between kills).
WORKER_NICE = 5
REPUBLISH_SAMPLE = 20
_ID_IN_TEXT = re.compile(r"\b[0-9a-f]{64}\b")


def _payload(item: int) -> dict[str, bytes]:
    """1-3 files of random bytes, up to 64 KB each, fixed by ``item``."""
    r = random.Random(item)
    return {f"part{j}.bin": r.randbytes(r.randrange(1, 64 << 10)) for j in range(1 + item % 3)}


def soak_publish(store: Store, item: int, inputs: dict[str, str], ref: str | None = None,
                 cached: bool = True, read_inputs: bool = True) -> tuple[str, str]:
    """The soak's toy stage: read (check) inputs, look up the run cache, else publish.

    Returns (id, how) with how one of "hit", "new", "raced" (an identical copy was there),
    "repaired" (a damaged copy was replaced).
    """
    if read_inputs:
        for i in inputs.values():
            store.get(i)
    cfg = {"item": item}
    key = store.action_key("soak", 1, cfg, inputs, seed=0)
    if cached and (hit := store.lookup(key)) is not None:
        if ref is not None:
            store.set_ref(ref, hit.id)
        return hit.id, "hit"
    kind = "render" if inputs else "capture"
    with store.publish(kind=kind, stage="soak", version=1, key=key, config=cfg, inputs=inputs, seed=0, ref=ref) as out:
        for rel, data in _payload(item).items():
            (out.dir / rel).write_bytes(data)
        out.summary["item"] = item
    return out.artifact.id, "raced" if out.raced else "repaired" if out.repaired else "new"


class _OpLog:
    """Append-only JSON lines, each fsync'd before the caller goes on."""

    def __init__(self, path: Path):
        self._fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)

    def __call__(self, op: str, **fields) -> None:
        rec = {"op": op, "t": round(time.time(), 3), "pid": os.getpid(), **fields}
        os.write(self._fd, (json.dumps(rec) + "\n").encode())
        os.fsync(self._fd)


def _read_log(path: Path) -> list[dict]:
    out = []
    if path.is_file():
        for line in path.read_text(errors="replace").splitlines():
            with contextlib.suppress(ValueError):
                rec = json.loads(line)
                if isinstance(rec, dict) and "op" in rec:
                    out.append(rec)
    return out


# ops that change a ref: "intent" is logged before the change, the others after it
_REF_OPS = ("intent", "publish", "tag", "delete", "capture", "observe")


def _ref_states(records: list[dict]) -> dict[str, dict]:
    """Each ref's last logged entry; an "intent" last means a kill mid-change (state unknown)."""
    last: dict[str, dict] = {}
    for r in records:
        if r["op"] in _REF_OPS and isinstance(r.get("ref"), str):
            last[r["ref"]] = r
    return last


def _read_ref(root: Path, name: str) -> str | None:
    """What a ref file says now (one line of 64 hex digits), or None when there is none."""
    try:
        text = (root / "refs" / name).read_text().strip()
    except (FileNotFoundError, NotADirectoryError, IsADirectoryError):
        return None
    return text if _ID_IN_TEXT.fullmatch(text) else None


def _die_with_parent() -> None:
    """preexec_fn: a CLI child is SIGKILLed with the worker that started it (PR_SET_PDEATHSIG),
    and runs at normal priority where it may (the writers are niced)."""
    import ctypes

    ctypes.CDLL(None).prctl(1, signal.SIGKILL)
    with contextlib.suppress(OSError):
        os.setpriority(os.PRIO_PROCESS, 0, 0)


def _nsim_cmd() -> list[str]:
    script = Path(sys.executable).parent / "nsim"
    if script.is_file():
        return [str(script)]
    return [sys.executable, "-c", "import sys; from nsim.cli import main; sys.exit(main())"]


def _run_cli(root: Path, args: list[str], pass_fds: tuple[int, ...] = (), timeout_s: float = 120.0):
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    return subprocess.run([*_nsim_cmd(), "-w", str(root), *args], capture_output=True, text=True, env=env,
                          timeout=timeout_s, pass_fds=pass_fds, preexec_fn=_die_with_parent)


def _capture_pid(run_dir: Path) -> int | None:
    """The worker running `nsim capture synth` now (written into capture.lock), if any."""
    try:
        parts = (run_dir / "capture.lock").read_text().split()
    except FileNotFoundError:
        return None
    return int(parts[1]) if len(parts) == 2 and parts[1].isdigit() else None


class _Worker:
    """One soak writer: random publish / tag / delete / read / CLI operations on its own refs."""

    def __init__(self, idx: int, root: Path, run_dir: Path, seed: int):
        self.idx, self.root, self.run_dir = idx, root, run_dir
        self.rng = random.Random(seed)
        self.log = _OpLog(run_dir / f"w{idx}.jsonl")
        self.tb_path = run_dir / f"w{idx}.tracebacks.txt"
        records = _read_log(run_dir / f"w{idx}.jsonl")
        self.n = len(records)
        self.pending: str | None = None  # a ref whose change was logged as intended, not yet as done
        self.stale = False  # this op tags an id no ref keeps: "no such artifact" is expected
        self.store = Store(root)
        self.refs: dict[str, str] = {}  # this worker's refs, name -> id, as it last left them
        for name, r in _ref_states(records).items():
            if r["op"] == "intent":  # killed mid-change: look, and log what is there now
                self.observe(name)
            elif r["op"] != "delete" and r.get("id"):
                self.refs[name] = r["id"]
        self.history = [r["id"] for r in records if r["op"] == "publish"][-200:]

    def intent(self, name: str) -> None:
        self.log("intent", ref=name)
        self.pending = name

    def done(self, op: str, **fields) -> None:
        self.log(op, **fields)
        self.pending = None

    def observe(self, name: str) -> None:
        now = _read_ref(self.root, name)
        self.done("observe", ref=name, id=now)
        if now is None:
            self.refs.pop(name, None)
        else:
            self.refs[name] = now

    def new_ref(self) -> str:
        self.n += 1
        return f"soak/w{self.idx}/n{self.n}"

    def run(self, stop: Path) -> None:
        ops = (("publish", 0.7), ("tag", 0.1), ("delete", 0.06), ("read", 0.12), ("cli", 0.02))
        while not stop.exists():
            op = self.rng.choices([o for o, _ in ops], [w for _, w in ops])[0]
            if not self.refs and op in ("tag", "delete", "read"):
                op = "publish"
            if op == "publish" and len(self.refs) > MAX_REFS and self.rng.random() < 0.3:
                op = "delete"
            self.stale = False
            try:
                getattr(self, f"op_{op}")()
            except NsimError as exc:
                self.log("error", during=op, type=type(exc).__name__, msg=str(exc), expected=self.stale)
            except Exception as exc:  # noqa: BLE001 - counted and kept, the soak goes on
                with open(self.tb_path, "a") as f:
                    f.write(f"--- w{self.idx} pid {os.getpid()} during {op}\n{traceback.format_exc()}\n")
                self.log("exception", during=op, type=type(exc).__name__, msg=str(exc)[:500])
            finally:
                if self.rng.random() < 0.3:  # drop the lease now and then (it grows with every id touched)
                    self.store.release()
            if self.pending is not None:  # the change failed part-way: log what the ref says now
                self.observe(self.pending)

    # -- operations (each returns nothing; a ref op logs "intent" first and its result after)
    def op_publish(self) -> None:
        item = self.rng.randrange(SOAK_POOL)
        inputs = {"capture": self.rng.choice(list(self.refs.values()))} if self.refs and self.rng.random() < 0.3 else {}
        ref = self.new_ref() if self.rng.random() < 0.5 else None
        if ref is not None:
            self.intent(ref)
        art_id, how = soak_publish(self.store, item, inputs, ref)
        self.done("publish", id=art_id, ref=ref, item=item, inputs=inputs, how=how)
        if ref is not None:
            self.refs[ref] = art_id
        self.history.append(art_id)

    def op_tag(self) -> None:
        if self.history and self.rng.random() < 0.1:
            target = self.rng.choice(self.history)  # may be collected by now: set_ref refuses it
            self.stale = True
        else:
            target = self.rng.choice(list(self.refs.values()))
        name = self.rng.choice(list(self.refs)) if self.rng.random() < 0.4 else self.new_ref()
        self.intent(name)
        if self.rng.random() < 0.1:
            r = _run_cli(self.root, ["tag", target, name])
            self.cli_outcome(["tag"], r)
            if r.returncode != 0:
                raise WorkspaceError(f"nsim tag exited {r.returncode}: {r.stderr.strip()[-300:]}")
        else:
            self.store.set_ref(name, target)
        self.done("tag", ref=name, id=target)
        self.refs[name] = target

    def op_delete(self) -> None:
        name = self.rng.choice(list(self.refs))
        self.intent(name)
        self.store.delete_ref(name)
        self.done("delete", ref=name)
        del self.refs[name]

    def op_read(self) -> None:
        name = self.rng.choice(list(self.refs))
        want = self.refs[name]
        reader = Store(self.root)  # a fresh checked store: get() holds and verifies
        try:
            try:
                art_id = reader.resolve(name)
                art = reader.get(art_id)
            except NsimError as exc:
                self.log("read_failed", ref=name, id=want, type=type(exc).__name__, msg=str(exc))
                return
            if art_id != want:
                self.log("read_failed", ref=name, id=want, msg=f"ref names {art_id}")
                return
            nbytes = 0
            for rel, info in art.manifest["files"].items():
                data = art.file(rel).read_bytes()
                if hashlib.sha256(data).hexdigest() != info["sha256"]:
                    raise AssertionError(f"{art_id[:12]}/{rel}: content differs from the manifest after a checked get")
                nbytes += len(data)
        finally:
            reader.release()
        self.log("read", ref=name, id=art_id, bytes=nbytes)

    def op_cli(self) -> None:
        pick = self.rng.random()
        if pick < 0.4:
            self.cli_capture()
        elif pick < 0.7:
            r = _run_cli(self.root, ["ls"])
            self.cli_outcome(["ls"], r)
        else:
            name = self.rng.choice(list(self.refs)) if self.refs else "capture/latest"
            r = _run_cli(self.root, ["verify", name])
            self.cli_outcome(["verify", name], r, held=name in self.refs)

    def cli_capture(self) -> None:
        fd = os.open(self.run_dir / "capture.lock", os.O_RDWR | os.O_CREAT, 0o644)
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                return
            last = os.pread(fd, 64, 0).decode().split()
            if last and time.time() - float(last[0]) < CAPTURE_EVERY_S:
                return
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{time.time():.3f} {os.getpid()}".encode(), 0)
            name = f"soak/cap{self.idx}-{self.n + 1}"
            self.n += 1
            self.intent(name)
            # the child inherits the locked descriptor: the lock lasts as long as the stage runs
            r = _run_cli(self.root, ["capture", "synth", "--preset", "tiny", "--tag", name], pass_fds=(fd,), timeout_s=300)
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{time.time():.3f}".encode(), 0)  # spacing counts from the end; no pid: done
            self.cli_outcome(["capture"], r)
            ids = _ID_IN_TEXT.findall(r.stdout)
            if r.returncode == 0 and ids:
                self.done("capture", ref=name, id=ids[-1])
                self.refs[name] = ids[-1]
        finally:
            os.close(fd)

    def cli_outcome(self, args: list[str], r: subprocess.CompletedProcess, held: bool = False) -> None:
        """Log a CLI run; a Python traceback on its stderr is recorded as one."""
        if "Traceback" in r.stderr:
            with open(self.tb_path, "a") as f:
                f.write(f"--- w{self.idx} CLI {' '.join(args)} rc {r.returncode}\n{r.stderr}\n")
        self.log("cli", cmd=args[0], args=args[1:], rc=r.returncode, traceback="Traceback" in r.stderr,
                 held=held, err=r.stderr.strip()[-300:] if r.returncode else "",
                 out=r.stdout.strip()[-300:] if r.returncode == 1 else "")


def _gc_loop(root: Path, run_dir: Path, seed: int, stop: Path) -> None:
    """The soak's collector: ``Store.gc(grace_s=0)`` in a loop, sometimes ``nsim gc --grace 0``."""
    rng = random.Random(seed)
    log = _OpLog(run_dir / "gc.jsonl")
    tb_path = run_dir / "gc.tracebacks.txt"
    while not stop.exists():
        try:
            if rng.random() < 0.05:
                r = _run_cli(root, ["gc", "--grace", "0"])
                if "Traceback" in r.stderr:
                    with open(tb_path, "a") as f:
                        f.write(f"--- CLI gc rc {r.returncode}\n{r.stderr}\n")
                if r.returncode == 0:
                    log("gc", via="cli", restored=r.stdout.count("kept object"), removed=r.stdout.count("removed object"))
                elif "another 'nsim gc'" in r.stderr:
                    log("gc_skipped", via="cli")
                else:
                    log("cli", cmd="gc", rc=r.returncode, traceback="Traceback" in r.stderr, err=r.stderr.strip()[-300:])
            else:
                rep = Store(root, create=False, checked=False).gc(grace_s=0)
                log("gc", via="api", restored=len(rep.restored), removed=len(rep.objects), tmp=len(rep.tmp))
        except WorkspaceError as exc:
            if "another 'nsim gc'" in str(exc):
                log("gc_skipped", via="api")
            else:
                log("error", during="gc", type=type(exc).__name__, msg=str(exc))
        except Exception as exc:  # noqa: BLE001
            with open(tb_path, "a") as f:
                f.write(f"--- gc pid {os.getpid()}\n{traceback.format_exc()}\n")
            log("exception", during="gc", type=type(exc).__name__, msg=str(exc)[:500])
        time.sleep(rng.uniform(0.0, 0.05))


def _soak_check(root: Path, run_dir: Path, rng: random.Random) -> dict:
    """The end state after a last gc: lost refs, unrecoverable objects, republish of a sample."""
    store = Store(root, create=False, checked=False)
    for _ in range(50):
        try:
            final = store.gc(grace_s=0)
            break
        except WorkspaceError:
            time.sleep(0.2)
    else:
        raise RuntimeError("the final gc never got the gc lock")
    logs = {p.stem: _read_log(p) for p in sorted(run_dir.glob("w*.jsonl"))}
    refs_now = store.refs()
    lost, resurrected, unknown, checked = [], [], 0, 0
    for recs in logs.values():
        for name, r in _ref_states(recs).items():
            if r["op"] == "intent":
                unknown += 1
                continue
            want = r.get("id") if r["op"] != "delete" else None
            now = refs_now.get(name)
            if want is None:
                if now is not None:
                    resurrected.append(name)
                continue
            checked += 1
            problems = store.verify(want) if now == want else []
            if now != want or problems:
                why = f"ref names {now}" if now != want else str(problems[0])
                lost.append(f"{name} -> {want[:12]}: {why} (last logged {r['op']} at {r['t']})")
    all_ids = set(store.all_ids())
    damaged = store.damaged_ids()
    reach = store.reachable()
    bad = [f"{i[:12]}: {store.verify(i)[0]}" for i in sorted(reach) if store.verify(i)]
    missing_inputs = []
    for i in sorted(reach):
        for name, child in store.get(i).manifest.get("inputs", {}).items():
            if child not in all_ids:
                missing_inputs.append(f"{i[:12]} input {name} {child[:12]}")
    broken = store.broken_refs()
    leaked = sorted(all_ids - reach)
    leftovers = [p.name for sub in ("trash", "tmp") for p in (root / sub).iterdir()]
    # a fresh publish of logged configs gives the logged id
    pubs = {r["id"]: r for recs in logs.values() for r in recs if r["op"] == "publish"}
    sample = rng.sample(sorted(pubs), min(REPUBLISH_SAMPLE, len(pubs)))
    republish_bad = []
    for art_id in sample:
        r = pubs[art_id]
        new_id, _ = soak_publish(store, r["item"], r["inputs"], cached=False, read_inputs=False)
        if new_id != art_id or store.verify(new_id):
            republish_bad.append(f"item {r['item']} inputs {r['inputs']}: {new_id[:12]} != logged {art_id[:12]}")
    store.release()
    return {
        "lost": lost, "resurrected": resurrected, "unknown_refs": unknown, "checked_refs": checked,
        "bad": bad, "missing_inputs": missing_inputs, "broken_refs": broken, "damaged": damaged,
        "leaked": leaked, "leftovers": leftovers, "republished": len(sample), "republish_bad": republish_bad,
        "final_gc_removed": len(final.objects), "final_gc_restored": len(final.restored), "objects": len(all_ids),
    }


def soak(seconds: float, workspace: Path | None, seed: int = 0) -> dict:
    """Run the kill soak; prints its table, returns the JSON fields."""
    rng = random.Random(seed)
    with tempfile.TemporaryDirectory(prefix="nsim-soak-") as tmp:
        workspace = workspace.absolute() if workspace is not None else None
        run_dir = Path(tmp) if workspace is None else workspace.with_name(workspace.name + ".soak-logs")
        run_dir.mkdir(exist_ok=workspace is None)
        root = workspace if workspace is not None else run_dir / "ws"
        Store(root)  # create it before anyone races to
        if any((root / "objects").iterdir()):
            raise SystemExit(f"--workspace {root}: the soak needs a fresh (empty) workspace")
        stop = run_dir / "stop"
        names = [*(f"w{i}" for i in range(SOAK_WORKERS)), "gc"]
        starts = Counter()
        procs: dict[str, subprocess.Popen] = {}

        def start(name: str) -> None:
            starts[name] += 1
            role = ["--gc-worker"] if name == "gc" else ["--worker", name[1:]]
            err = open(run_dir / f"{name}.stderr", "a")
            procs[name] = subprocess.Popen(
                [sys.executable, __file__, *role, "--root", str(root), "--run-dir", str(run_dir),
                 "--seed", str(seed * 100_003 + names.index(name) * 1009 + starts[name])],
                stdout=subprocess.DEVNULL, stderr=err)
            err.close()

        t0 = time.monotonic()
        for name in names:
            start(name)
        kills, crashes = Counter(), []
        deadline = t0 + seconds
        while (now := time.monotonic()) < deadline:
            time.sleep(min(rng.uniform(*KILL_EVERY_S), max(0.0, deadline - now)))
            if time.monotonic() >= deadline:
                break
            for name, p in procs.items():  # a process that ended by itself crashed
                if p.poll() is not None:
                    crashes.append(f"{name} exited {p.returncode}")
                    start(name)
            victim = "gc" if rng.random() < 0.25 else rng.choice(names[:-1])
            if procs[victim].pid == _capture_pid(run_dir) and rng.random() < CAPTURE_SPARE:
                victim = rng.choice([n for n in names if n != victim])
            os.kill(procs[victim].pid, signal.SIGKILL)
            procs[victim].wait()
            kills[victim] += 1
            start(victim)
        soak_s = time.monotonic() - t0
        stop.touch()
        end = time.monotonic() + STOP_WAIT_S
        for name, p in procs.items():
            try:
                p.wait(timeout=max(0.05, end - time.monotonic()))
            except subprocess.TimeoutExpired:
                p.kill()  # e.g. inside a capture: its CLI child dies with it
                p.wait()
            if p.returncode not in (0, -signal.SIGKILL):
                crashes.append(f"{name} exited {p.returncode}")
        peak_rss_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
        check = _soak_check(root, run_dir, rng)

        recs = [r for p in sorted(run_dir.glob("*.jsonl")) for r in _read_log(p)]
        by_op = Counter(r["op"] for r in recs)
        how = Counter(r["how"] for r in recs if r["op"] == "publish")
        cli = [r for r in recs if r["op"] == "cli"]
        stage_runs = sum(1 for r in recs if r["op"] == "capture")
        stderr_tb = sum((run_dir / f"{n}.stderr").read_text(errors="replace").count("Traceback") for n in names)
        tracebacks = by_op["exception"] + sum(1 for r in cli if r.get("traceback")) + stderr_tb + len(crashes)
        errors = Counter(f"{r['during']}: {r['msg'][:90]}" for r in recs if r["op"] == "error" and not r.get("expected"))
        stale_tags = sum(1 for r in recs if r["op"] == "error" and r.get("expected"))
        read_failed = [r for r in recs if r["op"] == "read_failed"]
        verify_failed = [r for r in cli if r["cmd"] == "verify" and r["rc"] == 1 and r.get("held")]
        unrecoverable = (len(check["bad"]) + len(check["missing_inputs"]) + len(check["broken_refs"])
                         + len(check["damaged"]) + len(check["republish_bad"]))
        tb_text = "".join(p.read_text(errors="replace") for p in sorted(run_dir.glob("*.tracebacks.txt")))
    rows = [
        ("soak seconds", f"{soak_s:.1f} ({SOAK_WORKERS} workers + gc, killed every {KILL_EVERY_S[0]}-{KILL_EVERY_S[1]} s)"),
        ("publishes", f"{how['new'] + how['raced'] + how['repaired']} (new {how['new']}, raced {how['raced']}, "
                      f"repaired {how['repaired']}); cache hits {how['hit']}"),
        ("tags / deletes / reads", f"{by_op['tag']} / {by_op['delete']} / {by_op['read']}"),
        ("gc runs", f"{by_op['gc']} (skipped: another gc {by_op['gc_skipped']}); restored "
                    f"{sum(r.get('restored', 0) for r in recs if r['op'] == 'gc')}, removed "
                    f"{sum(r.get('removed', 0) for r in recs if r['op'] == 'gc')}"),
        ("kills", f"{sum(kills.values())} ({', '.join(f'{k} {v}' for k, v in sorted(kills.items()))})"),
        ("CLI runs", f"{len(cli)}: " + ", ".join(f"{k} {v}" for k, v in sorted(Counter(r['cmd'] for r in cli).items()))
                     + f"; capture stages finished {stage_runs}"),
        ("one-line errors", f"{sum(errors.values())} (and {stale_tags} expected: tag of an id gc had collected)"),
        ("reads of a held ref that failed", f"{len(read_failed)}; CLI verify of a held ref failed {len(verify_failed)}"),
        ("final state", f"{check['objects']} objects, {check['checked_refs']} refs checked, {check['unknown_refs']} "
                        f"unknown (killed mid-change), final gc removed {check['final_gc_removed']}, "
                        f"restored {check['final_gc_restored']}"),
        ("lost", str(len(check["lost"]))),
        ("tracebacks", f"{tracebacks} (caught {by_op['exception']}, CLI {sum(1 for r in cli if r.get('traceback'))}, "
                       f"stderr {stderr_tb}, crashes {len(crashes)})"),
        ("unrecoverable", f"{unrecoverable} (bad {len(check['bad'])}, missing inputs {len(check['missing_inputs'])}, "
                          f"broken refs {len(check['broken_refs'])}, damaged dirs {len(check['damaged'])}, "
                          f"republish {len(check['republish_bad'])}/{check['republished']})"),
        ("leaked / leftovers", f"{len(check['leaked'])} unreachable objects kept; {len(check['leftovers'])} in trash/ tmp/; "
                               f"{len(check['resurrected'])} deleted refs back"),
        ("peak RSS of a child", f"{peak_rss_mb:.0f} MB (workers, gc and the CLI runs they waited for)"),
    ]
    print()
    if workspace is not None:
        print(f"workspace {workspace}; worker logs and tracebacks in {run_dir}")
    for label, value in rows:
        print(f"{label:<32} {value}")
    for what, items in (("error", [f"{n} x {m}" for m, n in errors.most_common(8)]), ("lost", check["lost"]),
                        ("bad", check["bad"]), ("missing input", check["missing_inputs"]),
                        ("broken ref", [f"{k} -> {v[:12]}" for k, v in check["broken_refs"].items()]),
                        ("republish", check["republish_bad"]), ("crash", crashes),
                        ("read failed", [f"{r['ref']} -> {r['id'][:12]}: {r['msg'][:120]}" for r in read_failed]),
                        ("verify failed", [f"{r['args']}: {r['out'][-150:]}" for r in verify_failed])):
        for line in items[:10]:
            print(f"  {what}: {line}")
    if tb_text:
        print("first traceback:\n" + tb_text[:3000])
    return {
        "lost": len(check["lost"]),
        "tracebacks": tracebacks,
        "unrecoverable": unrecoverable,
        "publishes": how["new"] + how["raced"] + how["repaired"],
        "cache_hits": how["hit"],
        "gc_runs": by_op["gc"],
        "kills": sum(kills.values()),
        "soak_s": round(soak_s, 1),
        "reads": by_op["read"],
        "tags": by_op["tag"],
        "stage_runs": stage_runs,
        "cli_runs": len(cli),
        "read_failures": len(read_failed) + len(verify_failed),
        "nsim_errors": sum(errors.values()),
        "peak_rss_mb": round(peak_rss_mb, 1),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="tiny sizes and a 10 s soak (seconds in all)")
    ap.add_argument("--soak", type=float, default=None, metavar="SECONDS", help="run the kill soak this long")
    ap.add_argument("--workspace", type=Path, default=None, help="soak in this (fresh) workspace, not a temp dir")
    ap.add_argument("--worker", type=int, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--gc-worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--root", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--run-dir", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--seed", type=int, default=0, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker is not None:
        os.nice(WORKER_NICE)
        _Worker(args.worker, args.root, args.run_dir, args.seed).run(args.run_dir / "stop")
        return
    if args.gc_worker:
        _gc_loop(args.root, args.run_dir, args.seed, args.run_dir / "stop")
        return
    out = {"bench": "workspace", "quick": args.quick, **throughput(args.quick)}
    soak_s = args.soak if args.soak is not None else 10.0 if args.quick else None
    if soak_s:
        out.update(soak(soak_s, args.workspace))
    print(json.dumps(out))


if __name__ == "__main__":
    main()
