"""Time stamps as plain integers: nanoseconds <-> (sec, nanosec) <-> seconds.

ROS stamps (``builtin_interfaces/Time``) are a pair of integers; bags index
messages by int64 nanoseconds; the simulation counts seconds as floats. The
node, the tool driver, replay, the bag readers and the benchmarks all convert
between the three through these functions, so a stamp written by one reads
back to the same nanosecond in another.
"""
from __future__ import annotations

NS_PER_S = 1_000_000_000
"""Nanoseconds per second."""

Stamp = tuple[int, int]
"""A ROS time as (sec, nanosec), 0 <= nanosec < 1e9."""


def ns_from_seconds(t: float) -> int:
    """Nanoseconds of a time in seconds, rounded to the nearest nanosecond."""
    return int(round(t * 1e9))


def stamp_from_ns(t_ns: int) -> Stamp:
    """(sec, nanosec) of a time in nanoseconds (t_ns >= 0)."""
    t_ns = int(t_ns)
    return t_ns // NS_PER_S, t_ns % NS_PER_S


def stamp_to_ns(stamp: Stamp) -> int:
    """Nanoseconds of a (sec, nanosec) stamp."""
    return int(stamp[0]) * NS_PER_S + int(stamp[1])


def stamp_from_seconds(t: float) -> Stamp:
    """(sec, nanosec) of a time in seconds (t >= 0), rounded to the nearest nanosecond."""
    return stamp_from_ns(ns_from_seconds(t))


def stamp_to_seconds(stamp: Stamp) -> float:
    """Seconds of a (sec, nanosec) stamp."""
    return stamp[0] + stamp[1] * 1e-9


__all__ = ["NS_PER_S", "Stamp", "ns_from_seconds", "stamp_from_ns", "stamp_to_ns", "stamp_from_seconds",
           "stamp_to_seconds"]
