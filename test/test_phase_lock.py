"""core/timing/phase_lock.py on synthetic arrival times (no clock, no ROS: deterministic).

A model of the rcl timer the node uses: ticks at a fixed period; a shift
decided at a tick stretches the interval after the next tick (the node sets the
timer's period for one call, as rcl computes the next call from the period at
each call). A pose is used by the first tick scheduled at or after its arrival
(the node takes the queued poses at each tick); its wait is that tick minus the
arrival.
"""
from __future__ import annotations

import numpy as np
import pytest

from tissue_sim_ros.core.timing.phase_lock import PhaseLock

P = 10_000_000  # 100 Hz [ns]
T0 = 1_800_000_000 * 10**9  # an epoch-like start, as the node's clock reads
SHIFT_TICKS: list[int] = []
"""The tick index of each shift of the last run()."""


def run(lock: PhaseLock, arrivals: np.ndarray, tick0: int, n_ticks: int) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """Drive the lock with arrival times (sorted, ns) against a modelled timer.

    Returns the tick times, each arrival's wait to the tick that used it (NaN
    past the last tick) and the shifts made.
    """
    ticks = np.empty(n_ticks, dtype=np.int64)
    shifts: list[int] = []
    SHIFT_TICKS.clear()
    sched, period, stretch_pending = tick0, P, False
    i = 0
    for k in range(n_ticks):
        ticks[k] = sched
        while i < len(arrivals) and arrivals[i] <= sched:
            lock.arrival(int(arrivals[i]))
            i += 1
        # rcl_timer_call: the next call is this one + the period set now (before the callback)
        next_sched = sched + period
        if stretch_pending:
            period, stretch_pending = P, False
        shift = lock.tick(sched)
        assert abs(shift) <= lock.max_shift_ns
        if shift:
            shifts.append(shift)
            SHIFT_TICKS.append(k)
            period, stretch_pending = P + shift, True
        sched = next_sched
    idx = np.searchsorted(ticks, arrivals, side="left")
    waits = np.full(len(arrivals), np.nan)
    ok = idx < n_ticks
    waits[ok] = ticks[idx[ok]] - arrivals[ok]
    return ticks, waits, shifts


def stream(offset_ns: float, seconds: float, jitter_ns: float = 200_000.0, period_ns: float = P,
           seed: int = 0) -> np.ndarray:
    """A periodic stream `offset_ns` after T0 + k period, with Gaussian jitter (seeded)."""
    rng = np.random.default_rng(seed)
    n = int(seconds * 1e9 / period_ns)
    t = T0 + offset_ns + np.arange(n) * period_ns + rng.normal(0.0, jitter_ns, n)
    return np.sort(t.astype(np.int64))


def median_ms(waits: np.ndarray, last: int = 200) -> float:
    w = waits[~np.isnan(waits)][-last:]
    return float(np.median(w)) / 1e6


def test_worst_phase_stream_just_after_the_ticks_gets_ticks_just_after_it() -> None:
    # poses arriving 0.5 ms after each tick wait 9.5 ms without the lock
    arrivals = stream(0.5e6, 3.0)
    lock = PhaseLock(P)
    _, waits, shifts = run(PhaseLock(P, max_shift_ns=1), arrivals, T0, 300)  # a lock that cannot move
    assert median_ms(waits) == pytest.approx(9.5, abs=0.2)
    _, waits, shifts = run(lock, arrivals, T0, 300)
    # ticks after the arrivals by the jitter's upper spread (1.28 sigma = 0.26 ms) + guard 0.5 ms
    assert 0.3 < median_ms(waits) < 1.5
    assert np.mean(waits[-200:] > 5e6) < 0.05  # few poses still miss their tick
    assert 1 <= len(shifts) <= 3 and lock.status.state == "locked"


@pytest.mark.parametrize("eighth", range(8))
def test_every_phase_locks_within_bounded_shifts(eighth: int) -> None:
    arrivals = stream(eighth * P / 8 + 0.1e6, 4.0, seed=eighth)
    lock = PhaseLock(P)
    _, waits, shifts = run(lock, arrivals, T0, 400)
    assert 0.3 < median_ms(waits) < 1.5, (eighth, shifts)
    # at most 5 ms to move, 2 ms a shift, plus the last small correction
    assert len(shifts) <= 4 and sum(abs(s) for s in shifts) <= P / 2 + lock.gain_out_ns
    assert lock.status.state == "locked"


