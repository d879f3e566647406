from __future__ import annotations

import json
import multiprocessing as mp
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from nsim.errors import InputError, WorkspaceError
from nsim.workspace.store import MANIFEST, Store, manifest_id
from tests.workspace.toy import ToyConfig, toy_publish

REPO = Path(__file__).resolve().parents[2]


def test_publish_then_cache_hit_is_fast(store):
    art, hit = toy_publish(store, ToyConfig())
    assert not hit
    assert (art.path / "a.txt").read_text() == "hellohellohello"
    t0 = time.process_time()  # CPU time: a busy machine does not count
    again, hit = toy_publish(store, ToyConfig())
    dt = time.process_time() - t0
    assert hit and again.id == art.id
    assert dt < 1.0, f"cache hit took {dt:.3f} s of CPU time"


def test_artifact_is_read_only_and_manifest_complete(store):
    art, _ = toy_publish(store, ToyConfig(), ref="toy/main")
    m = art.manifest
    assert m["id"] == art.id == manifest_id(m)
    assert set(m["files"]) == {"a.txt", "sub/b.bin"}
    assert m["files"]["sub/b.bin"]["size"] == 256 * 3
    assert m["fingerprint"]["nsim"]
    assert {"wall_time_s", "created_utc", "host"} <= set(m["timing"])
    assert m["summary"] == {"n": 3}
    assert not os.access(art.path / "a.txt", os.W_OK) or os.geteuid() == 0
    assert oct((art.path / "a.txt").stat().st_mode & 0o777) == oct(0o444)
    assert store.refs()["toy/main"] == art.id
    assert store.refs()["capture/latest"] == art.id


def test_id_is_content_addressed_across_workspaces(tmp_path):
    a, _ = toy_publish(Store(tmp_path / "one"), ToyConfig())
    time.sleep(1.1)  # a different timestamp must not change the id
    b, _ = toy_publish(Store(tmp_path / "two"), ToyConfig())
    c, _ = toy_publish(Store(tmp_path / "two"), ToyConfig(payload="other"))
    assert a.id == b.id
    assert c.id != a.id


def test_failed_stage_leaves_nothing(store):
    key = store.action_key("toy", 1, ToyConfig())
    with pytest.raises(RuntimeError, match="boom"):
        with store.publish(kind="capture", stage="toy", version=1, key=key, config=ToyConfig()) as out:
            (out.dir / "half.txt").write_text("half")
            raise RuntimeError("boom")
    assert store.all_ids() == []
    assert list((store.root / "tmp").iterdir()) == []
    assert store.lookup(key) is None


