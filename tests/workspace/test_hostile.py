"""The workspace under hostile files, kills mid-gc and concurrent processes (issue 19).

Each test first builds the situation that broke the store before (a planted ref, a damaged
manifest, a gc killed between two steps) and then checks what must hold now.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from nsim.errors import InputError, WorkspaceError
from nsim.workspace.store import MANIFEST, Store
from tests.workspace.toy import ToyConfig, toy_publish

REPO = Path(__file__).resolve().parents[2]


def _writable(path: Path) -> None:
    for dirpath, _dirs, files in os.walk(path):
        os.chmod(dirpath, 0o755)
        for f in files:
            if not os.path.islink(os.path.join(dirpath, f)):
                os.chmod(os.path.join(dirpath, f), 0o644)


def _one_line_error(code: int, err: str) -> None:
    assert code == 2
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert "Traceback" not in err


# ------------------------------------------------------------------------------------ ids and paths
def test_ref_climbing_out_of_the_workspace_is_refused(store, tmp_path, run_cli):
    art, _ = toy_publish(store, ToyConfig(), ref="capture/good")
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / MANIFEST).write_text(json.dumps({"kind": "capture", "stage": "x", "files": {}, "inputs": {}}))
    (store.root / "refs" / "capture" / "evil").write_text("../../../../" + str(outside) + "\n")
    with pytest.raises(WorkspaceError, match="does not hold an artifact id"):
        store.resolve("capture/evil")
    code, _, err = run_cli("show", "capture/evil", workspace=store.root)
    _one_line_error(code, err)
    assert "capture/evil" in err
    # a gc is not fooled into keeping or touching anything outside
    assert store.gc(grace_s=0).objects == []
    assert (outside / MANIFEST).is_file()
    assert store.resolve("capture/good") == art.id


def test_absolute_id_in_the_run_cache_is_a_miss(store, tmp_path):
    cfg = ToyConfig(payload="cache")
    art, _ = toy_publish(store, cfg)
    key = store.action_key("toy", 1, cfg, {}, seed=0)
    entry = store.root / "actions" / key[:2] / key
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / MANIFEST).write_text("{}")
    entry.write_text(json.dumps({"id": str(foreign)}))
    assert store.lookup(key) is None
    again, hit = toy_publish(store, cfg, ref="capture/again")
    assert not hit and again.id == art.id and again.path.parent.parent == store.root / "objects"
    assert store.lookup(key).id == art.id
    with pytest.raises(WorkspaceError, match="not an artifact id"):
        store.set_ref("capture/abs", str(foreign))
    with pytest.raises(WorkspaceError, match="not an artifact id"):
        store.get(str(foreign))


@pytest.mark.parametrize("content", [b"\x00\xff\xfe\n", b"[]", b'{"id": 5}', b"not json"])
def test_binary_or_odd_cache_entries_and_refs_do_not_crash(store, run_cli, content):
    cfg = ToyConfig(payload="odd")
    art, _ = toy_publish(store, cfg, ref="capture/ok")
    key = store.action_key("toy", 1, cfg, {}, seed=0)
    (store.root / "actions" / key[:2] / key).write_bytes(content)
    (store.root / "refs" / "capture" / "odd").write_bytes(content)
    assert store.lookup(key) is None
    for args in (("ls",), ("gc", "--dry-run"), ("verify",)):
        code, _, err = run_cli(*args, workspace=store.root)
        assert code == 0 and "Traceback" not in err, (args, err)
    code, _, err = run_cli("ls", workspace=store.root)
    assert "capture/odd: does not hold an artifact id" in err
    code, _, err = run_cli("show", "capture/odd", workspace=store.root)
    _one_line_error(code, err)
    # a stage whose cache entry is damaged recomputes instead of crashing
    code, _, err = run_cli("capture", "synth", "--preset", "tiny", "--tag", "capture/odd", workspace=store.root)
    assert code == 0, err
    assert store.resolve("capture/odd") != art.id
    assert store.resolve("capture/ok") == art.id


def test_manifest_names_outside_the_artifact_are_refused_not_hashed(store, run_cli):
    art, _ = toy_publish(store, ToyConfig(), ref="capture/m")
    _writable(art.path)
    m = json.loads((art.path / MANIFEST).read_text())
    m["files"]["../../../../etc/hostname"] = {"sha256": "0" * 64, "size": 1}
    (art.path / MANIFEST).write_text(json.dumps(m))
    problems = store.verify(art.id)
    assert [p.file for p in problems] == [MANIFEST]
    assert "not a relative, normalised path" in problems[0].reason
    code, out, err = run_cli("verify", "capture/m", workspace=store.root)
    assert code == 1 and "CORRUPT" in out and "Traceback" not in err


def test_symlink_replacing_a_listed_file_is_reported_and_refused(store, tmp_path, run_cli):
    art, _ = toy_publish(store, ToyConfig(), ref="capture/s")
    secret = tmp_path / "secret.txt"
    secret.write_text("hellohellohello")  # same bytes: only the link gives it away
    os.chmod(art.path, 0o755)
    (art.path / "a.txt").chmod(0o644)
    (art.path / "a.txt").unlink()
    (art.path / "a.txt").symlink_to(secret)
    (art.path / "extra").symlink_to("/etc")
    reasons = {p.file: p.reason for p in store.verify(art.id)}
    assert reasons == {"a.txt": "is a symbolic link (not followed)",
                       "extra": "symbolic link is not listed in the manifest"}
    code, out, _ = run_cli("verify", art.id, workspace=store.root)
    assert code == 1 and "a.txt" in out
    reader = Store(store.root)
    with pytest.raises(WorkspaceError, match="is damaged: (a.txt|extra)"):
        reader.get(art.id)
    with pytest.raises(WorkspaceError, match="symbolic link"):
        Store(store.root, checked=False).get(art.id).file("a.txt")


# ------------------------------------------------------------------------------------ stages check on read
def test_a_stage_refuses_a_tampered_input_and_publishes_nothing(store, run_cli):
    code, out, err = run_cli("capture", "synth", "--preset", "tiny", "--tag", "capture/t", workspace=store.root)
    assert code == 0, err
    cap = store.resolve("capture/t")
    before = sorted(store.all_ids())
    path = store.get(cap).path / "transforms.json"
    os.chmod(path, 0o644)
    data = json.loads(path.read_text())
    data["frames"][0]["transform_matrix"][0][3] += 0.5  # a pose edited by hand
    path.write_text(json.dumps(data))
    code, _, err = run_cli("reconstruct", "--preset", "tiny", "capture/t", workspace=store.root)
    _one_line_error(code, err)
    assert cap[:12] in err and "transforms.json" in err
    assert sorted(store.all_ids()) == before
    assert list((store.root / "tmp").iterdir()) == []


def test_check_on_read_uses_the_marker_and_sees_a_rewrite(store, monkeypatch):
    import nsim.workspace.verify as st

    art, _ = toy_publish(store, ToyConfig(repeat=4))
    hashed = []
    real_sha = st.sha256_file
    monkeypatch.setattr(st, "sha256_file", lambda p: hashed.append(p) or real_sha(p))
    Store(store.root).get(art.id)  # the publish left a marker: no re-hash needed
    assert hashed == []
    marker = store.root / "verified" / art.id[:2] / art.id
    marker.unlink()
    Store(store.root).get(art.id)  # no marker: one full check, which writes it again
    assert len(hashed) == 2 and marker.is_file()
    Store(store.root).get(art.id)
    assert len(hashed) == 2
    p = art.path / "sub" / "b.bin"
    os.chmod(art.path / "sub", 0o755)
    os.chmod(p, 0o644)
    data = bytearray(p.read_bytes())
    data[3] ^= 0xFF
    st = p.stat()
    p.write_bytes(bytes(data))
    os.utime(p, ns=(st.st_atime_ns, st.st_mtime_ns))  # same size and mtime: only ctime gives it away
    with pytest.raises(WorkspaceError, match="sub/b.bin: content digest"):
        Store(store.root).get(art.id)


def test_force_republish_repairs_a_corrupt_copy(store):
    cfg = ToyConfig(payload="fix")
    art, _ = toy_publish(store, cfg, ref="capture/fix")
    p = art.path / "a.txt"
    os.chmod(p, 0o644)
    p.write_text("fiXfixfix")
    assert store.verify(art.id) != []
    key = store.action_key("toy", 1, cfg, {}, seed=0)
    with store.publish(kind="capture", stage="toy", version=1, key=key, config=cfg, seed=0) as out:
        (out.dir / "sub").mkdir()
        (out.dir / "a.txt").write_text(cfg.payload * cfg.repeat)
        (out.dir / "sub" / "b.bin").write_bytes(bytes(range(256)) * cfg.repeat)
        out.summary["n"] = cfg.repeat
    assert out.repaired and not out.raced and out.ref == art.id
    assert store.verify(art.id) == []
    assert Store(store.root).get(art.id).id == art.id


def test_half_removed_object_is_repaired_by_the_next_publish(store, run_cli):
    cfg = ToyConfig(payload="half")
    art, _ = toy_publish(store, cfg)
    _writable(art.path)
    (art.path / MANIFEST).unlink()  # what an interrupted rmtree used to leave
    assert store.damaged_ids() == [art.id]
    assert store.lookup(store.action_key("toy", 1, cfg, {}, seed=0)) is None
    code, _, err = run_cli("ls", workspace=store.root)
    assert code == 0 and "has no manifest" in err
    again, hit = toy_publish(store, cfg)
    assert not hit and again.id == art.id
    assert store.verify(art.id) == [] and store.damaged_ids() == []


# ------------------------------------------------------------------------------------ gc
def test_gc_keeps_young_objects_and_leased_ones(store, tmp_path):
    young, _ = toy_publish(store, ToyConfig(payload="young"))
    store.delete_ref("capture/latest")
    store.release()
    assert store.gc().objects == []  # default grace: an hour
    assert young.id in store.all_ids()
    # another live process holding the id keeps it even with no grace at all
    flag = tmp_path / "held"
    holder = subprocess.Popen([sys.executable, "-c", (
        f"import sys, time, pathlib; sys.path.insert(0, {str(REPO)!r});"
        "from nsim.workspace.store import Store;"
        f"s = Store({str(store.root)!r}); s.get({young.id!r}); pathlib.Path({str(flag)!r}).write_text('1'); time.sleep(3600)"
    )])
    try:
        for _ in range(12000):  # up to 10 min for the holder to start on a busy machine; on as soon as it holds
            if flag.exists():
                break
            time.sleep(0.05)
        assert flag.exists(), "the holder process never started"
        report = store.gc(grace_s=0)
        assert report.objects == [] and report.kept_leased == 1
    finally:
        holder.kill()
        holder.wait()
    report = store.gc(grace_s=0)  # the holder is dead: its lease expired
    assert report.objects == [young.id] and report.leases
    assert list((store.root / "leases").iterdir()) == []


def test_cache_hit_moves_latest(store):
    a, _ = toy_publish(store, ToyConfig(payload="a"))
    b, _ = toy_publish(store, ToyConfig(payload="b"))
    assert store.refs()["capture/latest"] == b.id
    hit, was_hit = toy_publish(store, ToyConfig(payload="a"))
    assert was_hit and hit.id == a.id
    assert store.refs()["capture/latest"] == a.id


_GC_KILL = """
import os, signal, sys
sys.path.insert(0, {repo!r})
import nsim.workspace.store as st
calls = {{"n": 0}}
target = ({fn!r}, {nth})
orig = getattr(st, target[0]) if hasattr(st, target[0]) else getattr(st.os, target[0])
def wrapped(*a, **k):
    calls["n"] += 1
    if calls["n"] == target[1]:
        os.kill(os.getpid(), signal.SIGKILL)
    return orig(*a, **k)