def test_stays_put_once_locked_despite_jitter_and_late_outliers() -> None:
    arrivals = stream(3e6, 60.0, jitter_ns=400_000.0, seed=3)
    rng = np.random.default_rng(4)
    late = rng.random(len(arrivals)) < 0.05
    arrivals = np.sort(arrivals + late * rng.integers(2_000_000, 8_000_000, len(arrivals)))
    lock = PhaseLock(P)
    ticks, waits, shifts = run(lock, arrivals, T0, 6000)
    # all the moving happens in the first second; the next 59 s hold still
    assert 1 <= len(shifts) <= 3 and max(SHIFT_TICKS) < 200
    assert lock.status.shifts == len(shifts)
    assert lock.status.state == "locked"
    on_time = waits[(~late) & ~np.isnan(waits)]
    assert np.median(on_time[-1000:]) / 1e6 < 2.0


def test_gives_up_on_a_random_stream() -> None:
    rng = np.random.default_rng(5)
    arrivals = np.sort(T0 + rng.integers(0, 3 * 10**9, 300))
    lock = PhaseLock(P)
    _, _, shifts = run(lock, arrivals, T0, 300)
    assert shifts == [] and lock.status.state == "irregular"
    assert lock.status.concentration < 0.3


@pytest.mark.parametrize("rate", [200.0, 30.0, 50.0, 99.5, 100.5])
@pytest.mark.parametrize("offset_ms", [0.5, 3.0, 6.0, 9.0])
def test_a_stream_at_another_rate_is_never_made_to_wait_longer(rate: float, offset_ms: float) -> None:
    arrivals = stream(offset_ms * 1e6, 10.0, period_ns=1e9 / rate, seed=int(rate * offset_ms))
    _, fixed, _ = run(PhaseLock(P, max_shift_ns=1), arrivals, T0, 1000)
    lock = PhaseLock(P)
    _, locked, _ = run(lock, arrivals, T0, 1000)
    # the mean wait after the first second (a phase lock can only choose where the ticks are); a phase
    # drifting by 5 ms a second (99.5, 100.5 Hz) averages ~P/2 either way, +-0.5 ms with the window's ends
    assert np.nanmean(locked[len(locked) // 10:]) <= np.nanmean(fixed[len(fixed) // 10:]) + 0.6e6


def test_a_slower_stream_on_a_subharmonic_locks() -> None:
    arrivals = stream(7e6, 6.0, period_ns=2 * P)  # 50 Hz: every other tick has a new pose
    lock = PhaseLock(P)
    _, waits, shifts = run(lock, arrivals, T0, 600)
    assert shifts and lock.status.state == "locked"
    assert median_ms(waits, 100) < 1.5


@pytest.mark.parametrize("ppm, bound_ms", [(200, 2.5), (1000, 3.0)])
def test_follows_a_drifting_stream(ppm: int, bound_ms: float) -> None:
    # the robot's clock fast: its phase moves 0.2 (1) ms per second
    arrivals = stream(4e6, 30.0, period_ns=P * (1 - ppm * 1e-6), seed=6)
    lock = PhaseLock(P)
    _, waits, shifts = run(lock, arrivals, T0, 3000)
    w = waits[~np.isnan(waits)]
    assert len(shifts) >= 3  # corrections as it drifts
    # after the first second, every median of 100 poses stays small
    w = w[100:]
    blocks = w[:len(w) // 100 * 100].reshape(-1, 100)
    # (a pose waits ~5 ms on average without the lock, its phase turning through the period)
    assert np.median(blocks, axis=1).max() / 1e6 < bound_ms


def test_a_stream_straddling_the_tick_is_one_cluster() -> None:
    # arrivals at the tick +- 0.3 ms: half of them would wait a whole period
    arrivals = stream(0.0, 3.0, jitter_ns=300_000.0, seed=7)
    lock = PhaseLock(P)
    _, waits, shifts = run(lock, arrivals, T0, 300)
    assert len(shifts) == 1 and 0 < shifts[0] < 2_000_000
    assert median_ms(waits) < 1.5 and np.mean(waits[-200:] > 5e6) < 0.05


def test_measuring_only_never_shifts_but_reports_the_wait() -> None:
    lock = PhaseLock(P)
    for k in range(100):
        assert lock.tick(T0 + k * P, steer=False) == 0
        lock.arrival(T0 + k * P + 1_000_000)  # 1 ms after each tick: 9 ms to wait
    assert lock.status.state == "measuring" and lock.status.shifts == 0
    assert lock.status.wait_median_ns == pytest.approx(9_000_000)


def test_no_stream_and_a_stream_that_stops() -> None:
    lock = PhaseLock(P)
    assert lock.tick(T0) == 0 and lock.status.state == "no stream"
    arrivals = stream(5e6, 1.0)
    _, _, shifts = run(lock, arrivals, T0, 100)
    assert shifts
    state_before = lock.status.shifts
    # 10 s later, nothing has arrived since: the old arrivals are forgotten, nothing moves
    for k in range(1000, 1100):
        assert lock.tick(T0 + k * P) == 0
    assert lock.status.state == "no stream" and lock.status.shifts == state_before


def test_collects_before_deciding_and_reset_forgets() -> None:
    lock = PhaseLock(P, min_samples=24, eval_ticks=1)
    for k in range(10):
        lock.arrival(T0 + k * P + 5_000_000)
        assert lock.tick(T0 + k * P + 6_000_000) == 0
    assert lock.status.state == "collecting"
    lock.reset()
    assert lock.status.state == "collecting" and lock.status.samples == 10  # samples as last measured
    assert lock.tick(T0 + 11 * P) == 0 and lock.status.state == "no stream"


@pytest.mark.parametrize("kwargs", [{"period_ns": 0}, {"period_ns": P, "max_shift_ns": P // 2}])
def test_bad_settings_are_refused(kwargs: dict) -> None:
    with pytest.raises(ValueError, match="expected"):
        PhaseLock(**kwargs)


def test_a_loaded_publishers_stream_still_locks() -> None:
    # 1.5 ms Gaussian jitter and one pose in ten anywhere in the period (a publisher on a loaded machine),
    # arriving 1 ms after the ticks: the mean wait falls from 6.2 to 3.4 ms (with a 1.5 ms jitter it cannot be
    # much less: a tick placed about two sigma after the median arrival)
    arrivals = stream(1e6, 10.0, jitter_ns=1.5e6, seed=8)
    rng = np.random.default_rng(9)
    scattered = rng.random(len(arrivals)) < 0.1
    arrivals = np.sort(np.where(scattered, arrivals + rng.integers(0, P, len(arrivals)), arrivals))
    _, fixed, _ = run(PhaseLock(P, max_shift_ns=1), arrivals, T0, 1000)
    lock = PhaseLock(P)
    _, locked, shifts = run(lock, arrivals, T0, 1000)
    assert shifts and lock.status.state == "locked" and lock.status.concentration > 0.5
    assert np.nanmean(locked[100:]) < 0.6 * np.nanmean(fixed[100:])


@pytest.mark.parametrize("phase_ms", [0.2, 5.0, 9.9])
def test_bench_reads_the_ticks_phase_from_late_callbacks(phase_ms: float) -> None:
    """bench node places its publisher from the node's step stamps: callbacks late by 0.1-3 ms (a wrap too)."""
    from tissue_sim_ros.bench.node_results import tick_phase as _tick_phase

    rng = np.random.default_rng(10)
    stamps = T0 + int(phase_ms * 1e6) + np.arange(200) * P + rng.exponential(400_000, 200).astype(np.int64) + 100_000
    found = _tick_phase(stamps, P)
    error = (found - int(phase_ms * 1e6) + P // 2) % P - P // 2
    assert 0 <= error < 300_000  # the 10th percentile: a little after the scheduled ticks
