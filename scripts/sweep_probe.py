#!/usr/bin/env python3
"""What bounds a distance sweep? Three rewrites of the shipped sweep, timed side by side, each checked bit for bit.

The shipped serial sweep (``kernels.solve_edges_pbd_range`` in its wavefront order, the paper's PBD) costs
5-8 ns per distance projection on these machines. Each rewrite below removes one candidate bound while
doing the same floating-point operations on the same data:

* ``vector sqrt/div``: four independent projections (one wavefront level) at a time, their square roots and
  divisions as one 4-wide vector instruction each (LLVM ``<4 x double>``): if the divider's throughput bounds
  the sweep, this is up to ~2x faster;
* ``two scenes interleaved``: the same sweep over two scenes' positions, edge by edge alternating: twice the
  independent work in the CPU's window; if latency (one projection waiting for the previous one's stores)
  bounds it, the pair costs less than two sweeps;
* ``one call, 30 sweeps``: the sweeps looped inside one compiled call (the shipped path makes one call per
  sweep from ``solve_step``, itself compiled, so this only shows the interpreter's share in this probe).

Prints ns per projection (median of ``--reps`` runs of 30 sweeps, rounds alternating) for the paper scene and
the 5k scene, and writes a bar chart. Usage: python scripts/sweep_probe.py [--out DIR] [--rounds 5]
"""
from __future__ import annotations

import argparse
import math
import os
import time
from pathlib import Path

import numpy as np
from llvmlite import ir
from numba import njit, types, uint32
from numba.extending import intrinsic

from tissue_sim_ros.core.physics.kernels import EPS_LEN2, solve_edges_pbd_range
from tissue_sim_ros.core.sim.scene import build_simulation

SWEEPS = 30


@intrinsic
def _f4(typingctx, k, r0, r1, r2, r3, l0, l1, l2, l3, w0, w1, w2, w3):  # noqa: ARG001
    """f = k (r - sqrt(l)) / (w sqrt(l)) on four lanes: the scalar sweep's IEEE operations, 4 wide."""
    sig = types.UniTuple(types.float64, 4)(*([types.float64] * 13))

    def codegen(context, builder, signature, args):
        vt = ir.VectorType(ir.DoubleType(), 4)

        def vec(values):
            v = ir.Constant(vt, ir.Undefined)
            for q, value in enumerate(values):
                v = builder.insert_element(v, value, ir.Constant(ir.IntType(32), q))
            return v

        sqrt = builder.module.globals.get("llvm.sqrt.v4f64") or ir.Function(
            builder.module, ir.FunctionType(vt, [vt]), name="llvm.sqrt.v4f64")
        length = builder.call(sqrt, [vec(args[5:9])])
        f = builder.fdiv(builder.fmul(vec([args[0]] * 4), builder.fsub(vec(args[1:5]), length)),
                         builder.fmul(vec(args[9:13]), length))
        out = [builder.extract_element(f, ir.Constant(ir.IntType(32), q)) for q in range(4)]
        return context.make_tuple(builder, signature.return_type, out)

    return sig, codegen


# The kernels below spell every projection out in their own loops: a helper taking the arrays, even inlined
# by numba, keeps a reference count increment and decrement per call (seen in the assembly: 2x slower).