if hasattr(st, target[0]):
    setattr(st, target[0], wrapped)
else:
    st.os.rename = wrapped
st.Store({ws!r}, create=False, checked=False).gc(grace_s=0)
"""


@pytest.mark.parametrize("fn,nth", [("rename", 1), ("rename", 2), ("rename", 3), ("remove_tree", 1),
                                    ("remove_tree", 2), ("_make_writable", 1)])
def test_gc_killed_at_each_step_loses_nothing(store, run_cli, fn, nth):
    keep = [toy_publish(store, ToyConfig(payload=f"keep{i}"), ref=f"capture/k{i}")[0] for i in range(2)]
    child, _ = toy_publish(store, ToyConfig(payload="child"), inputs={"capture": keep[0].id}, ref="capture/child")
    drop = [toy_publish(store, ToyConfig(payload=f"drop{i}"))[0] for i in range(3)]
    store.delete_ref("capture/latest")
    store.release()
    proc = subprocess.run([sys.executable, "-c", _GC_KILL.format(repo=str(REPO), ws=str(store.root), fn=fn, nth=nth)],
                          capture_output=True)
    assert proc.returncode == -signal.SIGKILL, proc.stderr.decode()
    # right after the kill: every referenced object is whole, and readers see whole objects or none
    for art in [*keep, child]:
        assert store.verify(art.id) == []
        assert Store(store.root).get(art.id).id == art.id
    for i, art in enumerate(drop):
        assert art.id not in store.all_ids() or store.verify(art.id) == []
        hit = store.lookup(store.action_key("toy", 1, ToyConfig(payload=f"drop{i}"), {}, seed=0))
        assert hit is None or (hit.id == art.id and store.verify(art.id) == [])
    store.release()  # the lookups above hold what they found, as a stage would
    code, out, err = run_cli("gc", "--grace", "0", workspace=store.root)
    assert code == 0, err
    assert sorted(store.all_ids()) == sorted(a.id for a in [*keep, child])
    assert store.damaged_ids() == [] and list((store.root / "trash").iterdir()) == []
    # a dropped artifact publishes again, whole
    again, hit = toy_publish(store, ToyConfig(payload="drop0"))
    assert not hit and again.id == drop[0].id and store.verify(again.id) == []


def test_victim_referenced_during_gc_is_restored(store, monkeypatch):
    victim, _ = toy_publish(store, ToyConfig(payload="victim"))
    store.delete_ref("capture/latest")
    store.release()
    other = Store(store.root, checked=False)
    real_to_trash = Store._to_trash

    def to_trash_then_tag(self, path, art_id, suffix="gc"):
        # a colleague's 'nsim tag' lands after gc computed its keep-set, before the victim moves
        if art_id == victim.id:
            (self.root / "refs" / "capture" / "late").write_text(art_id + "\n")
        return real_to_trash(self, path, art_id, suffix)

    monkeypatch.setattr(Store, "_to_trash", to_trash_then_tag)
    report = store.gc(grace_s=0)
    assert report.restored == [victim.id] and report.objects == []
    assert other.get(victim.id).id == victim.id and store.verify(victim.id) == []


_LOOKUP = """
import sys
sys.path.insert(0, {repo!r})
from nsim.workspace.store import Store
from tests.workspace.toy import ToyConfig
s = Store({ws!r})
hit = s.lookup(s.action_key("toy", 1, ToyConfig(payload="old"), {{}}, seed=0))
if hit is not None:
    s.set_ref("capture/found", hit.id)
    (hit.path / "a.txt").read_text()
