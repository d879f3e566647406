"""Sharded, resumable execution of a shard renderer: in this process, or on Ray actors.

The engine knows nothing about what is rendered. A caller cuts its work into shards (ints), gives
each shard a key (a digest of the shard's inputs, so an edit never reuses a stale shard) and a
*factory* that builds a :class:`ShardRenderer` (the models are loaded once per worker, in the
factory). :func:`run_shards` then renders every shard whose published directory is missing::

    factory = functools.partial(FrameRenderer, scene_dir=..., rig=..., seed=ctx.seed)
    results = run_shards(factory, range(n_shards), root / "shards", key_of, EngineConfig(engine="ray"))
    results[3].path      # root/shards/<key_of(3)>: exactly the files the renderer wrote
    results[3].summary   # what its render_shard returned (also for shards found already published)

Publishing a shard (both engines, in the worker that rendered it)
    1. the renderer writes into a fresh ``shard_root/.<key>.<host>.<pid>.<uuid>.tmp/``; the engine
       fsyncs every file and directory in it;
    2. the summary goes to ``shard_root/<key>.summary.json`` (``{"shard": i, "key": key, "summary":
       ...}``, written to a temp file, fsynced, renamed): before the directory, so that a published
       shard always has one, and beside it, so that the directory holds only the renderer's files;
    3. ``os.rename`` of the directory to ``shard_root/<key>`` (atomic, also on NFS), then an fsync
       of ``shard_root``.
    A shard directory that exists is complete. A writer that loses a rename race (another worker or
    driver published the same key first) drops its copy (its summary, written just before, is the
    same for a deterministic renderer). A renderer that raises leaves nothing; a
    worker that dies leaves its temp directory, which the driver removes when Ray reports the death
    (it knows the dead worker's host and pid), and any later writer of that key on the same host
    removes when the writing process is gone.

So a rerun after a crash renders only the missing shards, and two drivers on the same shard root
never corrupt each other. Only paths and the small summaries travel back to the driver.

Determinism: a shard's files must depend only on the shard index and the factory's arguments
(seed per shard, e.g. ``np.random.SeedSequence([seed, shard])``), never on the worker, the engine or
the order of shards. The same holds for the summary if it is to be compared: keep wall times out.

Engines
    ``local``: in this process, one renderer built once, shards in order.
    ``ray``: ``workers`` :class:`RenderWorker` actors (``num_cpus_per_worker``,
    ``num_gpus_per_worker`` each: 0.5 packs two per GPU), each building its renderer once; shards are
    dealt dynamically to whichever worker is idle. A worker process that dies is restarted by Ray
    (up to ``max_restarts`` times; the restart rebuilds the renderer) and its shard is redone, on
    the restarted worker or another, up to ``max_task_retries`` times per shard, then a one-line
    :class:`~nsim.errors.NsimError`. An :class:`~nsim.errors.NsimError` raised by a renderer comes
    back as the same class, prefixed with the shard; any other exception keeps its traceback.
    Where Ray runs is decided by :func:`nsim.distributed.ray_session` (``--address``,
    ``$RAY_ADDRESS``, else a private local instance; never a stray cluster).
"""

from __future__ import annotations

import dataclasses
import errno
import json
import logging
import math
import os
import shutil
import socket
import time
import uuid
from collections import Counter, deque
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any, Protocol

from nsim.errors import ConfigError, NsimError
from nsim.io import atomic_write_text, fsync_path
from nsim.progress import progress_bar

logger = logging.getLogger(__name__)

ENGINES = ("local", "ray")
SUMMARY_SUFFIX = ".summary.json"  # shard_root/<key>.summary.json beside shard_root/<key>/
REPROBE_INTERVAL_S = 0.5  # how often to ask a restarting worker whether it is up again
RESTART_TIMEOUT_S = 900.0  # a worker still restarting after this long is given up (renderer builds included)


