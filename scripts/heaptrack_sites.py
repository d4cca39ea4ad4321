#!/usr/bin/env python3
"""Which allocation sites grow over a run: live bytes per site through a heaptrack recording, in time steps.

``heaptrack_print`` reports peaks and leaks at the end; a soak's question is when and where memory grew.
This reads heaptrack's interpreted file (``heaptrack -p PID`` or ``heaptrack CMD`` writes
``heaptrack.NAME.PID.zst``; format v3: ``a SIZE TRACE`` allocation kinds, ``+ KIND`` / ``- KIND``
allocations and frees, ``c MS`` time, ``t IP PARENT`` trace nodes, ``i IP MODULE [FUNC [FILE LINE]]``
instruction pointers, ``s LEN TEXT`` strings; numbers in hex), follows the live count of every allocation
kind, samples it every ``--period`` seconds, and prints the sites whose live bytes grew most from
``--since`` seconds to the end, each with its growth over time and its backtrace (innermost first).
Writes a chart of the top sites' live MiB against time.

How the soak's 5 MiB step and its creep were found (docs/benchmarks.md, Soak):

    heaptrack -p $(pgrep -f tissue_sim_node) &      # while `tissue-sim bench node --soak 1000` runs
    python scripts/heaptrack_sites.py heaptrack.tissue_sim_node.PID.zst --since 40

Pure Python over every line: ~3.5 minutes for 17 minutes of a 5k node (75 million allocations).
"""
from __future__ import annotations

import argparse
import subprocess
from pathlib import Path

import numpy as np


def read(path: Path, period_s: float) -> dict:
    """Samples of the live count of every allocation kind, with the trace tables."""
    opener = ["zstdcat", str(path)] if path.suffix == ".zst" else ["zcat", str(path)] if path.suffix == ".gz" \
        else ["cat", str(path)]
    proc = subprocess.Popen(opener, stdout=subprocess.PIPE, bufsize=1 << 20)
    sizes: list[int] = []
    kind_trace: list[int] = []
    live: list[int] = []
    strings: list[str] = []
    traces: list[tuple[int, int]] = []
    ips: list[list[str]] = []
    samples: list[np.ndarray] = []
    times: list[float] = []
    next_ms, now_ms = 0.0, 0.0
    period_ms = 1e3 * period_s
    assert proc.stdout is not None
    for raw in proc.stdout:
        c = raw[0]
        if c == 43:  # '+'
            live[int(raw[2:], 16)] += 1
        elif c == 45:  # '-'
            live[int(raw[2:], 16)] -= 1
        elif c == 99:  # 'c'
            now_ms = int(raw[2:], 16)
            if now_ms >= next_ms:
                samples.append(np.array(live, dtype=np.int64))
                times.append(now_ms / 1e3)
                next_ms = now_ms + period_ms
        elif c == 97:  # 'a'
            _, size, trace = raw.split()
            sizes.append(int(size, 16))
            kind_trace.append(int(trace, 16))
            live.append(0)
        elif c == 115:  # 's'
            parts = raw.decode(errors="replace").rstrip("\n").split(" ", 2)
            strings.append(parts[2] if len(parts) > 2 else "")
        elif c == 116:  # 't'
            _, ip, parent = raw.split()
            traces.append((int(ip, 16), int(parent, 16)))
        elif c == 105:  # 'i'
            ips.append(raw.decode(errors="replace").split()[1:])
    proc.wait()
    samples.append(np.array(live, dtype=np.int64))
    times.append(now_ms / 1e3)
    counts = np.zeros((len(samples), len(sizes)), dtype=np.int64)
    for k, sample in enumerate(samples):
        counts[k, :sample.shape[0]] = sample
    return {"times": np.array(times), "counts": counts, "sizes": np.array(sizes, dtype=np.int64),
            "kind_trace": np.array(kind_trace), "strings": strings, "traces": traces, "ips": ips}


def backtrace(data: dict, trace: int, depth: int = 12) -> list[str]:
    """The frames of ``trace``, innermost first: function [module] file:line."""
    strings, traces, ips = data["strings"], data["traces"], data["ips"]

    def text(index: int) -> str:
        return strings[index - 1] if 0 < index <= len(strings) else "?"

    frames = []
    while 0 < trace <= len(traces) and len(frames) < depth:
        ip, trace = traces[trace - 1]
        fields = ips[ip - 1] if 0 < ip <= len(ips) else []
        module = text(int(fields[1], 16)).rsplit("/", 1)[-1] if len(fields) > 1 else "?"
        function = text(int(fields[2], 16))[:100] if len(fields) > 2 else "??"
        where = f" {text(int(fields[3], 16)).rsplit('/', 1)[-1]}:{int(fields[4], 16)}" if len(fields) > 4 else ""
        frames.append(f"{function} [{module}]{where}")
    return frames


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("file", type=Path, help="heaptrack's recording (.zst, .gz or plain)")
    parser.add_argument("--period", type=float, default=5.0, help="seconds between samples (default 5)")
    parser.add_argument("--since", type=float, default=0.0, help="growth counted from this time [s] (after a warm-up)")
    parser.add_argument("--top", type=int, default=6, help="sites to show (default 6)")
    parser.add_argument("--out", type=Path, default=None, help="chart (default: next to the recording, .png)")
    args = parser.parse_args()
    data = read(args.file, args.period)
    t, counts, sizes, kind_trace = data["times"], data["counts"], data["sizes"], data["kind_trace"]
    live = counts * sizes[None, :]
    k0 = int(np.searchsorted(t, args.since))
    by_site: dict[int, np.ndarray] = {}
    for kind in range(live.shape[1]):
        by_site[int(kind_trace[kind])] = by_site.get(int(kind_trace[kind]), 0) + live[:, kind]
    growth = sorted(by_site.items(), key=lambda kv: -(kv[1][-1] - kv[1][k0]))[:args.top]
    total = live.sum(axis=1)
    print(f"{args.file}: {t[-1]:.0f} s, {live.shape[1]} allocation kinds; live heap {total[k0] / 2**20:.2f} MiB at "
          f"{t[k0]:.0f} s -> {total[-1] / 2**20:.2f} MiB at the end")
    marks = np.linspace(k0, len(t) - 1, 6).astype(int)
    for site, series in growth:
        print(f"\n+{(series[-1] - series[k0]) / 2**20:.3f} MiB  site {site}: "
              + ", ".join(f"{t[k]:.0f} s {series[k] / 2**20:.3f}" for k in marks) + " MiB")
        for frame in backtrace(data, site):
            print(f"    {frame}")
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, ax = plt.subplots(figsize=(8, 4))
    for site, series in growth:
        label = next((f for f in backtrace(data, site, 3) if "malloc" not in f and "operator new" not in f), "?")
        ax.plot(t, (series - series[k0]) / 2**20, label=f"{site}: {label[:60]}")
    ax.set_xlabel("time in the recording [s]")
    ax.set_ylabel(f"live MiB since {t[k0]:.0f} s")
    ax.legend(fontsize=6)
    fig.tight_layout()
    out = args.out or args.file.with_suffix(".png")
    fig.savefig(out, dpi=120)
    print(f"\nwrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
