"""The recent observations of an estimator that follows a slowly drifting quantity (the pad's
heading and tilt in the frame of the autopilot's attitude): those exposed within ``window_s`` of
the newest, never fewer than ``min_count``, in the order they were added."""

from __future__ import annotations

import math
from collections import deque
from typing import Generic, TypeVar

T = TypeVar("T")


class RecentWindow(Generic[T]):
    def __init__(self, window_s: float, min_count: int):
        self.window_s = window_s
        self.min_count = min_count
        self._items: deque[tuple[float, T]] = deque()  # (exposure time s, value)
        self.newest_s = -math.inf  # exposure time of the newest value added

    def add(self, time_s: float, value: T) -> None:
        self._items.append((time_s, value))
        self.newest_s = max(self.newest_s, time_s)
        oldest_s = self.newest_s - self.window_s
        while len(self._items) > self.min_count and self._items[0][0] < oldest_s:
            self._items.popleft()

    def values(self) -> list[T]:
        return [v for _, v in self._items]