class ShardRenderer(Protocol):
    def render_shard(self, shard: int, out_dir: Path) -> dict[str, Any]:
        """Write shard ``shard``'s files into ``out_dir`` (an empty temp dir); return a small JSON-able summary."""
        ...


RendererFactory = Callable[[], ShardRenderer]
"""Builds a renderer (loading its models). Must pickle for Ray: a top-level class or function, or a
``functools.partial`` of one with plain arguments (paths, ids, config dataclasses)."""


@dataclasses.dataclass(frozen=True)
class EngineConfig:
    engine: str = "local"  # local | ray
    # ray only: a cluster ('auto', HOST:6379, ray://HOST:10001); None: $RAY_ADDRESS, else a private instance
    address: str | None = None
    workers: int = 1  # ray: number of RenderWorker actors; local: must be 1
    num_cpus_per_worker: float = 1.0
    num_gpus_per_worker: float = 0.0  # fractions below 1 share a GPU (0.5: two workers per GPU)
    max_restarts: int = 2  # times Ray restarts each dead worker (rebuilding its renderer)
    max_task_retries: int = 2  # times a shard lost with its worker is redone before giving up

    def __post_init__(self) -> None:
        if self.engine not in ENGINES:
            raise ConfigError(f"--engine: {self.engine!r} is not one of {', '.join(ENGINES)}")
        if self.address is not None and (not isinstance(self.address, str) or not self.address):
            raise ConfigError(f"--address: expected a non-empty string, got {self.address!r}")
        if self.address is not None and self.engine != "ray":
            raise ConfigError("--address: only the ray engine connects to a cluster (use --engine ray)")
        for name in ("workers", "max_restarts", "max_task_retries"):
            value, low = getattr(self, name), 1 if name == "workers" else 0
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ConfigError(f"--{name.replace('_', '-')}: expected an int >= {low}, got {value!r}")
        if self.engine == "local" and self.workers != 1:
            raise ConfigError(
                f"--workers: the local engine renders in this process with one worker, got {self.workers} "
                "(use --engine ray for more)"
            )
        for name, flag in (
            ("num_cpus_per_worker", "--cpus-per-worker"),
            ("num_gpus_per_worker", "--gpus-per-worker"),
        ):
            value = getattr(self, name)
            if (
                isinstance(value, bool)
                or not isinstance(value, int | float)
                or not math.isfinite(value)
                or value < 0
            ):
                raise ConfigError(f"{flag}: expected a number >= 0, got {value!r}")
        gpus = self.num_gpus_per_worker
        if gpus > 1 and gpus != int(gpus):
            raise ConfigError(f"--gpus-per-worker: above 1 it must be a whole number, got {gpus!r}")


@dataclasses.dataclass(frozen=True)
class ShardResult:
    """A published shard; path-like (``Path(result)``, ``open``, ``os.fspath`` see its directory)."""

    shard: int
    path: Path  # the published directory, shard_root/<key>
    summary: dict[str, Any]  # what render_shard returned (read back for a shard found published)
    rendered: bool  # False: it was already published (by an earlier run or a concurrent writer)

    def __fspath__(self) -> str:
        return str(self.path)


