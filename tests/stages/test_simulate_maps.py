"""`nsim simulate` on scenarios with maps of their own (polygons, a nav2 map), end to end at tiny size."""

from __future__ import annotations

import json

from nsim.config import configs_dir
from nsim.workspace.store import Store
from tests.crowd.test_own_map import _nav2_scenario

POLYGON_ROOM = configs_dir() / "scenarios" / "polygon_room.yaml"
FAST = ("--preset", "tiny", "--set", "video=false", "--set", "max_duration_s=1")


def test_own_maps_run_rebuild_and_name_bad_maps(run_cli, tmp_path):
    store = Store(tmp_path / "ws")
    code, out, err = run_cli("simulate", "--scenario", str(POLYGON_ROOM), *FAST)
    assert code == 0, err
    art = store.get(out.strip())
    occ = json.loads(art.file("occupancy.json").read_text())
    assert occ["scene"] == "the scenario's polygon map"
    assert len(occ["polygons"]) == 3 and [len(h) for h in occ["holes"]] == [1, 0, 0]
    # a nav2 map: the artifact stores the polygons traced from it, so it rebuilds from the artifact alone
    path = _nav2_scenario(tmp_path / "nav")
    code, out, err = run_cli("simulate", "--scenario", str(path), *FAST)
    assert code == 0, err
    nav = store.get(out.strip())
    assert set(json.loads(nav.file("scenario.json").read_text())["scene"]) == {"polygons", "holes"}
    code, text, err = run_cli("verify", "--rebuild", nav.id[:10])
    assert code == 0 and "rebuilt identically" in text, (text, err)
    # a bad map: exit 2, one line naming the scenario, the field, the map file and its field
    (tmp_path / "nav" / "maps" / "lab.yaml").write_text("image: lab.pgm\nresolution: 0\norigin: [0.0, 0.0, 0.0]\n")
    code, out, err = run_cli("simulate", "--scenario", str(path), *FAST)
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and out == "" and len(lines) == 1, err
    assert lines[0].startswith(f"error: {path}: scene.nav2_map: ") and "lab.yaml: resolution: expected > 0" in lines[0]
