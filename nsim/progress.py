"""Progress bars: rich on a terminal, silent otherwise (logs and CI stay clean)."""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Iterator
from typing import TypeVar

T = TypeVar("T")


class _Bar:
    def __init__(self, progress, task) -> None:
        self._progress = progress
        self._task = task

    def advance(self, n: float = 1, **fields: object) -> None:
        if self._progress is not None:
            info = {"info": " ".join(f"{k}={v}" for k, v in fields.items())} if fields else {}
            self._progress.update(self._task, advance=n, **info)

    def info(self, text: str) -> None:
        if self._progress is not None:
            self._progress.update(self._task, info=text)


@contextlib.contextmanager
def progress_bar(total: float | None, description: str, enabled: bool) -> Iterator[_Bar]:
    """``with progress_bar(n, "rendering", ctx.show_progress) as bar: bar.advance()``."""
    if not enabled:
        yield _Bar(None, None)
        return
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    with Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        TextColumn("{task.fields[info]}"),
        transient=False,
    ) as progress:
        task = progress.add_task(description, total=total, info="")
        yield _Bar(progress, task)


def track(items: Iterable[T], description: str, enabled: bool, total: int | None = None) -> Iterator[T]:
    if total is None and hasattr(items, "__len__"):
        total = len(items)  # type: ignore[arg-type]
    with progress_bar(total, description, enabled) as bar:
        for item in items:
            yield item
            bar.advance()