def run_shards(
    factory: RendererFactory,
    shards: Iterable[int],
    shard_root: Path,
    shard_key: Callable[[int], str],
    cfg: EngineConfig,
    progress: bool = False,
) -> dict[int, ShardResult]:
    """Render every shard whose ``shard_root/<shard_key(i)>`` is missing; return shard -> result, in ``shards`` order.

    ``shard_root`` must be on a filesystem every Ray worker sees at the same path (it is created).
    ``progress`` shows a per-shard bar (pass ``ctx.show_progress``: quiet when not on a terminal).
    """
    shards = list(shards)
    if len(set(shards)) != len(shards):
        raise ValueError("run_shards: shards must be unique")
    keys = {i: shard_key(i) for i in shards}
    for i, key in keys.items():
        _check_key(i, key)
    if len(set(keys.values())) != len(keys):
        raise ValueError("run_shards: shard_key gave two shards the same key")
    shard_root = Path(shard_root).absolute()
    shard_root.mkdir(parents=True, exist_ok=True)

    results: dict[int, ShardResult] = {}
    todo = []
    for i in shards:
        path = shard_root / keys[i]
        if path.is_dir():
            results[i] = ShardResult(i, path, read_summary(path), rendered=False)
        else:
            todo.append(i)
    logger.info("%d of %d shards to render (engine %s)", len(todo), len(shards), cfg.engine)
    if todo:
        with progress_bar(len(todo), "rendering shards", progress) as bar:
            if cfg.engine == "local":
                rendered = _run_local(factory, todo, shard_root, keys, bar)
            else:
                rendered = _run_ray(factory, todo, shard_root, keys, cfg, bar)
        results.update(rendered)
    return {i: results[i] for i in shards}


def summary_path(shard_dir: Path) -> Path:
    shard_dir = Path(shard_dir)
    return shard_dir.with_name(shard_dir.name + SUMMARY_SUFFIX)


def read_summary(shard_dir: Path) -> dict[str, Any]:
    """The summary stored beside a published shard directory ({} for a directory the engine did not publish)."""
    path = summary_path(shard_dir)
    return json.loads(path.read_text())["summary"] if path.is_file() else {}


def publish_shard(renderer: ShardRenderer, shard: int, shard_root: Path, key: str) -> ShardResult:
    """Render one shard into a temp dir and rename it to ``shard_root/<key>`` (see the module docstring)."""
    final = shard_root / key
    if final.is_dir():
        return ShardResult(shard, final, read_summary(final), rendered=False)
    host, pid = socket.gethostname(), os.getpid()
    _remove_stale_temps(shard_root, key, host)
    tmp = shard_root / f".{key}.{host}.{pid}.{uuid.uuid4().hex[:12]}.tmp"
    tmp.mkdir()
    try:
        summary = renderer.render_shard(shard, tmp)
        if not isinstance(summary, dict):
            raise TypeError(f"render_shard({shard}) returned {type(summary).__name__}, expected a dict")
        record = {"shard": shard, "key": key, "summary": summary}
        text = json.dumps(record, indent=2, sort_keys=True, allow_nan=False) + "\n"
        _fsync_tree(tmp)
        _write_atomic(summary_path(final), text, tmp.name)
        try:
            os.rename(tmp, final)
        except OSError as exc:
            if exc.errno not in (errno.ENOTEMPTY, errno.EEXIST) or not final.is_dir():
                raise
            logger.info("shard %d: %s was published by another writer; dropping this copy", shard, key)
            shutil.rmtree(tmp, ignore_errors=True)
            return ShardResult(shard, final, read_summary(final), rendered=False)
        fsync_path(shard_root)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    # what read_summary gives back, so that a fresh and a found shard (and both engines) look the same
    return ShardResult(shard, final, json.loads(json.dumps(summary)), rendered=True)


class RenderWorker:
    """Holds one renderer built from the factory; run as a Ray actor (``ray.remote(RenderWorker)``)."""

    def __init__(self, factory: RendererFactory) -> None:
        self._error: NsimError | None = None
        try:
            self._renderer = factory()
        except NsimError as exc:  # a user error (e.g. a missing checkpoint): reported by ready()
            self._error = exc

    def ready(self) -> tuple[str, int, NsimError | None]:
        """(host, pid, the factory's user error or None): the driver's handle on this process."""
        return socket.gethostname(), os.getpid(), self._error

    def render(self, shard: int, shard_root: str, key: str) -> ShardResult | NsimError:
        if self._error is not None:
            return self._error
        try:
            return publish_shard(self._renderer, shard, Path(shard_root), key)
        except NsimError as exc:  # crosses the process boundary as a value, re-raised by the driver
            return exc