@njit(fastmath={"contract"}, error_model="numpy", nogil=True)
def sweeps_vector(x, inv_mass, edges, rest, k, run_end, sweeps):
    """The sweep with four projections of one wavefront level at a time (``run_end[e]``: end of e's level)."""
    m = edges.shape[0]
    for _ in range(sweeps):
        e = 0
        while e < m:
            if e + 4 <= run_end[e]:
                i0, j0 = uint32(edges[e, 0]), uint32(edges[e, 1])
                i1, j1 = uint32(edges[e + 1, 0]), uint32(edges[e + 1, 1])
                i2, j2 = uint32(edges[e + 2, 0]), uint32(edges[e + 2, 1])
                i3, j3 = uint32(edges[e + 3, 0]), uint32(edges[e + 3, 1])
                wi0, wj0 = inv_mass[i0], inv_mass[j0]
                wi1, wj1 = inv_mass[i1], inv_mass[j1]
                wi2, wj2 = inv_mass[i2], inv_mass[j2]
                wi3, wj3 = inv_mass[i3], inv_mass[j3]
                dx0, dy0 = x[i0, 0] - x[j0, 0], x[i0, 1] - x[j0, 1]
                dx1, dy1 = x[i1, 0] - x[j1, 0], x[i1, 1] - x[j1, 1]
                dx2, dy2 = x[i2, 0] - x[j2, 0], x[i2, 1] - x[j2, 1]
                dx3, dy3 = x[i3, 0] - x[j3, 0], x[i3, 1] - x[j3, 1]
                l0, l1 = dx0 * dx0 + dy0 * dy0, dx1 * dx1 + dy1 * dy1
                l2, l3 = dx2 * dx2 + dy2 * dy2, dx3 * dx3 + dy3 * dy3
                f0, f1, f2, f3 = _f4(k, rest[e], rest[e + 1], rest[e + 2], rest[e + 3], l0, l1, l2, l3,
                                     wi0 + wj0, wi1 + wj1, wi2 + wj2, wi3 + wj3)
                if wi0 + wj0 != 0.0 and l0 > EPS_LEN2:
                    x[i0, 0] += wi0 * f0 * dx0
                    x[i0, 1] += wi0 * f0 * dy0
                    x[j0, 0] -= wj0 * f0 * dx0
                    x[j0, 1] -= wj0 * f0 * dy0
                if wi1 + wj1 != 0.0 and l1 > EPS_LEN2:
                    x[i1, 0] += wi1 * f1 * dx1
                    x[i1, 1] += wi1 * f1 * dy1
                    x[j1, 0] -= wj1 * f1 * dx1
                    x[j1, 1] -= wj1 * f1 * dy1
                if wi2 + wj2 != 0.0 and l2 > EPS_LEN2:
                    x[i2, 0] += wi2 * f2 * dx2
                    x[i2, 1] += wi2 * f2 * dy2
                    x[j2, 0] -= wj2 * f2 * dx2
                    x[j2, 1] -= wj2 * f2 * dy2
                if wi3 + wj3 != 0.0 and l3 > EPS_LEN2:
                    x[i3, 0] += wi3 * f3 * dx3
                    x[i3, 1] += wi3 * f3 * dy3
                    x[j3, 0] -= wj3 * f3 * dx3
                    x[j3, 1] -= wj3 * f3 * dy3
                e += 4
            else:
                i, j = uint32(edges[e, 0]), uint32(edges[e, 1])
                wi, wj = inv_mass[i], inv_mass[j]
                w = wi + wj
                if w != 0.0:
                    dx, dy = x[i, 0] - x[j, 0], x[i, 1] - x[j, 1]
                    len2 = dx * dx + dy * dy
                    if len2 > EPS_LEN2:
                        length = math.sqrt(len2)
                        f = k * (rest[e] - length) / (w * length)
                        x[i, 0] += wi * f * dx
                        x[i, 1] += wi * f * dy
                        x[j, 0] -= wj * f * dx
                        x[j, 1] -= wj * f * dy
                e += 1


@njit(fastmath={"contract"}, nogil=True)
def sweeps_pair(xa, xb, inv_mass, edges, rest, k, sweeps):
    """The sweep over two scenes at once, edge by edge alternating (each scene's order unchanged)."""
    for _ in range(sweeps):
        for e in range(uint32(edges.shape[0])):
            i, j = uint32(edges[e, 0]), uint32(edges[e, 1])
            wi, wj = inv_mass[i], inv_mass[j]
            w = wi + wj
            if w == 0.0:
                continue
            r = rest[e]
            dx, dy = xa[i, 0] - xa[j, 0], xa[i, 1] - xa[j, 1]
            len2 = dx * dx + dy * dy
            if len2 > EPS_LEN2:
                length = math.sqrt(len2)
                f = k * (r - length) / (w * length)
                xa[i, 0] += wi * f * dx
                xa[i, 1] += wi * f * dy
                xa[j, 0] -= wj * f * dx
                xa[j, 1] -= wj * f * dy
            dx, dy = xb[i, 0] - xb[j, 0], xb[i, 1] - xb[j, 1]
            len2 = dx * dx + dy * dy
            if len2 > EPS_LEN2:
                length = math.sqrt(len2)
                f = k * (r - length) / (w * length)
                xb[i, 0] += wi * f * dx
                xb[i, 1] += wi * f * dy
                xb[j, 0] -= wj * f * dx
                xb[j, 1] -= wj * f * dy


@njit(fastmath={"contract"}, nogil=True)
def sweeps_one_call(x, inv_mass, edges, rest, k, sweeps):
    for _ in range(sweeps):
        for e in range(uint32(edges.shape[0])):
            i, j = uint32(edges[e, 0]), uint32(edges[e, 1])
            wi, wj = inv_mass[i], inv_mass[j]
            w = wi + wj
            if w == 0.0:
                continue
            dx, dy = x[i, 0] - x[j, 0], x[i, 1] - x[j, 1]
            len2 = dx * dx + dy * dy
            if len2 <= EPS_LEN2:
                continue
            length = math.sqrt(len2)
            f = k * (rest[e] - length) / (w * length)
            x[i, 0] += wi * f * dx
            x[i, 1] += wi * f * dy
            x[j, 0] -= wj * f * dx
            x[j, 1] -= wj * f * dy