print("hit" if hit is not None else "miss")
"""


def test_a_lookup_during_gc_waits_and_never_sees_an_object_vanish(store, monkeypatch):
    old, _ = toy_publish(store, ToyConfig(payload="old"))
    store.delete_ref("capture/latest")
    store.release()
    real_to_trash = Store._to_trash
    seen = {}

    def to_trash_with_a_stage_looking(self, path, art_id, suffix="gc"):
        # a stage's cache lookup arrives after gc chose its victims, before they move
        proc = subprocess.Popen([sys.executable, "-c", _LOOKUP.format(repo=str(REPO), ws=str(self.root))],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=REPO)
        time.sleep(1.0)
        seen["blocked"] = proc.poll() is None
        seen["proc"] = proc
        return real_to_trash(self, path, art_id, suffix)

    monkeypatch.setattr(Store, "_to_trash", to_trash_with_a_stage_looking)
    report = store.gc(grace_s=0)
    out, err = seen["proc"].communicate(timeout=900)
    assert seen["blocked"], "the lookup did not wait for gc"
    assert seen["proc"].returncode == 0, err.decode()
    assert out.decode().split() == ["miss"]
    assert report.objects == [old.id] and old.id not in store.all_ids()


_KILL_BETWEEN = """
import os, signal, sys
sys.path.insert(0, {repo!r})
import nsim.workspace.store as st
from tests.workspace.toy import ToyConfig, toy_publish
orig = st.Store.{method}
def wrapped(self, *a, **k):
    {cond}
    return orig(self, *a, **k)