def _run_local(factory, todo, shard_root, keys, bar) -> dict[int, ShardResult]:
    renderer = factory()
    results = {}
    for i in todo:
        try:
            results[i] = publish_shard(renderer, i, shard_root, keys[i])
        except NsimError as exc:
            raise _shard_error(i, exc) from exc
        bar.advance(shard=i)
    return results


def _run_ray(factory, todo, shard_root, keys, cfg: EngineConfig, bar) -> dict[int, ShardResult]:
    from nsim.distributed import ray_session

    num_cpus = max(1, math.ceil(cfg.workers * cfg.num_cpus_per_worker))
    with ray_session(cfg.address, num_cpus=num_cpus) as ray:
        _check_resources(ray, cfg)
        actor_cls = ray.remote(RenderWorker).options(
            num_cpus=cfg.num_cpus_per_worker,
            num_gpus=cfg.num_gpus_per_worker,
            max_restarts=cfg.max_restarts,
            max_task_retries=0,  # the driver redoes a lost shard itself, on whichever worker is free
        )
        workers = [actor_cls.remote(factory) for _ in range(min(cfg.workers, len(todo)))]
        return _Dispatch(ray, workers, todo, shard_root, keys, cfg, bar).run()


class _Dispatch:
    """The driver's side of the ray engine: deals shards to idle workers, redoes the shards of dead ones.

    Each worker is first probed with ``ready()`` (which also tells its host and pid); a started worker
    gets one shard at a time. When a worker's process dies mid-shard, the shard goes back to the
    front of the queue, the worker is probed again (Ray restarts it, rebuilding the renderer) and,
    once its new process answers, the dead process's temp dir is removed.
    """

    def __init__(self, ray, workers, todo, shard_root: Path, keys: dict[int, str], cfg: EngineConfig, bar):
        from ray.exceptions import ActorDiedError, ActorUnavailableError, RayActorError

        self.ray, self.workers, self.n_todo = ray, workers, len(todo)
        self.shard_root, self.keys, self.cfg, self.bar = shard_root, keys, cfg, bar
        self.died, self.unavailable, self.actor_error = ActorDiedError, ActorUnavailableError, RayActorError
        self.queue = deque(todo)
        self.results: dict[int, ShardResult] = {}
        self.pending: dict[Any, tuple[int, int | None]] = {}  # ref -> (worker, shard or None for a probe)
        self.reprobe_at: dict[int, float] = {}  # worker -> when to probe again (it was restarting)
        self.restarting_since: dict[int, float] = {}
        self.idle: set[int] = set()  # started workers with nothing to do (the queue ran dry)
        self.where: dict[int, tuple[str, int]] = {}  # worker -> (host, pid) of its live process
        self.started: set[int] = set()  # workers that answered ready() at least once
        # worker -> (key, host, pid) of temp dirs its lost processes may have left
        self.orphans: dict[int, list[tuple[str, str, int]]] = {k: [] for k in range(len(workers))}
        self.deaths: Counter[int] = Counter()
        self.losses: Counter[int] = Counter()
        self.last_death: BaseException | None = None

    def run(self) -> dict[int, ShardResult]:
        for k in range(len(self.workers)):
            self._probe(k)
        try:
            while len(self.results) < self.n_todo:
                self._step()
        finally:
            self._stop()
        return self.results

    def _step(self) -> None:
        if not self.pending and not self.reprobe_at:
            if not self.started and self.last_death is not None:
                raise self.last_death  # no worker ever started: a bug in the factory, with its traceback
            raise NsimError(
                f"all {len(self.workers)} render workers died (each restarted up to {self.cfg.max_restarts} "
                f"times); last error: {_first_line(self.last_death)}"
            )
        timeout = max(0.0, min(self.reprobe_at.values()) - time.monotonic()) if self.reprobe_at else None
        if self.pending:
            done, _ = self.ray.wait(list(self.pending), num_returns=1, timeout=timeout)
        else:
            time.sleep(timeout or 0.0)
            done = []
        for k, at in list(self.reprobe_at.items()):
            if at <= time.monotonic():
                del self.reprobe_at[k]
                self._probe(k)
        if not done:
            return
        k, shard = self.pending.pop(done[0])
        try:
            value = self.ray.get(done[0])
        except self.actor_error as exc:
            self.last_death = exc
            if shard is None:
                self._probe_failed(k, exc)
            else:
                self._lost(k, shard, exc)
            return
        if shard is None:
            host, pid, error = value
            if error is not None:
                raise error  # the factory's user error, e.g. a missing checkpoint
            self.where[k] = (host, pid)
            self.started.add(k)
            self.restarting_since.pop(k, None)
            self._clean(k, unless=(host, pid))
        else:
            if isinstance(value, NsimError):
                raise _shard_error(shard, value)
            self.results[shard] = value
            self.bar.advance(shard=shard)
        self._feed(k)

    def _probe(self, k: int) -> None:
        self.pending[self.workers[k].ready.remote()] = (k, None)

    def _feed(self, k: int) -> None:
        if self.queue:
            shard = self.queue.popleft()
            ref = self.workers[k].render.remote(shard, str(self.shard_root), self.keys[shard])
            self.pending[ref] = (k, shard)
        else:
            self.idle.add(k)

    def _lost(self, k: int, shard: int, exc: BaseException) -> None:
        """Worker ``k`` died while rendering ``shard``: requeue the shard, wait for Ray's restart."""
        if k in self.where:
            self.orphans[k].append((self.keys[shard], *self.where.pop(k)))
        self.losses[shard] += 1
        if self.losses[shard] > self.cfg.max_task_retries:
            raise NsimError(
                f"shard {shard}: its worker died {_times(self.losses[shard])} while rendering it "
                f"(--max-task-retries {self.cfg.max_task_retries}); see the Ray worker logs "
                f"(/tmp/ray/session_latest/logs on the worker's node)"
            ) from None
        logger.warning("shard %d: worker %d died (%s); redoing the shard", shard, k, _first_line(exc))
        self.queue.appendleft(shard)
        while self.queue and self.idle:
            self._feed(self.idle.pop())
        self.deaths[k] += 1
        if isinstance(exc, self.died) or self.deaths[k] > self.cfg.max_restarts:
            self._gone(k)
        else:
            self.restarting_since[k] = time.monotonic()
            self._probe(k)

    def _probe_failed(self, k: int, exc: BaseException) -> None:
        """A ready() probe failed: the worker is still restarting (probe again shortly) or dead for good."""
        self.where.pop(k, None)
        since = self.restarting_since.setdefault(k, time.monotonic())
        if isinstance(exc, self.unavailable) and time.monotonic() - since < RESTART_TIMEOUT_S:
            self.reprobe_at[k] = time.monotonic() + REPROBE_INTERVAL_S
        else:
            self._gone(k)

    def _gone(self, k: int) -> None:
        logger.warning("render worker %d is gone for good", k)
        self.where.pop(k, None)
        self.ray.kill(self.workers[k], no_restart=True)
        self._clean(k)

    def _clean(self, k: int, unless: tuple[str, int] | None = None) -> None:
        """Remove the temp dirs of worker ``k``'s lost processes (not of ``unless``: a blip, not a death)."""
        for key, host, pid in self.orphans[k]:
            if (host, pid) != unless:
                _remove_temps_of(self.shard_root, key, host, pid)
        self.orphans[k].clear()

    def _stop(self) -> None:
        for w in self.workers:
            self.ray.kill(w, no_restart=True)
        for k, shard in self.pending.values():  # killed mid-shard (after an error elsewhere)
            if shard is not None and k in self.where:
                self.orphans[k].append((self.keys[shard], *self.where[k]))
        for k in self.orphans:  # best effort: a killed process may take a moment to stop writing
            self._clean(k)


