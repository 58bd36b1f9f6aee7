"""Distances for people to read: never ``0.00 m`` for an error that is not zero."""

from __future__ import annotations

import math


def format_m(value_m: float) -> str:
    """A distance with units that keep its size visible: metres with two decimals from 0.1 m,
    millimetres below (``44 mm``, ``3.2 mm``, ``0.04 mm``), ``0 m`` only for exactly zero,
    ``n/a`` when not finite."""
    if not math.isfinite(value_m):
        return "n/a"
    a = abs(value_m)
    if a == 0.0:
        return "0 m"
    if a >= 0.1:
        return f"{value_m:.2f} m"
    mm = value_m * 1000.0
    if a >= 0.01:
        return f"{mm:.0f} mm"
    if a >= 0.0001:
        return f"{mm:.1f} mm"
    return f"{mm:.2g} mm"


def format_cm(value_m: float) -> str:
    """A distance in centimetres with one decimal (tables of landing errors), in millimetres
    when that would print 0.0 for a non-zero value."""
    if not math.isfinite(value_m):
        return "n/a"
    if value_m != 0.0 and abs(value_m) < 0.0005:
        return f"{value_m * 1000.0:.2g} mm"
    return f"{value_m * 100.0:.1f} cm"