def level_ends(edges: np.ndarray) -> np.ndarray:
    """For each edge, the end of the run of consecutive edges that share no particle with each other."""
    m = edges.shape[0]
    end = np.empty(m, dtype=np.int64)
    start, used = 0, set(edges[0]) if m else set()
    for q in range(1, m + 1):
        if q == m or used.intersection(edges[q]):
            end[start:q] = q
            if q < m:
                start, used = q, set(edges[q])
        else:
            used.update(edges[q])
    return end


def probe(spacing: float | None, rounds: int, reps: int) -> dict[str, float]:
    sim = build_simulation({} if spacing is None else {"spacing": spacing})
    sim.step(None)  # the solver's inverse masses of a step (held particles zeroed)
    s, k = sim.solver, sim.params.k_spring
    w, edges, rest = s.inv_mass_eff.copy(), s.edges, s.rest
    rng = np.random.default_rng(1)
    xa = sim.state.particle_q + 1e-3 * rng.standard_normal(sim.state.particle_q.shape)
    xb = sim.state.particle_q + 1e-3 * rng.standard_normal(sim.state.particle_q.shape)
    ends = level_ends(edges)
    m = edges.shape[0]

    def shipped(x: np.ndarray) -> None:
        for _ in range(SWEEPS):
            solve_edges_pbd_range(x, w, edges, rest, k, 0, m)

    # the same positions, bit for bit
    ref_a, ref_b = xa.copy(), xb.copy()
    shipped(ref_a)
    shipped(ref_b)
    va, pa, pb, oa = xa.copy(), xa.copy(), xb.copy(), xa.copy()
    sweeps_vector(va, w, edges, rest, k, ends, SWEEPS)
    sweeps_pair(pa, pb, w, edges, rest, k, SWEEPS)
    sweeps_one_call(oa, w, edges, rest, k, SWEEPS)
    for name, got, ref in (("vector", va, ref_a), ("pair a", pa, ref_a), ("pair b", pb, ref_b),
                           ("one call", oa, ref_a)):
        if not np.array_equal(got, ref):
            raise SystemExit(f"{name}: not the shipped sweep's positions (max diff {np.abs(got - ref).max():.3g})")
    variants = {
        "shipped sweep": (lambda a, b: shipped(a), 1),
        "vector sqrt/div": (lambda a, b: sweeps_vector(a, w, edges, rest, k, ends, SWEEPS), 1),
        "two scenes interleaved": (lambda a, b: sweeps_pair(a, b, w, edges, rest, k, SWEEPS), 2),
        "one call, 30 sweeps": (lambda a, b: sweeps_one_call(a, w, edges, rest, k, SWEEPS), 1),
    }
    times: dict[str, list[float]] = {name: [] for name in variants}
    for _ in range(rounds):
        for name, (fn, scenes) in variants.items():
            runs = []
            for _ in range(reps):
                a, b = xa.copy(), xb.copy()
                t0 = time.perf_counter_ns()
                fn(a, b)
                runs.append(time.perf_counter_ns() - t0)
            times[name].append(float(np.median(runs)) / (SWEEPS * m * scenes))
    print(f"  {sim.model.n_particles} particles, {m} edges, mean wavefront run {m / len(set(ends)):.1f} edges")
    return {name: float(np.median(v)) for name, v in times.items()}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="bench_out/sweep_probe", help="output directory (PNG)")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--reps", type=int, default=100)
    args = parser.parse_args()
    load = os.getloadavg()[0]
    results = {}
    for scene, spacing in (("paper", None), ("5k", 0.0165)):
        print(f"{scene}:")
        results[scene] = probe(spacing, args.rounds, args.reps)
    print(f"\nns per distance projection (median over {args.rounds} alternating rounds; every variant's positions "
          f"equal the shipped sweep's bit for bit); load {load:.2f} -> {os.getloadavg()[0]:.2f}")
    names = list(next(iter(results.values())))
    print(f"{'variant':26s} " + " ".join(f"{s:>14s}" for s in results))
    for name in names:
        cells = " ".join(f"{results[s][name]:8.2f} ({results[s]['shipped sweep'] / results[s][name]:.2f}x)"
                         for s in results)
        print(f"{name:26s} {cells}")
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(7, 3.5))
    width = 0.8 / len(names)
    for q, name in enumerate(names):
        ax.bar(np.arange(len(results)) + q * width, [results[s][name] for s in results], width, label=name)
    ax.set_xticks(np.arange(len(results)) + 0.4 - width / 2, list(results))
    ax.set_ylabel("ns per distance projection")
    ax.set_title(f"what bounds a sweep (same positions bit for bit); load {load:.2f}")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "sweep_probe.png", dpi=120)
    print(f"wrote {out / 'sweep_probe.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