def _check_resources(ray, cfg: EngineConfig) -> None:
    """Fail fast when not even one worker fits the cluster (it would wait forever)."""
    total = ray.cluster_resources()
    for resource, need, flag in (
        ("CPU", cfg.num_cpus_per_worker, "--cpus-per-worker"),
        ("GPU", cfg.num_gpus_per_worker, "--gpus-per-worker"),
    ):
        have = float(total.get(resource, 0.0))
        if need > 0 and have < need:
            raise NsimError(
                f"{flag} {need:g}: the Ray cluster has {have:g} {resource}s, not enough for one worker"
            )
        if need > 0 and have < need * cfg.workers:
            logger.warning(
                "--workers %d x %s %g needs %g %ss; the Ray cluster has %g: some workers wait for resources",
                cfg.workers, flag, need, need * cfg.workers, resource, have,
            )  # fmt: skip


def _shard_error(shard: int, exc: NsimError) -> NsimError:
    try:
        return type(exc)(f"shard {shard}: {exc}")
    except TypeError:  # a subclass with another constructor
        return NsimError(f"shard {shard}: {exc}")


def _times(n: int) -> str:
    return "once" if n == 1 else f"{n} times"


def _first_line(exc: BaseException | None) -> str:
    text = str(exc).strip() if exc is not None else ""
    return text.splitlines()[0] if text else "unknown"


