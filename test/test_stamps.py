"""The one set of stamp conversions (core/timing/stamps.py) the node, replay, bags and benchmarks share."""
from __future__ import annotations

import numpy as np

from tissue_sim_ros.core.timing import stamps


def test_seconds_and_stamps() -> None:
    assert stamps.stamp_from_seconds(1.5) == (1, 500_000_000)
    assert stamps.stamp_to_seconds((2, 250_000_000)) == 2.25
    assert stamps.ns_from_seconds(0.01) == 10_000_000  # 0.01 * 1e9 is 10000000.000000002: rounded, not truncated
    assert stamps.stamp_from_seconds(0.0) == (0, 0)


def test_nanoseconds_round_trip() -> None:
    rng = np.random.default_rng(3)
    for t_ns in [0, 1, 999_999_999, 1_000_000_000, 1_700_000_000_123_456_789, *rng.integers(0, 2**62, 50).tolist()]:
        stamp = stamps.stamp_from_ns(t_ns)
        assert 0 <= stamp[1] < stamps.NS_PER_S
        assert stamps.stamp_to_ns(stamp) == t_ns
        assert isinstance(stamp[0], int) and isinstance(stamp[1], int)
    # numpy integers (a bag's int64 times) give plain ints
    assert stamps.stamp_from_ns(np.int64(2_500_000_000)) == (2, 500_000_000)
    assert type(stamps.stamp_from_ns(np.int64(5))[0]) is int