@pytest.mark.parametrize("target", ["a.txt", "sub/b.bin", MANIFEST])
def test_verify_catches_a_flipped_byte(store, run_cli, target):
    art, _ = toy_publish(store, ToyConfig())
    assert store.verify(art.id) == []
    p = art.path / target
    os.chmod(p, 0o644)
    data = bytearray(p.read_bytes())
    data[len(data) // 2] ^= 0x01
    p.write_bytes(bytes(data))
    problems = store.verify(art.id)
    assert [pr.file for pr in problems] == [target]
    code, out, _ = run_cli("verify", art.id[:8], workspace=store.root)
    assert code == 1
    assert target in out and "CORRUPT" in out


def test_verify_catches_missing_and_extra_files(store):
    art, _ = toy_publish(store, ToyConfig())
    os.chmod(art.path, 0o755)
    (art.path / "extra.txt").write_text("x")
    os.chmod(art.path / "sub", 0o755)
    (art.path / "sub" / "b.bin").unlink()
    reasons = {p.file: p.reason for p in store.verify(art.id)}
    assert reasons == {"sub/b.bin": "missing", "extra.txt": "file is not listed in the manifest"}


def test_resolve_by_id_prefix_ref_and_kind(store):
    art, _ = toy_publish(store, ToyConfig(), ref="capture/lab")
    assert store.resolve(art.id) == art.id
    assert store.resolve(art.id[:6]) == art.id
    assert store.resolve("capture/lab") == art.id
    with pytest.raises(InputError, match="no artifact or ref named 'nothing'"):
        store.resolve("nothing")
    with pytest.raises(InputError, match="is a capture artifact, expected poses"):
        store.resolve("capture/lab", kind="poses")
    with pytest.raises(InputError, match="invalid ref name"):
        store.set_ref("../escape", art.id)
    with pytest.raises(WorkspaceError, match="no such artifact"):
        store.set_ref("dangling", "0" * 64)


def test_ambiguous_prefix_is_reported(store):
    art, _ = toy_publish(store, ToyConfig())
    # a second object sharing the first 6 hex digits (forged: real collisions are too rare to wait for)
    twin = art.id[:6] + ("0" if art.id[6] != "0" else "1") + art.id[7:]
    twin_dir = store.object_path(twin)
    twin_dir.mkdir(parents=True)
    (twin_dir / MANIFEST).write_text((art.path / MANIFEST).read_text())
    with pytest.raises(InputError, match="ambiguous"):
        store.resolve(art.id[:6])
    assert store.resolve(art.id[:7]) == art.id


def test_gc_keeps_reachable_and_inputs(store):
    base, _ = toy_publish(store, ToyConfig(payload="base"))
    child, _ = toy_publish(store, ToyConfig(payload="child"), inputs={"capture": base.id}, ref="keep/child")
    orphan, _ = toy_publish(store, ToyConfig(payload="orphan"))
    store.delete_ref("capture/latest")
    assert store.gc(dry_run=True).objects == []  # younger than the grace period, and held by this process
    store.release()
    assert store.gc(dry_run=True).objects == []  # still younger than the grace period
    dry = store.gc(dry_run=True, grace_s=0)
    assert dry.objects == [orphan.id]
    assert orphan.id in store.all_ids()
    report = store.gc(grace_s=0)
    assert report.objects == [orphan.id]
    assert sorted(store.all_ids()) == sorted([base.id, child.id])
    assert store.lookup(store.action_key("toy", 1, ToyConfig(payload="orphan"), {}, seed=0)) is None
    # the orphan can be rebuilt afterwards
    again, hit = toy_publish(store, ToyConfig(payload="orphan"))
    assert not hit and again.id == orphan.id


_KILL_SCRIPT = """
import sys
from nsim.workspace.store import Store
sys.path.insert(0, {repo!r})
from tests.workspace.toy import ToyConfig, toy_publish
toy_publish(Store({ws!r}), ToyConfig(payload="killed"), ref="toy/killed", slow_kill_after={flag!r})
"""


def test_sigkill_mid_publish_leaves_no_artifact(store, tmp_path, run_cli):
    flag = tmp_path / "flag"
    script = _KILL_SCRIPT.format(repo=str(REPO), ws=str(store.root), flag=str(flag))
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True)
    assert proc.returncode == -9, proc.stderr.decode()
    assert flag.read_text() == "writing"
    assert store.all_ids() == []
    assert store.broken_refs() == {}
    assert "toy/killed" not in store.refs()
    debris = list((store.root / "tmp").iterdir())
    assert len(debris) == 1
    # a rerun completes
    art, hit = toy_publish(store, ToyConfig(payload="killed"), ref="toy/killed")
    assert not hit and store.verify(art.id) == []
    code, out, _ = run_cli("gc", workspace=store.root)
    assert code == 0 and "1 tmp entries" in out
    assert list((store.root / "tmp").iterdir()) == []
    assert store.all_ids() == [art.id]


def _publish_in_process(root: str, barrier) -> str:
    barrier.wait()
    art, _ = toy_publish(Store(root), ToyConfig(payload="race", repeat=50000))
    return art.id


def test_eight_concurrent_writers_end_with_one_artifact(store):
    ctx = mp.get_context("fork")
    with ctx.Manager() as manager:
        barrier = manager.Barrier(8)
        with ctx.Pool(8) as pool:
            ids = pool.starmap(_publish_in_process, [(str(store.root), barrier)] * 8)
    assert len(set(ids)) == 1
    assert store.all_ids() == [ids[0]]
    assert store.verify(ids[0]) == []
    assert list((store.root / "tmp").iterdir()) == []


def test_workspace_refuses_foreign_directories(tmp_path):
    (tmp_path / "foreign").mkdir()
    (tmp_path / "foreign" / "notes.txt").write_text("mine")
    with pytest.raises(WorkspaceError, match="not an nsim workspace"):
        Store(tmp_path / "foreign")
    (tmp_path / "afile").write_text("x")
    with pytest.raises(WorkspaceError, match="not a directory"):
        Store(tmp_path / "afile")
    marker_ws = tmp_path / "bad"
    marker_ws.mkdir()
    (marker_ws / "nsim-workspace.json").write_text("{not json")
    with pytest.raises(WorkspaceError, match="corrupt workspace marker"):
        Store(marker_ws)


def test_manifest_is_valid_json_with_sorted_files(store):
    art, _ = toy_publish(store, ToyConfig())
    raw = json.loads((art.path / MANIFEST).read_text())
    assert list(raw["files"]) == sorted(raw["files"])
