"""map_tasks: the same results in the same order whichever engine runs them; one-line user errors."""

from __future__ import annotations

import sys

import pytest

from nsim.distributed import RAY_HOWTO, map_tasks, resolve_ray_address
from nsim.errors import InputError, NsimError


def square_and_pid(x: int) -> tuple[int, int]:
    import os

    return x * x, os.getpid()


def square(x: int) -> int:
    return x * x


def fail_on_three(x: int) -> int:
    if x == 3:
        raise InputError(f"item {x}: bad input")
    return x


def test_local_sequential_and_process_pool_agree():
    items = list(range(7))
    seq = map_tasks(square_and_pid, items)
    pool = map_tasks(square_and_pid, items, workers=2)
    assert [r[0] for r in seq] == [r[0] for r in pool] == [x * x for x in items]
    assert {r[1] for r in seq} == {__import__("os").getpid()}  # sequential runs in this process
    assert __import__("os").getpid() not in {r[1] for r in pool}
    assert map_tasks(square, []) == [] and map_tasks(square, [5], workers=4) == [25]


@pytest.mark.parametrize("workers", [1, 2])
def test_user_errors_come_back_as_one_line(workers):
    with pytest.raises(NsimError, match=r"^task 3: item 3: bad input$"):
        map_tasks(fail_on_three, range(5), workers=workers)


def test_bad_arguments():
    with pytest.raises(NsimError, match="--engine: 'dask' is not one of local, ray"):
        map_tasks(square, [1], engine="dask")
    with pytest.raises(NsimError, match="--workers: expected an int >= 1, got 0"):
        map_tasks(square, [1], workers=0)
    with pytest.raises(NsimError, match="--address: only the ray engine"):
        map_tasks(square, [1], address="auto")


def test_missing_ray_says_how_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    with pytest.raises(NsimError) as err:
        map_tasks(square, [1, 2], engine="ray")
    assert RAY_HOWTO in str(err.value) and "\n" not in str(err.value)


def test_ray_address_is_explicit_or_a_private_instance(monkeypatch):
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    assert resolve_ray_address(None) == "local"  # never "auto": a stray cluster is not joined silently
    assert resolve_ray_address("auto") == "auto"
    monkeypatch.setenv("RAY_ADDRESS", "head:6379")
    assert resolve_ray_address(None) == "head:6379"
    assert resolve_ray_address("other:6379") == "other:6379"


def test_ray_matches_local(monkeypatch):
    pytest.importorskip("ray")
    monkeypatch.setenv("RAY_AUTH_MODE", "disabled")
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    items = list(range(6))
    assert map_tasks(square, items, engine="ray", workers=2) == map_tasks(square, items)
    with pytest.raises(NsimError, match=r"^task 3: item 3: bad input$"):
        map_tasks(fail_on_three, items, engine="ray", workers=2)
