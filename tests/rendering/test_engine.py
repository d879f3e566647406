"""run_shards: the same shard directories from either engine; resumable; a dead worker's shard is redone."""

from __future__ import annotations

import dataclasses
import functools
import os
import sys
from pathlib import Path

import numpy as np
import pytest

from nsim.distributed import RAY_HOWTO
from nsim.errors import ConfigError, InputError, NsimError
from nsim.io.images import write_image
from nsim.rendering.engine import EngineConfig, read_summary, run_shards, shard_temps, summary_path

SHARDS = list(range(6))


@dataclasses.dataclass
class ToyRenderer:
    """Writes one float frame (.npy) and its PNG from (seed, shard); counts its constructions in a file."""

    seed: int
    count_file: str
    crash_shard: int | None = None  # os._exit(1) when rendering this shard: every time, or...
    crash_marker: str | None = None  # ...only the first time, as recorded by this file
    bad_shard: int | None = None  # raise an InputError for this shard

    def __post_init__(self) -> None:
        with open(self.count_file, "a") as f:
            f.write(f"{os.getpid()}\n")

    def render_shard(self, shard: int, out_dir: Path) -> dict:
        if shard == self.crash_shard and (self.crash_marker is None or not os.path.exists(self.crash_marker)):
            if self.crash_marker is not None:
                Path(self.crash_marker).write_text("crashed once\n")
            os._exit(1)
        with open(self.count_file + ".renders", "a") as f:
            f.write(f"{os.getpid()}\n")
        if shard == self.bad_shard:
            raise InputError(f"frame {shard}: bad pose")
        rgb = np.random.default_rng([self.seed, shard]).random((6, 8, 3), dtype=np.float32)
        np.save(out_dir / "frame.npy", rgb)
        write_image(out_dir / "frame.png", rgb)
        return {"frames": 1, "mean": float(rgb.mean())}


def key_of(shard: int) -> str:
    return f"shard-{shard:04d}"


def constructions(count_file: Path) -> int:
    return len(count_file.read_text().splitlines()) if count_file.exists() else 0


def built_once_per_process(count_file: Path) -> set[str]:
    """The pids of the processes that rendered; checks each of them built its renderer exactly once."""
    built = count_file.read_text().split()
    rendered_by = set(Path(f"{count_file}.renders").read_text().split())
    assert len(built) == len(set(built)) and rendered_by <= set(built)
    return rendered_by


