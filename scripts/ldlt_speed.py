"""Time the sparse LDL^T (core/physics/ldlt.py) beside SciPy's SuperLU, CHOLMOD (cholespy) and QDLDL.

The matrices are the Newton step's: mesh_rectangle(1.0, 0.5, spacing), 2 dofs a vertex, each triangle a dense
6x6 SPD block (G^T G, G random 3 x 6) plus a mass diagonal, and 4 tool dofs coupled to a tenth of the vertices.
Prints one row per mesh: the fill, and the medians (of --repeat runs, interleaved so that a change of the
machine's load hits every column alike) of

* ldlt: the symbolic analysis (once), the numeric refactorisation, the solve;
* splu: ``scipy.sparse.linalg.splu`` (MMD on A^T + A, no pivoting) factorisation and solve;
* cholespy: CHOLMOD's analysis and factorisation (it has no refactorisation), and its solve;
* qdldl: a new Solver (AMD, symbolic, numeric), its numeric ``update``, and its solve.

``--orders`` prints instead the fill, the multiply-adds and the ldlt times of the orderings that were compared
(MMD on the dofs; MMD on the vertices, the module's; SuiteSparse's AMD, taken from qdldl; a geometric nested
dissection; reverse Cuthill-McKee). BLAS runs on one thread (OPENBLAS_NUM_THREADS, unless set). The load
(/proc/loadavg) is printed before and after: the machine may be shared. ::

    python scripts/ldlt_speed.py [--spacings 0.0162 0.0082 0.0058] [--repeat 15] [--orders] [--cpu]
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402
import scipy.sparse.linalg as spla  # noqa: E402
from scipy.sparse.csgraph import reverse_cuthill_mckee  # noqa: E402

from tissue_sim_ros.core.mesh import mesh_rectangle  # noqa: E402
from tissue_sim_ros.core.physics import ldlt  # noqa: E402


def mesh_system(spacing: float, n_tool: int = 4, coupled: float = 0.1, seed: int = 0):
    """(mesh, n, rows, cols, values): the lower triangle's entries, with duplicates; the tool's dofs last."""
    m = mesh_rectangle(1.0, 0.5, spacing)
    tris = m.triangles.astype(np.int64)
    nv = m.vertices.shape[0]
    rng = np.random.default_rng(seed)
    g = rng.standard_normal((tris.shape[0], 3, 6))
    dofs = np.stack([2 * tris[:, k] + c for k in range(3) for c in range(2)], axis=1)
    rows = [np.repeat(dofs, 6, axis=1).ravel(), np.arange(2 * nv + n_tool)]
    cols = [np.tile(dofs, (1, 6)).ravel(), np.arange(2 * nv + n_tool)]
    vals = [np.einsum("tki,tkj->tij", g, g).ravel(), np.full(2 * nv + n_tool, 0.1)]
    tool = 2 * nv + np.arange(n_tool)
    for v in rng.choice(nv, size=max(1, int(coupled * nv)), replace=False):
        j = 0.3 * rng.standard_normal((2, 2 + n_tool))
        dd = np.concatenate([[2 * v, 2 * v + 1], tool])
        rows.append(np.repeat(dd, dd.size))
        cols.append(np.tile(dd, dd.size))
        vals.append((j.T @ j).ravel())
    r, c, v = np.concatenate(rows), np.concatenate(cols), np.concatenate(vals)
    keep = r >= c
    return m, 2 * nv + n_tool, r[keep], c[keep], v[keep]


def matrix(n, rows, cols, values) -> sp.csc_matrix:
    t = sp.coo_matrix((values, (rows, cols)), shape=(n, n)).tocsc()
    return sp.csc_matrix(t + t.T - sp.diags(t.diagonal()))


def load() -> str:
    with open("/proc/loadavg") as f:
        return " ".join(f.read().split()[:3])


CLOCK = [time.perf_counter]


def timed(fn) -> float:
    t = CLOCK[0]()
    fn()
    return CLOCK[0]() - t


def interleaved(runs: dict, repeat: int) -> dict:
    """{name: median seconds}: every function once a round, ``repeat`` rounds (after one warm-up round)."""
    for fn in runs.values():
        fn()
    times = {name: [] for name in runs}
    for _ in range(repeat):
        for name, fn in runs.items():
            times[name].append(timed(fn))
    return {name: float(np.median(t)) for name, t in times.items()}


def speed_row(spacing: float, repeat: int) -> str:
    import qdldl
    from cholespy import CholeskySolverD, MatrixType

    mesh, n, r, c, v = mesh_system(spacing)
    a = matrix(n, r, c, v)
    a.sort_indices()
    b = np.random.default_rng(1).standard_normal(n)
    ldlt.LDLTPattern(n, r, c)  # loads the compiled kernels
    t0 = time.perf_counter()
    pattern = ldlt.LDLTPattern(n, r, c)
    analyse = time.perf_counter() - t0
    fac = ldlt.LDLTFactor(pattern)
    fac.factor(v)
    out, work = np.empty(n), ldlt.solve_workspace(pattern)
    lu = spla.splu(a, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    ii, jj = a.indptr.astype(np.int32), a.indices.astype(np.int32)
    chol = CholeskySolverD(n, ii, jj, a.data.copy(), MatrixType.CSC)
    x = np.zeros(n)
    q = qdldl.Solver(a)
    runs = {
        "factor": lambda: ldlt.ldlt_factor(pattern.arrays, fac.a_values, fac.l_values, fac.d, fac.work),
        "solve": lambda: ldlt.ldlt_solve(pattern.arrays, fac.l_values, fac.d, b, out, work),
        "lu": lambda: spla.splu(a, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                                options={"SymmetricMode": True}),
        "lu_solve": lambda: lu.solve(b),
        "chol": lambda: CholeskySolverD(n, ii, jj, a.data, MatrixType.CSC),
        "chol_solve": lambda: chol.solve(b, x),
        "qdldl": lambda: qdldl.Solver(a),
        "qdldl_update": lambda: q.update(a),
        "qdldl_solve": lambda: q.solve(b),
    }
    t = {k: 1e3 * s for k, s in interleaved(runs, repeat).items()}
    err = max(np.linalg.norm(a @ y - b) / np.linalg.norm(b) for y in (out, lu.solve(b), x, q.solve(b)))
    lq = q.factors()[0].nnz + n
    return (f"{mesh.vertices.shape[0]:>8} {n:>6} {pattern.nnz_l / 1e6:>6.2f} {lq / 1e6:>6.2f} |{analyse * 1e3:>7.0f}"
            f" {t['factor']:>7.2f} {t['solve']:>6.3f} |{t['lu']:>7.1f} {t['lu_solve']:>6.2f} |{t['chol']:>7.1f}"
            f" {t['chol_solve']:>6.3f} |{t['qdldl']:>7.1f} {t['qdldl_update']:>7.1f} {t['qdldl_solve']:>6.3f}"
            f" | {err:.0e}")


SPEED_HEAD = ("                          nnz(L) [M] |     ldlt [ms]          |   splu [ms]    |  cholespy [ms] "
              "|        qdldl [ms]       |\n"
              "vertices      n   ldlt    amd |analyse  factor  solve | factor  solve | factor  solve "
              "|    new  update  solve | residual")


def nested_dissection(xy: np.ndarray, adj: sp.csr_matrix, idx: np.ndarray, leaf: int, out: list) -> None:
    """Geometric nested dissection of the vertices ``idx``: a median cut across the longer side, the cut's
    vertices on one side last; leaves of at most ``leaf`` vertices ordered by MMD."""
    if idx.size <= leaf:
        out.extend(idx[ldlt.order_mmd(adj[idx][:, idx].tocsr())] if idx.size > 2 else idx)
        return
    p = xy[idx]
    axis = int(np.argmax(p.max(0) - p.min(0)))
    left = p[:, axis] < np.median(p[:, axis])
    right = np.zeros(adj.shape[0])
    right[idx[~left]] = 1.0
    cut = (adj[idx[left]] @ right) > 0
    nested_dissection(xy, adj, idx[left][~cut], leaf, out)
    nested_dissection(xy, adj, idx[~left], leaf, out)
    out.extend(idx[left][cut])


def order_rows(spacing: float, repeat: int) -> list[str]:
    import qdldl

    mesh, n, r, c, v = mesh_system(spacing)
    a = matrix(n, r, c, v)
    nv = mesh.vertices.shape[0]
    tool = np.arange(2 * nv, n)
    e = np.concatenate([mesh.triangles[:, [0, 1]], mesh.triangles[:, [1, 2]], mesh.triangles[:, [2, 0]]])
    adj = sp.csr_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(nv, nv))

    def dofs(vertex_order):
        vo = np.asarray(vertex_order, np.int64)
        return np.concatenate([np.stack([2 * vo, 2 * vo + 1], 1).ravel(), tool])

    def mmd_dofs():
        g = ldlt._graph(n, r, c)
        keep = np.setdiff1d(np.arange(n), tool)
        return np.concatenate([keep[ldlt.order_mmd(g[keep][:, keep].tocsr())], tool])

    def nd(leaf):
        out = []
        nested_dissection(mesh.vertices, adj, np.arange(nv), leaf, out)
        return dofs(out)

    orders = {"mmd, dofs": mmd_dofs, "mmd, vertices (ldlt)": lambda: ldlt.fill_order(n, r, c),
              "amd (qdldl's)": lambda: np.asarray(qdldl.Solver(a).factors()[2], np.int64),
              "nd, leaves 256": lambda: nd(256), "nd, leaves 4000": lambda: nd(4000),
              "rcm": lambda: reverse_cuthill_mckee(a.tocsr(), symmetric_mode=True).astype(np.int64)}
    rows = []
    b = np.random.default_rng(1).standard_normal(n)
    for name, make in orders.items():
        t0 = time.perf_counter()
        order = make()
        t_order = time.perf_counter() - t0
        pattern = ldlt.LDLTPattern(n, r, c, order=order)
        times = ""
        if pattern.fmas < 5e8:  # rcm's factor takes seconds
            fac = ldlt.LDLTFactor(pattern)
            fac.factor(v)
            t = interleaved({"f": lambda: fac.factor(v), "s": lambda: fac.solve(b)}, repeat)
            times = f"{t['f'] * 1e3:>8.2f} {t['s'] * 1e3:>7.3f}"
        rows.append(f"{nv:>8} {name:<22} {t_order * 1e3:>7.0f} {pattern.nnz_l / 1e6:>7.3f} {pattern.fmas / 1e6:>8.1f}"
                    f" {times}")
    return rows


ORDER_HEAD = "vertices ordering              ms     nnz(L)[M] fma[M]  factor  solve [ms]"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--spacings", type=float, nargs="+", default=[0.0162, 0.0082, 0.0058])
    p.add_argument("--repeat", type=int, default=15)
    p.add_argument("--orders", action="store_true", help="compare the orderings instead")
    p.add_argument("--cpu", action="store_true", help="time the thread's CPU time, not the wall clock (every "
                   "solver here runs on the calling thread): a loaded machine's descheduling then does not count")
    args = p.parse_args()
    if args.cpu:
        CLOCK[0] = time.thread_time
    print(f"load before: {load()}  (OPENBLAS_NUM_THREADS={os.environ['OPENBLAS_NUM_THREADS']}, "
          f"{'thread CPU time' if args.cpu else 'wall clock'})")
    print(ORDER_HEAD if args.orders else SPEED_HEAD)
    for spacing in args.spacings:
        for row in order_rows(spacing, args.repeat) if args.orders else [speed_row(spacing, args.repeat)]:
            print(row, flush=True)
    print(f"load after: {load()}")


if __name__ == "__main__":
    main()
