"""Run independent tasks in-process, in a local process pool, or on a Ray cluster.

``map_tasks(fn, items, engine=..., address=..., workers=...)`` returns ``[fn(item) for item in
items]`` in item order, whichever engine runs them; ``fn`` and the items must be picklable (a
module-level function and plain data) for anything but the sequential engine.

Engines
    ``local`` with ``workers=1`` (the default): sequential, in this process.
    ``local`` with ``workers>1``: a ``concurrent.futures`` process pool (``spawn`` start method,
    so workers never inherit locks or threads from the parent).
    ``ray``: Ray tasks. ``address=None`` uses ``$RAY_ADDRESS`` if set, else starts a private local
    Ray instance (``workers`` CPUs, no dashboard; it never attaches to a stray cluster);
    ``address="auto"`` or ``"HOST:6379"`` joins a running cluster, ``"ray://HOST:10001"`` connects
    through the Ray client (:func:`ray_session`, shared with ``nsim.rendering.engine``). Ray is
    optional and imported only when asked for: ``pip install 'nsim[ray]'``.

Stages that publish from workers rely on the workspace being safe for concurrent writers (it is:
``nsim.workspace.store`` writes under ``tmp/`` and renames into place) and, across machines, on a
shared filesystem that every node mounts at the same path.

On SLURM (Ray >= 2.49), ``ray symmetric-run`` starts Ray on every node of the allocation and runs
the command on the head node only, e.g. in an sbatch script over N nodes::

    HEAD=$(scontrol show hostnames "$SLURM_JOB_NODELIST" | head -n 1)
    srun --nodes="$SLURM_NNODES" --ntasks-per-node=1 \\
        ray symmetric-run --address "$HEAD:6379" --min-nodes "$SLURM_NNODES" -- \\
        nsim simulate --sweep sweep.yaml --engine ray --address auto --summary summary.md

(the workspace, the virtual environment and the sweep file on the shared filesystem; see
docs/cluster.md and ``ray symmetric-run --help``).

User errors (:class:`~nsim.errors.NsimError`) raised by a task come back as an ``NsimError``
naming the task's index; any other exception propagates with its traceback.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import socket
from collections.abc import Callable, Iterator, Sequence
from typing import Any, TypeVar

from nsim.errors import NsimError

T = TypeVar("T")
R = TypeVar("R")

ENGINES = ("local", "ray")
RAY_HOWTO = "pip install 'nsim[ray]' (or 'ray[default]>=2.49')"
#: Seconds a Ray cluster's address gets to accept a TCP connection before ``ray.init`` is tried
#: (``ray.init`` itself retries an unreachable GCS for minutes and has no option to shorten that).
RAY_PROBE_TIMEOUT_S = 3.0
RAY_CLIENT_PORT = 10001  # ray://HOST without a port
_LOOPBACK = ("localhost", "127.0.0.1", "::1")


@dataclasses.dataclass(frozen=True)
class _Failure:
    message: str


@dataclasses.dataclass(frozen=True)
class _Guarded:
    """``fn`` with user errors returned as values (so they cross process boundaries as one line)."""

    fn: Callable[[Any], Any]

    def __call__(self, item: Any) -> Any:
        try:
            return self.fn(item)
        except NsimError as exc:
            return _Failure(str(exc))


def _unwrap(results: Sequence[Any]) -> list[Any]:
    for k, r in enumerate(results):
        if isinstance(r, _Failure):
            raise NsimError(f"task {k}: {r.message}")
    return list(results)


def map_tasks(
    fn: Callable[[T], R],
    items: Sequence[T],
    *,
    engine: str = "local",
    address: str | None = None,
    workers: int = 1,
) -> list[R]:
    """``[fn(item) for item in items]``, run by ``engine`` (see the module docstring)."""
    if engine not in ENGINES:
        raise NsimError(f"--engine: {engine!r} is not one of {', '.join(ENGINES)}")
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise NsimError(f"--workers: expected an int >= 1, got {workers!r}")
    if address is not None and engine != "ray":
        raise NsimError("--address: only the ray engine connects to a cluster (use --engine ray)")
    items = list(items)
    guarded = _Guarded(fn)
    if not items:
        return []
    if engine == "ray":
        return _unwrap(_map_ray(guarded, items, address, workers))
    if workers == 1 or len(items) == 1:
        return _unwrap([guarded(x) for x in items])
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=min(workers, len(items)), mp_context=ctx) as pool:
        return _unwrap(list(pool.map(guarded, items)))


def import_ray():
    """The ``ray`` module, or an :class:`NsimError` saying how to install it."""
    try:
        import ray
    except ImportError:
        raise NsimError(f"--engine ray: Ray is not installed; install it with: {RAY_HOWTO}") from None
    return ray


def resolve_ray_address(address: str | None) -> str:
    """``address``, else ``$RAY_ADDRESS``, else ``"local"`` (a new private instance; never a stray cluster)."""
    if address:
        return address
    return os.environ.get("RAY_ADDRESS") or "local"


def ray_endpoint(address: str) -> tuple[str, int] | None:
    """The ``(host, port)`` that ``ray.init(address)`` dials first: the GCS of ``HOST:PORT``
    (``[IPv6]:PORT`` too), the client server of ``ray://HOST[:PORT]``. None where there is nothing
    to dial before Ray looks it up itself: ``local``, ``auto`` and other ``scheme://`` addresses.
    :class:`NsimError` for anything else that is not ``HOST:PORT``."""
    if address in ("local", "auto"):
        return None
    rest, default_port = address, None
    if "://" in address:
        scheme, _, rest = address.partition("://")
        if scheme != "ray":
            return None
        default_port = RAY_CLIENT_PORT
    rest = rest.rstrip("/")
    if rest.startswith("["):  # [::1]:6379
        host, _, port = rest[1:].partition("]")
        port = port.removeprefix(":")
    elif rest.count(":") == 1:
        host, _, port = rest.partition(":")
    else:
        host, port = rest, ""
    if not port and default_port is not None:
        port = str(default_port)
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise NsimError(f"{address}: not a Ray address (expected HOST:PORT, ray://HOST:PORT, auto or local)")
    return host, int(port)


def _dial(host: str, port: int, timeout_s: float) -> str | None:
    """None if ``host:port`` accepts a TCP connection within ``timeout_s``, else why not."""
    try:
        with socket.create_connection((host, port), timeout=timeout_s):
            return None
    except TimeoutError:
        return f"no answer within {timeout_s:g} s"
    except OSError as exc:
        return exc.strerror or str(exc)


def _node_ip() -> str | None:
    """The address Ray dials instead of a loopback host (it never uses 127.0.0.1 for a GCS)."""
    try:
        from ray._private.services import get_node_ip_address
    except ImportError:
        return None
    try:
        return get_node_ip_address()
    except Exception:  # noqa: BLE001 - a best-effort second host; the loopback probe stands alone
        return None


def _auto_target() -> str | None:
    """What ``ray.init(address="auto")`` joins: ``$RAY_ADDRESS``, else the cluster Ray finds on this
    machine (its ``ray_current_cluster`` file or a running GCS), else None (Ray then fails at once)."""
    env = os.environ.get("RAY_ADDRESS")
    if env and env != "auto":
        return env
    try:
        from ray._private.services import canonicalize_bootstrap_address
    except ImportError:
        return None
    try:
        return canonicalize_bootstrap_address("auto")
    except Exception:  # noqa: BLE001 - nothing found: ray.init says so quickly itself
        return None


def check_ray_address(address: str, where: str, timeout_s: float = RAY_PROBE_TIMEOUT_S) -> None:
    """:class:`NsimError` (one line, naming ``where`` and ``address``) unless something accepts a TCP
    connection at the Ray ``address`` (:func:`ray_endpoint`; ``auto`` as Ray resolves it) within
    ``timeout_s``. A stale ``$RAY_ADDRESS`` then fails in seconds, not after Ray's minutes of retries.
    Only reachability is checked: what answers is Ray's to judge in ``ray.init``."""
    target = _auto_target() if address == "auto" else address
    endpoint = ray_endpoint(target) if target else None
    if endpoint is None:
        return
    host, port = endpoint
    hosts = [host]
    if host in _LOOPBACK and not target.startswith("ray://") and (ip := _node_ip()):
        hosts.append(ip)  # Ray swaps a loopback GCS host for this node's IP
    why = ""
    for h in dict.fromkeys(hosts):
        if (why := _dial(h, port, timeout_s)) is None:
            return
    shown = address if target == address else f"{address} ({target})"
    raise NsimError(f"{where} {shown}: cannot connect to a Ray cluster there ({host}:{port}: {why})")


