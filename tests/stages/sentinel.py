"""The expensive step of a stage replaced by a sentinel, to show that a check runs before it."""

from __future__ import annotations


class ReachedWork(Exception):
    """Raised by the sentinel: the stage got past its checks to the expensive work."""


def block_work(monkeypatch, *targets: str) -> list:
    """Replace each dotted ``target`` by a sentinel that records its call and raises :class:`ReachedWork`; returns
    the list of the calls' positional arguments (empty: no expensive step was reached)."""
    calls: list = []

    def sentinel(*args, **kwargs):
        calls.append(args)
        raise ReachedWork

    for target in targets:
        monkeypatch.setattr(target, sentinel)
    return calls