def tree(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def make_factory(tmp_path: Path, name: str, **kw):
    return functools.partial(ToyRenderer, seed=7, count_file=str(tmp_path / f"{name}.count"), **kw)


@pytest.fixture(scope="module")
def local_reference(tmp_path_factory) -> Path:
    """The shards rendered by the local engine: the reference for every Ray run."""
    tmp = tmp_path_factory.mktemp("local")
    root = tmp / "shards"
    results = run_shards(make_factory(tmp, "local"), SHARDS, root, key_of, EngineConfig())
    assert constructions(tmp / "local.count") == 1  # one renderer, built once, in this process
    assert all(r.rendered for r in results.values())
    return root


@pytest.fixture(scope="module")
def ray_cluster():
    """One private Ray instance for the module (the engine uses it and leaves it running)."""
    ray = pytest.importorskip("ray")
    mp = pytest.MonkeyPatch()
    mp.setenv("RAY_AUTH_MODE", "disabled")
    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()
    mp.undo()


def test_local_publishes_every_shard(local_reference):
    names = [key_of(i) for i in SHARDS]
    assert sorted(p.name for p in local_reference.iterdir()) == sorted(
        names + [n + ".summary.json" for n in names]
    )
    for i in SHARDS:
        assert set(tree(local_reference / key_of(i))) == {
            "frame.npy",
            "frame.png",
        }  # only the renderer's files
        assert summary_path(local_reference / key_of(i)).is_file()
        expected = np.random.default_rng([7, i]).random((6, 8, 3), dtype=np.float32)
        np.testing.assert_array_equal(np.load(local_reference / key_of(i) / "frame.npy"), expected)
        assert read_summary(local_reference / key_of(i)) == {"frames": 1, "mean": float(expected.mean())}
    assert shard_temps(local_reference) == []


def test_local_rerun_renders_nothing_and_resumes_one(local_reference, tmp_path):
    root = tmp_path / "shards"
    factory = make_factory(tmp_path, "again")
    run_shards(factory, SHARDS, root, key_of, EngineConfig())
    again = run_shards(factory, SHARDS, root, key_of, EngineConfig())
    assert not any(r.rendered for r in again.values()) and constructions(tmp_path / "again.count") == 1
    assert [r.summary for r in again.values()] == [read_summary(local_reference / key_of(i)) for i in SHARDS]


def test_ray_matches_local_and_resumes(ray_cluster, local_reference, tmp_path):
    root = tmp_path / "shards"
    count = tmp_path / "ray.count"
    factory = make_factory(tmp_path, "ray")
    cfg = EngineConfig(engine="ray", workers=2)
    results = run_shards(factory, SHARDS, root, key_of, cfg)
    assert list(results) == SHARDS and all(r.rendered for r in results.values())
    assert [Path(r) for r in results.values()] == [root / key_of(i) for i in SHARDS]  # path-like
    assert tree(root) == tree(local_reference)  # byte-identical, whichever worker rendered what
    # a worker builds its renderer once (the second may not even start before the first is done)
    n_built = constructions(count)
    assert 1 <= n_built <= 2 and len(built_once_per_process(count)) <= 2
    assert [r.summary for r in results.values()] == [
        read_summary(local_reference / key_of(i)) for i in SHARDS
    ]

    again = run_shards(factory, SHARDS, root, key_of, cfg)  # all present: no worker is even started
    assert not any(r.rendered for r in again.values()) and constructions(count) == n_built

    victim = root / key_of(4)
    for p in victim.iterdir():
        p.unlink()
    victim.rmdir()  # (its summary stays: it is overwritten)
    resumed = run_shards(factory, SHARDS, root, key_of, cfg)
    assert [i for i, r in resumed.items() if r.rendered] == [4]
    assert constructions(count) == n_built + 1  # one worker for the one missing shard
    assert tree(root) == tree(local_reference) and shard_temps(root) == []


def test_ray_redoes_the_shard_of_a_dead_worker(ray_cluster, local_reference, tmp_path):
    root = tmp_path / "shards"
    marker = tmp_path / "crashed"
    factory = make_factory(tmp_path, "crash", crash_shard=3, crash_marker=str(marker))
    results = run_shards(factory, SHARDS, root, key_of, EngineConfig(engine="ray", workers=2))
    assert marker.exists()  # the worker did die on shard 3...
    assert results[3].rendered and tree(root) == tree(local_reference)  # ...and the shard was redone
    assert shard_temps(root) == []  # the dead worker's temp dir was removed
    built_once_per_process(tmp_path / "crash.count")  # the restarted worker (if it came in time) rebuilt it


def test_ray_gives_up_after_max_task_retries(ray_cluster, tmp_path):
    factory = make_factory(tmp_path, "doomed", crash_shard=1)  # dies on shard 1 every time
    cfg = EngineConfig(engine="ray", workers=1, max_restarts=2, max_task_retries=1)
    with pytest.raises(
        NsimError, match=r"^shard 1: its worker died 2 times while rendering it \(--max-task-retries 1\)"
    ):
        run_shards(factory, [0, 1], tmp_path / "shards", key_of, cfg)
    assert (tmp_path / "shards" / key_of(0)).is_dir() and shard_temps(tmp_path / "shards") == []


def test_user_errors_name_the_shard(ray_cluster, tmp_path):
    factory = make_factory(tmp_path, "bad", bad_shard=2)
    for cfg in (EngineConfig(), EngineConfig(engine="ray", workers=1)):
        root = tmp_path / cfg.engine
        with pytest.raises(InputError, match=r"^shard 2: frame 2: bad pose$"):
            run_shards(factory, [0, 1, 2], root, key_of, cfg)
        assert shard_temps(root) == [] and not (root / key_of(2)).exists()


def test_ray_needs_resources_for_one_worker(ray_cluster, tmp_path):
    cfg = EngineConfig(engine="ray", num_gpus_per_worker=0.5)
    with pytest.raises(NsimError, match=r"--gpus-per-worker 0.5: the Ray cluster has 0 GPUs"):
        run_shards(make_factory(tmp_path, "gpu"), [0], tmp_path / "shards", key_of, cfg)


def test_missing_ray_says_how_to_install(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    with pytest.raises(NsimError) as err:
        run_shards(make_factory(tmp_path, "x"), [0], tmp_path / "shards", key_of, EngineConfig(engine="ray"))
    assert RAY_HOWTO in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"engine": "dask"}, "--engine: 'dask' is not one of local, ray"),
        ({"engine": "ray", "workers": 0}, "--workers: expected an int >= 1, got 0"),
        ({"workers": 2}, "--workers: the local engine renders in this process"),
        ({"address": "auto"}, "--address: only the ray engine"),
        ({"engine": "ray", "num_gpus_per_worker": -1}, "--gpus-per-worker: expected a number >= 0"),
        (
            {"engine": "ray", "num_gpus_per_worker": 1.5},
            "--gpus-per-worker: above 1 it must be a whole number",
        ),
        ({"engine": "ray", "max_restarts": -1}, "--max-restarts: expected an int >= 0, got -1"),
    ],
)
def test_bad_config(kwargs, message):
    with pytest.raises(ConfigError, match=message):
        EngineConfig(**kwargs)


def test_bad_keys(tmp_path):
    factory = make_factory(tmp_path, "keys")
    with pytest.raises(ValueError, match="same key"):
        run_shards(factory, [0, 1], tmp_path, lambda i: "k", EngineConfig())
    with pytest.raises(ValueError, match="not a plain directory name"):
        run_shards(factory, [0], tmp_path, lambda i: "../escape", EngineConfig())
    assert constructions(tmp_path / "keys.count") == 0


class RacingRenderer:
    """Another writer publishes the same shard (with the same summary: renderers are deterministic) meanwhile."""

    def render_shard(self, shard: int, out_dir: Path) -> dict:
        (out_dir / "mine.txt").write_text("mine\n")
        final = out_dir.parent / key_of(shard)
        final.mkdir()
        (final / "theirs.txt").write_text("theirs\n")
        summary_path(final).write_text('{"summary": {"frames": 1}}\n')
        return {"frames": 1}


def test_a_writer_that_loses_the_rename_race_drops_its_copy(tmp_path):
    results = run_shards(RacingRenderer, [0], tmp_path, key_of, EngineConfig())
    assert not results[0].rendered and results[0].summary == {"frames": 1}
    assert [p.name for p in (tmp_path / key_of(0)).iterdir()] == ["theirs.txt"] and shard_temps(
        tmp_path
    ) == []


def test_debris_of_dead_writers_on_this_host_is_removed(tmp_path):
    import socket

    dead = tmp_path / f".{key_of(0)}.{socket.gethostname()}.999999999.0123abcd.tmp"  # no such pid
    (dead / "half").mkdir(parents=True)
    run_shards(make_factory(tmp_path, "debris"), [0], tmp_path / "", key_of, EngineConfig())
    assert not dead.exists() and shard_temps(tmp_path) == []