st.Store.{method} = wrapped
toy_publish(st.Store({ws!r}), ToyConfig(payload="between"), ref="capture/between")
"""


@pytest.mark.parametrize("method,cond", [
    ("set_ref", "os.kill(os.getpid(), signal.SIGKILL) if a[0] == 'capture/latest' else None"),
    ("set_ref", "os.kill(os.getpid(), signal.SIGKILL) if a[0] == 'capture/between' else None"),
    ("_record_action", "os.kill(os.getpid(), signal.SIGKILL)"),
])
def test_kill_between_object_ref_and_cache_record(store, method, cond):
    script = _KILL_BETWEEN.format(repo=str(REPO), ws=str(store.root), method=method, cond=cond)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, cwd=REPO)
    assert proc.returncode == -signal.SIGKILL, proc.stderr.decode()
    cfg = ToyConfig(payload="between")
    key = store.action_key("toy", 1, cfg, {}, seed=0)
    hit = store.lookup(key)
    # the cache never names an object that is not there, and what a ref names survives gc
    assert hit is None or store.verify(hit.id) == []
    store.release()
    store.gc(grace_s=0)
    for name, art_id in store.refs().items():
        assert store.verify(art_id) == [], name
    if (hit := store.lookup(key)) is not None:
        assert store.verify(hit.id) == []
    art, _ = toy_publish(store, cfg, ref="capture/between")
    assert store.verify(art.id) == [] and store.lookup(key).id == art.id
    assert store.refs()["capture/between"] == art.id == store.refs()["capture/latest"]


# ------------------------------------------------------------------------------------ one line, early
def test_tag_destinations_are_checked_before_work(store, run_cli, monkeypatch):
    art, _ = toy_publish(store, ToyConfig(), ref="capture/x")
    import nsim.synth.room

    def no_work(*args, **kwargs):
        raise AssertionError("the capture started before its --tag was checked")

    monkeypatch.setattr(nsim.synth.room, "make_room", no_work)
    for name, msg in (("capture", "folder of refs"), ("capture/latest/sub", "exists, so no ref"),
                      ("../evil", "invalid ref name")):
        code, _, err = run_cli("tag", "capture/x", name, workspace=store.root)
        _one_line_error(code, err)
        assert msg in err
        before = sorted(store.all_ids())
        code, _, err = run_cli("capture", "synth", "--preset", "tiny", "--tag", name, workspace=store.root)
        _one_line_error(code, err)
        assert msg in err
        assert sorted(store.all_ids()) == before
    assert [p.name for p in (store.root / "refs").iterdir() if p.name.startswith(".")] == []
    assert store.resolve("capture/x") == art.id


@pytest.mark.parametrize("content", ["{not json", "[]", '{"kind": 3}'])
def test_damaged_manifest_is_one_line_everywhere(store, run_cli, content):
    art, _ = toy_publish(store, ToyConfig(), ref="capture/dm")
    os.chmod(art.path, 0o755)
    os.chmod(art.path / MANIFEST, 0o644)
    (art.path / MANIFEST).write_text(content)
    code, _, err = run_cli("ls", workspace=store.root)
    assert code == 0 and "manifest.json" in err and "Traceback" not in err
    code, _, err = run_cli("show", "capture/dm", workspace=store.root)
    _one_line_error(code, err)
    code, out, err = run_cli("gc", "--dry-run", workspace=store.root)
    assert code == 0 and "Traceback" not in err
    code, out, err = run_cli("verify", workspace=store.root)
    assert code == 1 and "CORRUPT" in out and MANIFEST in out
    with pytest.raises(WorkspaceError, match=MANIFEST):
        Store(store.root).get(art.id)


def test_tmp_being_a_file_is_one_line(store, run_cli):
    (store.root / "tmp").rmdir()
    (store.root / "tmp").write_text("oops")
    code, _, err = run_cli("gc", workspace=store.root)
    _one_line_error(code, err)
    assert "tmp" in err
    code, _, err = run_cli("capture", "synth", "--preset", "tiny", workspace=store.root)
    _one_line_error(code, err)


def test_read_only_commands_create_no_workspace(tmp_path, run_cli):
    for args in (("ls",), ("show", "abcd"), ("verify",), ("gc",), ("tag", "abcd", "x/y")):
        ws = tmp_path / f"none-{args[0]}"
        code, _, err = run_cli(*args, workspace=ws)
        _one_line_error(code, err)
        assert "no nsim workspace here" in err
        assert not ws.exists()


def test_symlinked_object_directory_is_refused(store, tmp_path):
    art, _ = toy_publish(store, ToyConfig(), ref="capture/l")
    elsewhere = tmp_path / "elsewhere"
    os.chmod(art.path.parent, 0o755)
    os.rename(art.path, elsewhere)
    art.path.symlink_to(elsewhere)
    with pytest.raises(WorkspaceError, match="symbolic link"):
        Store(store.root).get(art.id)
    assert [p.file for p in store.verify(art.id)] == ["(object)"]
    assert art.id not in store.all_ids()


def test_truncated_npz_is_one_line(tmp_path):
    import numpy as np

    from nsim.io.npz import read_npz

    p = tmp_path / "trajectory.npz"
    np.savez(p, time_s=np.arange(10.0))
    assert read_npz(p, required=("time_s",))["time_s"].shape == (10,)
    with pytest.raises(InputError, match="missing array"):
        read_npz(p, required=("robot_pose_se3",))
    p.write_bytes(p.read_bytes()[:40])
    with pytest.raises(InputError, match="not a readable .npz"):
        read_npz(p)
    np.save(tmp_path / "obj.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    import zipfile

    with zipfile.ZipFile(tmp_path / "obj.npz", "w") as z:
        z.write(tmp_path / "obj.npy", "x.npy")
    with pytest.raises(InputError, match="not a readable"):
        read_npz(tmp_path / "obj.npz")


def test_ref_name_rules(store):
    art, _ = toy_publish(store, ToyConfig())
    with pytest.raises(InputError):
        store.set_ref("capture/latest/deeper", art.id)
    with pytest.raises(InputError):
        store.set_ref("capture", art.id)
