"""Memory and counters of a long node run (``tissue-sim bench node --soak``): the node's resident memory
read from /proc, one sample row per period, and the soak's CSV, chart and summary."""
from __future__ import annotations

import csv
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import InputError

#: Seconds the soak's warm-up keeps its second reader stopped (``node.STALL_SECONDS``), named in the summary.
STALL_SECONDS = 3.0


def rss_kib(pid: int) -> int:
    """Resident set size of a process [KiB] (Linux /proc)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise InputError(f"no VmRSS for process {pid}")


def memory_parts_kib(pid: int, proc: Path = Path("/proc")) -> dict[str, int]:
    """Where the resident memory is [KiB]: anonymous and file-backed (``/proc/PID/status``), and glibc's
    main heap (the ``[heap]`` mapping in ``/proc/PID/smaps``); -1 where not readable.

    A soak's growth that lands in ``[heap]`` is Python's and glibc's small allocations; anonymous memory
    outside it is mmap'd: thread arenas, numba/LLVM, DDS's pools.
    """
    parts = {"rss_anon_kib": -1, "rss_file_kib": -1, "heap_kib": -1}
    try:
        for line in (proc / str(pid) / "status").read_text().splitlines():
            if line.startswith("RssAnon:"):
                parts["rss_anon_kib"] = int(line.split()[1])
            elif line.startswith("RssFile:"):
                parts["rss_file_kib"] = int(line.split()[1])
        in_heap = False
        for line in (proc / str(pid) / "smaps").read_text().splitlines():
            if line[:1] in "0123456789abcdef" and "-" in line.split(" ", 1)[0]:
                in_heap = line.rstrip().endswith("[heap]")
            elif in_heap and line.startswith("Rss:"):
                parts["heap_kib"] = int(line.split()[1])
                in_heap = False
    except (OSError, ValueError):
        pass
    return parts


def soak_row(t: float, pid: int, d0: dict[str, str], d: dict[str, str]) -> dict[str, Any]:
    return {"t_s": round(t, 2), "rss_kib": rss_kib(pid), **memory_parts_kib(pid),
            "steps": int(d["steps"]) - int(d0["steps"]),
            "overruns": int(d["overruns"]) - int(d0["overruns"]),
            "missed_ticks": int(d["missed_ticks"]) - int(d0["missed_ticks"]),
            "markers_published": int(d.get("markers_published", 0)),
            "load1": os.getloadavg()[0]}  # the machine's load beside the soak


def write_soak_report(out: Path, r: Any) -> None:
    """node_soak.csv and node_soak.png of a soak's :class:`~tissue_sim_ros.bench.node.SceneResult`, and its summary."""
    rows = r.soak
    with open(out / "node_soak.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    rss = np.array([row["rss_kib"] for row in rows], dtype=float) / 1024.0
    t = np.array([row["t_s"] for row in rows], dtype=float)
    growth = float(rss[-1] - rss[0])
    # the trend, robust to one allocation burst: least-squares slope over the run
    slope = float(np.polyfit(t, rss, 1)[0]) * 3600.0 if len(t) > 2 else math.nan
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, ax = plt.subplots(figsize=(8, 4))
    ax.plot(t / 60.0, rss, label="node RSS [MiB]")
    ax.set_xlabel("time since warm-up [min]")
    ax.set_ylabel("RSS [MiB]")
    ax2 = ax.twinx()
    ax2.plot(t / 60.0, [row["overruns"] + row["missed_ticks"] for row in rows], color="tab:red",
             label="overruns + missed ticks")
    ax2.set_ylabel("missed deadlines (cumulative)")
    ax.set_title(f"soak: {r.scene} {r.mode}, {r.triangles} triangles, markers at {r.marker_rate:g} Hz: "
                 f"RSS {growth:+.2f} MiB")
    fig.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "node_soak.png", dpi=120)
    plt.close(fig)
    print(f"soak {r.scene} {r.mode}: {r.seconds:.0f} s, {r.steps} steps at {r.rate_hz:.2f} Hz, {r.triangles} triangles, "
          f"markers at {r.marker_rate:g} Hz ({r.markers_received} received, {r.markers_skipped} skipped by the node)")
    print(f"RSS {rss[0]:.2f} MiB after warm-up -> {rss[-1]:.2f} MiB at the end: growth {growth:+.2f} MiB "
          f"(max {rss.max():.2f} MiB; trend {slope:+.2f} MiB/h); target < 5 MiB: "
          f"{'met' if growth < 5.0 else 'MISSED'}; the reliable histories were filled to their depth in the "
          f"warm-up (a second reader stopped {STALL_SECONDS:g} s)")
    load = np.array([row["load1"] for row in rows], dtype=float)
    print(f"load average (1 min) beside it: median {np.median(load):.2f}, min {load.min():.2f}, max {load.max():.2f}")
    print(f"overruns {r.overruns}, missed ticks {r.missed_ticks} of {r.steps + r.missed_ticks} ticks "
          f"({100 * r.missed_fraction:.3f} %), divergences {r.divergences}; phase lock "
          f"{'on' if r.phase_lock else 'off'} ({r.phase_shifts} shifts while measuring)")
    print(f"wrote {out / 'node_soak.csv'}, {out / 'node_soak.png'}")
