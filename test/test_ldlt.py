"""The sparse LDL^T (core/physics/ldlt.py) against its NumPy twins and SciPy.

The systems are the target's: a mesh_rectangle's triangles each coupling their 6 dofs (a random 6x6 G^T G, G
3 x 6) plus a mass diagonal, and 4 tool dofs coupled to a random subset of the vertices. The twins
(:func:`twin_ldlt`, :func:`twin_solve`, :func:`twin_fill`) are dense NumPy on the permuted matrix; the solves
are also compared with ``scipy.sparse.linalg.spsolve`` (to 1e-10 relative).
"""
from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from numba import njit
from numba.core.runtime import _nrt_python, rtsys

from tissue_sim_ros.core.errors import InputError
from tissue_sim_ros.core.mesh import mesh_rectangle
from tissue_sim_ros.core.physics.ldlt import (
    LDLTFactor,
    LDLTPattern,
    ldlt_assemble,
    ldlt_factor,
    ldlt_solve,
    make_workspace,
    solve_workspace,
)

SMALL, MEDIUM = 0.05, 0.0162  # mesh_rectangle(1.0, 0.5, spacing): 231 and 2,016 vertices


def mesh_system(spacing: float, n_tool: int = 4, coupled: float = 0.1, seed: int = 0):
    """(n, rows, cols, values) of the lower triangle of a mesh matrix, entries unsorted and with duplicates (a
    dof pair shared by triangles appears once per triangle); the tool's dofs are the last n_tool."""
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
    for v in rng.choice(nv, size=max(1, int(coupled * nv)), replace=False) if n_tool else []:
        j = 0.3 * rng.standard_normal((2, 2 + n_tool))
        dd = np.concatenate([[2 * v, 2 * v + 1], tool])
        rows.append(np.repeat(dd, dd.size))
        cols.append(np.tile(dd, dd.size))
        vals.append((j.T @ j).ravel())
    r, c, v = np.concatenate(rows), np.concatenate(cols), np.concatenate(vals)
    keep = r >= c
    return 2 * nv + n_tool, r[keep], c[keep], v[keep]


def matrix(n: int, rows: np.ndarray, cols: np.ndarray, values: np.ndarray) -> sp.csc_matrix:
    """The symmetric matrix of the entries: A_ij = A_ji = the sum of the values at (i, j) and (j, i)."""
    t = sp.coo_matrix((values, (rows, cols)), shape=(n, n)).tocsc()
    return sp.csc_matrix(t + t.T - sp.diags(t.diagonal()))


# ----------------------------------------------------------------------------- the NumPy twins


