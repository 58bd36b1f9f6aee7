"""The window of recent observations shared by the pad heading and tilt estimators."""

from __future__ import annotations

import math

from companion.delivery.recent_window import RecentWindow


def test_keeps_what_is_within_the_window_of_the_newest_but_never_fewer_than_the_minimum() -> None:
    w: RecentWindow[int] = RecentWindow(window_s=1.0, min_count=2)
    assert w.values() == [] and w.newest_s == -math.inf
    for t, v in ((0.0, 1), (0.5, 2), (1.2, 3)):
        w.add(t, v)
    assert w.values() == [2, 3]  # 0.0 is more than 1 s before 1.2
    w.add(5.0, 4)
    assert w.values() == [3, 4]  # all older than 1 s, but two are kept
    w.add(4.8, 5)  # a late exposure: kept, the newest stays 5.0
    assert w.values() == [4, 5] and w.newest_s == 5.0