def check_ray(address: str | None) -> None:
    """Fail now, in one line, if ``--engine ray`` cannot work: Ray missing, or the cluster to join
    (:func:`resolve_ray_address`) not answering. A no-op when this process already runs Ray."""
    ray = import_ray()
    if ray.is_initialized():
        return
    check_ray_address(resolve_ray_address(address), "--address" if address else "$RAY_ADDRESS")


@contextlib.contextmanager
def ray_session(address: str | None, *, num_cpus: int) -> Iterator[Any]:
    """The ``ray`` module, connected for the duration of the block.

    If this process already called ``ray.init`` (a caller's or a test's session), that session is
    used as is and left running. Otherwise Ray is started or joined at :func:`resolve_ray_address`:
    ``"local"`` starts a private instance with ``num_cpus`` logical CPUs, the GPUs Ray detects and
    no dashboard; anything else joins that cluster (``auto``, ``HOST:6379``, ``ray://HOST:10001``)
    and uses its resources; an address where nothing answers fails in seconds
    (:func:`check_ray_address`). What was started or joined here is shut down on exit. Ray's
    ``RAY_AUTH_MODE`` (token authentication, on by default for new clusters since Ray 2.5x) is left
    to the environment; see docs/cluster.md.
    """
    ray = import_ray()
    if ray.is_initialized():
        yield ray
        return
    resolved = resolve_ray_address(address)
    where = "--address" if address else "$RAY_ADDRESS"
    check_ray_address(resolved, where)
    kwargs: dict[str, Any] = {"address": resolved, "log_to_driver": False, "logging_level": logging.WARNING}
    if resolved == "local":
        kwargs.update(num_cpus=num_cpus, include_dashboard=False)
    try:
        ray.init(**kwargs)
    except ConnectionError as exc:
        raise NsimError(f"{where} {resolved}: cannot connect to a Ray cluster there ({exc})") from None
    try:
        yield ray
    finally:
        ray.shutdown()


def _map_ray(guarded: _Guarded, items: list[Any], address: str | None, workers: int) -> list[Any]:
    with ray_session(address, num_cpus=workers) as ray:
        task = ray.remote(num_cpus=1)(_call)
        fn_ref = ray.put(guarded)
        return ray.get([task.remote(fn_ref, x) for x in items])


def _call(fn: Callable[[Any], Any], item: Any) -> Any:
    return fn(item)
