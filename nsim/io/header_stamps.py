"""The header stamps of a robot's recording: taken, checked to increase, and paired across streams.

Timestamps are the messages' header stamps in integer nanoseconds (``sec * 10**9 +
nanosec``), the time the data was taken. Only where a header stamp is zero does the message's bag
(receive) time stand in; the stream's ``stamps_from_bag`` counts those messages and a warning
names the topic. Per topic (per tf link for /tf) the stamps must increase in bag order. On /tf a
repeated stamp of the same link is dropped (the first one is kept, as tf2 does).

:class:`HeaderStamps` gathers one topic's (or tf link's) stamps as they come and checks them;
:func:`associate` pairs the stamps of two streams.
"""

from __future__ import annotations

import numpy as np

from nsim.errors import InputError


class HeaderStamps:
    """Header stamps of one topic (or tf link) as they come, checked to increase."""

    def __init__(self) -> None:
        self.stamps: list[int] = []
        self.from_bag = 0

    def add(self, header_stamp_ns: int, log_time_ns: int, where: str, strict: bool = True) -> bool:
        """Append; returns False for a repeated stamp when not ``strict`` (the message is dropped)."""
        t = header_stamp_ns
        if t == 0:
            t = log_time_ns
            self.from_bag += 1
        if self.stamps and t <= self.stamps[-1]:
            if not strict and t == self.stamps[-1]:
                return False
            raise InputError(f"{where}: header stamp {t} ns is not after the previous message's "
                             f"{self.stamps[-1]} ns (stamps must increase)")
        self.stamps.append(t)
        return True


def associate(stamps_a_ns: np.ndarray, stamps_b_ns: np.ndarray, tolerance_ns: int) -> np.ndarray:
    """Index pairs ``(K, 2)`` int64 ``[i, j]`` matching ``stamps_a_ns[i]`` with ``stamps_b_ns[j]``.

    Nearest first, unique, within the tolerance: every pair with ``|a_i - b_j| <= tolerance_ns``
    is a candidate; candidates are taken in order of increasing ``|a_i - b_j|`` (ties: smaller
    ``i``, then smaller ``j``) unless ``i`` or ``j`` is already taken. So each stamp is used at
    most once, a pair is never farther apart than the tolerance, and where two stamps want the
    same partner the nearer one gets it (the other may get its second choice). Rows are sorted by
    ``i``. Stamps are integer nanoseconds, 1-D, in any order.
    """
    a, b = np.asarray(stamps_a_ns), np.asarray(stamps_b_ns)
    for name, x in (("stamps_a_ns", a), ("stamps_b_ns", b)):
        if x.ndim != 1 or not (np.issubdtype(x.dtype, np.integer) or x.size == 0):
            raise ValueError(f"{name}: expected 1-D integer nanoseconds, got {x.dtype} {x.shape}")
    if isinstance(tolerance_ns, bool) or not isinstance(tolerance_ns, int | np.integer) or tolerance_ns < 0:
        raise ValueError(f"tolerance_ns: expected an integer >= 0, got {tolerance_ns!r}")
    a, b = a.astype(np.int64), b.astype(np.int64)
    order_b = np.argsort(b, kind="stable")
    sorted_b = b[order_b]
    lo = np.searchsorted(sorted_b, a - tolerance_ns, side="left")
    hi = np.searchsorted(sorted_b, a + tolerance_ns, side="right")
    counts = hi - lo
    ii = np.repeat(np.arange(len(a)), counts)
    jj = order_b[np.repeat(lo, counts) + np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)]
    gap = np.abs(a[ii] - b[jj])
    taken_a, taken_b = np.zeros(len(a), bool), np.zeros(len(b), bool)
    pairs = []
    for k in np.lexsort((jj, ii, gap)):
        i, j = ii[k], jj[k]
        if not (taken_a[i] or taken_b[j]):
            taken_a[i] = taken_b[j] = True
            pairs.append((i, j))
    out = np.array(sorted(pairs), dtype=np.int64).reshape(-1, 2)
    return out