def twin_ldlt(a: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Dense unpivoted LDL^T of ``a`` (n, n): (L (n, n) unit lower, d (n,), status as ldlt_factor's)."""
    a = np.array(a, dtype=np.float64)
    n = a.shape[0]
    lo, d = np.eye(n), np.zeros(n)
    for k in range(n):
        d[k] = a[k, k]
        if not d[k] > 0.0:
            return lo, d, k + 1
        lo[k + 1:, k] = a[k + 1:, k] / d[k]
        a[k + 1:, k + 1:] -= np.outer(lo[k + 1:, k], a[k + 1:, k])
    return lo, d, 0


def twin_solve(perm: np.ndarray, lo: np.ndarray, d: np.ndarray, b: np.ndarray) -> np.ndarray:
    """A^-1 b from the twin's factor of the permuted A: y = P b, L z = y, D w = z, L^T x = w, out = P^T x."""
    z = sla.solve_triangular(lo, b[perm], lower=True, unit_diagonal=True)
    x = sla.solve_triangular(lo.T, z / d, lower=False, unit_diagonal=True)
    out = np.empty_like(x)
    out[perm] = x
    return out


def twin_fill(pattern: np.ndarray) -> np.ndarray:
    """L's structure (n, n) bool from A's (symmetric, bool), by eliminating the columns in order."""
    s = np.tril(pattern | pattern.T | np.eye(pattern.shape[0], dtype=bool))
    for k in range(s.shape[0]):
        below = np.flatnonzero(s[k + 1:, k]) + k + 1
        s[np.ix_(below, below)] |= np.tril(np.ones((below.size, below.size), dtype=bool))
    return s


def l_matrix(fac: LDLTFactor) -> np.ndarray:
    """L (n, n), unit lower in the permuted order, read from the supernodal blocks as the bundle documents them:
    supernode s's columns super_ptr[s]..super_ptr[s+1], its rows rows[rows_ptr[s]:rows_ptr[s+1]], its block
    column-major at l_values[lx_ptr[s]:]."""
    perm, a_colptr, amap, super_ptr, col2super, rows_ptr, rows, lx_ptr, info = fac.pattern.arrays
    lo = np.zeros((fac.pattern.n, fac.pattern.n))
    for s in range(fac.pattern.nsuper):
        f, nc, nr = super_ptr[s], super_ptr[s + 1] - super_ptr[s], rows_ptr[s + 1] - rows_ptr[s]
        block = fac.l_values[lx_ptr[s]:lx_ptr[s + 1]].reshape(nc, nr).T
        rr = rows[rows_ptr[s]:rows_ptr[s + 1]]
        for j in range(nc):
            lo[rr[j:], f + j] = block[j:, j]
    return lo


def relative(x: np.ndarray, ref: np.ndarray) -> float:
    return float(np.linalg.norm(x - ref) / np.linalg.norm(ref))


# ----------------------------------------------------------------------------- against the twins


@pytest.fixture(scope="module")
def small():
    n, r, c, v = mesh_system(SMALL)
    pattern = LDLTPattern(n, r, c)
    fac = LDLTFactor(pattern)
    assert fac.factor(v) == 0
    return n, r, c, v, pattern, fac


def test_factor_matches_the_dense_twin(small) -> None:
    n, r, c, v, pattern, fac = small
    a = matrix(n, r, c, v).toarray()[np.ix_(pattern.perm, pattern.perm)]
    lo, d, status = twin_ldlt(a)
    assert status == 0
    assert np.allclose(fac.d, d, rtol=1e-10, atol=0)
    assert np.abs(l_matrix(fac) - lo).max() < 1e-10 * np.abs(lo).max()
    assert np.allclose(pattern.lower(fac.a_values).toarray(), np.tril(a), rtol=1e-14, atol=1e-14)


def test_solve_matches_the_twin(small) -> None:
    n, r, c, v, pattern, fac = small
    a = matrix(n, r, c, v).toarray()[np.ix_(pattern.perm, pattern.perm)]
    lo, d, _ = twin_ldlt(a)
    b = np.random.default_rng(1).standard_normal(n)
    assert relative(fac.solve(b), twin_solve(pattern.perm, lo, d, b)) < 1e-12


def test_symbolic_analysis_matches_the_twins_fill(small) -> None:
    n, r, c, v, pattern, fac = small
    structure = twin_fill((matrix(n, r, c, np.ones_like(v)).toarray() != 0)[np.ix_(pattern.perm, pattern.perm)])
    assert pattern.nnz_l == structure.sum()
    assert not (l_matrix(fac) != 0)[~structure].any()  # the relaxed supernodes' zeros stay zero
    counts = structure.sum(axis=0)
    assert pattern.fmas == int((counts * (counts - 1) // 2).sum())
    assert pattern.nnz_a == np.count_nonzero(np.tril(matrix(n, r, c, np.ones_like(v)).toarray())) <= pattern.l_size


# ----------------------------------------------------------------------------- against SciPy


@pytest.mark.parametrize("spacing", [SMALL, MEDIUM])
def test_factor_and_solve_match_spsolve(spacing: float) -> None:
    n, r, c, v = mesh_system(spacing)
    a = matrix(n, r, c, v)
    fac = LDLTFactor(LDLTPattern(n, r, c))
    assert fac.factor(v) == 0
    b = np.random.default_rng(2).standard_normal((2, n))
    for bb in b:
        assert relative(fac.solve(bb), spla.spsolve(a, bb)) < 1e-10
    assert fac.pattern.nnz_l < 12 * fac.pattern.nnz_a  # a fill-reducing order: the natural one fills 4x more


def test_duplicates_are_summed_and_either_triangle_is_the_entry(small) -> None:
    n, r, c, v, pattern, fac = small
    rng = np.random.default_rng(3)
    split = rng.uniform(0.0, 1.0, v.size)
    r2, c2, v2 = np.concatenate([r, r]), np.concatenate([c, c]), np.concatenate([split * v, (1 - split) * v])
    swap = rng.random(r2.size) < 0.5
    r2, c2 = np.where(swap, c2, r2), np.where(swap, r2, c2)
    shuffle = rng.permutation(r2.size)
    fac2 = LDLTFactor(LDLTPattern(n, r2[shuffle], c2[shuffle]))
    assert fac2.factor(v2[shuffle]) == 0
    assert np.array_equal(fac2.pattern.perm, pattern.perm)
    assert np.allclose(fac2.d, fac.d, rtol=1e-12, atol=0)
    b = rng.standard_normal(n)
    assert relative(fac2.solve(b), spla.spsolve(matrix(n, r, c, v), b)) < 1e-10


def test_refactoring_with_new_values_gives_the_new_factor(small) -> None:
    n, r, c, v, pattern, _ = small
    fac = LDLTFactor(pattern)
    b = np.random.default_rng(4).standard_normal(n)
    v2 = v * np.random.default_rng(5).uniform(0.5, 2.0, v.size) + (r == c) * 1.0
    assert fac.factor(v) == 0
    x1 = fac.solve(b)
    assert fac.factor(v2) == 0
    assert relative(fac.solve(b), spla.spsolve(matrix(n, r, c, v2), b)) < 1e-10
    assert relative(fac.solve(b), x1) > 1e-3
    assert fac.factor(v) == 0
    assert np.array_equal(fac.solve(b), x1)  # nothing of the previous factor carries over


def test_a_non_positive_pivot_is_reported_and_a_shift_cures_it(small) -> None:
    n, r, c, v, pattern, _ = small
    fac = LDLTFactor(pattern)
    dof = int(pattern.perm[n // 3])
    bad = v.copy()
    bad[np.flatnonzero((r == dof) & (c == dof))[0]] -= 1e3  # indefinite
    a = matrix(n, r, c, bad)
    _, _, status = twin_ldlt(a.toarray()[np.ix_(pattern.perm, pattern.perm)])
    assert status == n // 3 + 1
    assert fac.factor(bad) == status
    with pytest.raises(InputError, match="not positive"):
        fac.solve(np.ones(n))
    assert fac.factor(bad, shift=2e3) == 0
    b = np.random.default_rng(6).standard_normal(n)
    assert relative(fac.solve(b), spla.spsolve(a + 2e3 * sp.identity(n), b)) < 1e-10
    assert fac.factor(np.where(np.arange(v.size) == 0, np.nan, v)) > 0  # a NaN pivot is not positive


def test_dense_tool_rows_are_ordered_last() -> None:
    n, r, c, v = mesh_system(SMALL, coupled=0.9)  # the tool couples to 90 % of the vertices: dense rows
    pattern = LDLTPattern(n, r, c)
    assert sorted(pattern.perm[-4:]) == list(range(n - 4, n))
    fac = LDLTFactor(pattern)
    assert fac.factor(v) == 0
    b = np.random.default_rng(7).standard_normal(n)
    assert relative(fac.solve(b), spla.spsolve(matrix(n, r, c, v), b)) < 1e-10
    n, r, c, v = mesh_system(SMALL, coupled=0.02)  # 4 vertices: not dense, unless the caller says so
    pattern = LDLTPattern(n, r, c, last=np.arange(n - 4, n))
    assert sorted(pattern.perm[-4:]) == list(range(n - 4, n))
    fac = LDLTFactor(pattern)
    assert fac.factor(v) == 0
    assert relative(fac.solve(b), spla.spsolve(matrix(n, r, c, v), b)) < 1e-10


def test_small_and_degenerate_patterns() -> None:
    one = LDLTFactor(LDLTPattern(1, [0], [0]))
    assert one.factor([4.0]) == 0 and one.solve(np.array([2.0]))[0] == 0.5
    assert one.factor([0.0]) == 1
    diag = LDLTFactor(LDLTPattern(5, [], []))  # the diagonal is always in the pattern
    assert diag.factor([]) == 1  # ... with zeros on it
    assert diag.factor([], shift=2.0) == 0 and np.array_equal(diag.solve(np.arange(5.0)), np.arange(5.0) / 2)
    # two disconnected meshes (a forest), in the natural order and the fill-reducing one
    n, r, c, v = mesh_system(0.25, n_tool=0)
    r2, c2, v2 = np.concatenate([r, r + n]), np.concatenate([c, c + n]), np.concatenate([v, 2 * v])
    a = matrix(2 * n, r2, c2, v2)
    b = np.random.default_rng(8).standard_normal(2 * n)
    for order in (None, np.arange(2 * n)):
        fac = LDLTFactor(LDLTPattern(2 * n, r2, c2, order=order))
        assert fac.factor(v2) == 0
        assert relative(fac.solve(b), spla.spsolve(a, b)) < 1e-10


def test_bad_input_is_refused(small) -> None:
    n, r, c, v, pattern, fac = small
    with pytest.raises(InputError, match="one length"):
        LDLTPattern(n, r, c[:-1])
    with pytest.raises(InputError, match="outside"):
        LDLTPattern(n, r, c + n)
    with pytest.raises(InputError, match="permutation"):
        LDLTPattern(n, r, c, order=np.zeros(n, np.int64))
    with pytest.raises(InputError, match="expected"):
        fac.factor(v[:-1])
    with pytest.raises(InputError, match="expected"):
        fac.solve(np.ones(n + 1))
    with pytest.raises(ValueError, match="shorter"):
        ldlt_factor(pattern.arrays, fac.a_values, fac.l_values[:-1], fac.d, fac.work)
    with pytest.raises(ValueError, match="too short"):
        ldlt_factor(pattern.arrays, fac.a_values, fac.l_values, fac.d, fac.work[:5] + (fac.work[5][:1],))
    with pytest.raises(ValueError, match="shorter"):
        ldlt_solve(pattern.arrays, fac.l_values, fac.d, np.ones(n), np.empty(n), np.empty(n))


# ----------------------------------------------------------------------------- the kernels allocate nothing


@njit(cache=True)
def _factor_and_solve(slot, values, pattern, a_values, l_values, d, work, b, out, solve_work, times):
    status = 0
    for _ in range(times):
        ldlt_assemble(slot, values, a_values)
        status = ldlt_factor(pattern, a_values, l_values, d, work)
        ldlt_solve(pattern, l_values, d, b, out, solve_work)
    return status


def test_the_kernels_allocate_nothing(small) -> None:
    n, r, c, v, pattern, fac = small
    args = (pattern.slot, v, pattern.arrays, np.empty(pattern.nnz_a), np.empty(pattern.l_size), np.empty(n),
            make_workspace(pattern), np.ones(n), np.empty(n), solve_workspace(pattern))
    assert _factor_and_solve(*args, 1) == 0
    _nrt_python.memsys_enable_stats()
    try:
        counts = []
        for times in (1, 4):
            before = rtsys.get_allocation_stats().alloc
            _factor_and_solve(*args, times)
            counts.append(rtsys.get_allocation_stats().alloc - before)
    finally:
        _nrt_python.memsys_disable_stats()
    assert counts[0] == counts[1]  # the arguments' wrappers only, not one more per factor and solve
    assert np.allclose(args[8], fac.solve(np.ones(n)), rtol=1e-12)
