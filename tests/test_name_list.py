"""One-line errors stay one readable line: a list of names is cut after a few, with a count."""

from nsim.errors import name_list


def test_short_lists_are_whole_and_long_ones_cut_with_a_count():
    assert name_list([]) == "none"
    assert name_list(["/a", "/b"]) == "/a, /b"
    assert name_list([f"/t{i}" for i in range(8)]) == ", ".join(f"/t{i}" for i in range(8))
    topics = [f"/robot/sensor_{i:03d}/diagnostics" for i in range(300)]
    line = name_list(topics)
    assert line.startswith("/robot/sensor_000/diagnostics, ") and line.endswith("and 292 more")
    assert len(line) < 300
    assert name_list(topics, most=2) == "/robot/sensor_000/diagnostics, /robot/sensor_001/diagnostics and 298 more"