def _check_key(shard: int, key: object) -> None:
    if (
        not isinstance(key, str)
        or not key
        or key.startswith(".")
        or "/" in key
        or os.sep in key
        or "\0" in key
    ):
        raise ValueError(f"run_shards: shard_key({shard}) = {key!r} is not a plain directory name")
    if key.endswith(SUMMARY_SUFFIX):
        raise ValueError(
            f"run_shards: shard_key({shard}) = {key!r} ends in {SUMMARY_SUFFIX}, which the engine uses"
        )


def _temps_of(shard_root: Path, key: str, host: str) -> list[tuple[Path, int]]:
    """(path, writer pid) of every temp dir (and summary temp file) of ``key`` written from ``host``."""
    prefix = f".{key}.{host}."
    found = []
    for p in shard_root.glob(f".{key}.*.tmp*"):
        rest = p.name[len(prefix) :].split(".") if p.name.startswith(prefix) else []
        if len(rest) >= 3 and rest[0].isdigit() and rest[2] == "tmp":
            found.append((p, int(rest[0])))
    return found


def _remove_temps_of(shard_root: Path, key: str, host: str, pid: int) -> None:
    for p, writer in _temps_of(shard_root, key, host):
        if writer == pid:
            _remove(p)


def _remove_stale_temps(shard_root: Path, key: str, host: str) -> None:
    """Temp dirs of ``key`` left on this host by processes that no longer exist."""
    for p, writer in _temps_of(shard_root, key, host):
        if writer != os.getpid() and not _alive(writer):
            _remove(p)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


def _write_atomic(path: Path, text: str, tmp_name: str) -> None:
    """``text`` to ``path`` through a temp file named after the shard's temp dir (``_temps_of`` finds it)."""
    atomic_write_text(path, text, tmp=path.with_name(f"{tmp_name}{SUMMARY_SUFFIX}"))


def _fsync_tree(root: Path) -> None:
    for dirpath, _, filenames in os.walk(root):
        for name in filenames:
            fsync_path(Path(dirpath) / name)
        fsync_path(Path(dirpath))


def shard_temps(shard_root: Path) -> Sequence[Path]:
    """Temp dirs and files under ``shard_root`` (in flight, or left by dead writers): for tests and ``gc``."""
    return sorted(Path(shard_root).glob(".*.tmp*"))
