"""A sparse symmetric LDL^T factorisation in numba, for a matrix refactored many times on one sparsity pattern.

A Newton or quasi-Newton step solves with M + dt^2 K whose pattern is fixed by the mesh (and a tool's pose
dofs) while its values change every step. :class:`LDLTPattern` analyses the pattern once: a fill-reducing
order, the elimination tree, L's column counts, relaxed supernodes and their rows, and where each assembled
entry lands (``slot``). :func:`ldlt_factor` then refactors numerically without allocating, and
:func:`ldlt_solve` applies the factor (A^-1 b) as often as wanted. :class:`LDLTFactor` wraps the three for
callers outside numba.

Choices, measured by ``scripts/ldlt_speed.py`` on its mesh matrices (2D triangle meshes, 2 dofs a vertex, a
dense 6x6 block a triangle, 4 tool dofs coupled to a tenth of the vertices; 2,000 to 15,000 vertices):

* Ordering: SuperLU's multiple minimum degree (``MMD_AT_PLUS_A``) on the graph with the two dofs of a vertex
  merged (indistinguishable nodes) and the dense rows set aside and ordered last. Its fill matches AMD's
  (SuiteSparse's, as qdldl orders) to 2 %: 1.25 M entries of L at 15,000 vertices. Merging the dofs about
  halves the ordering's time and takes up to 6 % off the multiply-adds. A geometric nested dissection (median
  cuts, MMD on leaves of 256 or 4,000 vertices) filled 2 to 30 % more and was as fast or slower; reverse
  Cuthill-McKee filled 11 to 47 times more.
* Numeric factorisation: supernodal, left-looking (as CHOLMOD's), each supernode a dense column-major block
  (its own columns and the rows below), a descendant's update as multi-column AXPYs into a buffer scattered
  into the target, two target columns a pass. Relaxed supernodes (CHOLMOD's amalgamation rule, smaller
  limits: :data:`RELAX`) trade a few explicit zeros for longer loops. Loops run on array views, never on
  offset indices into one array: numba then vectorises them (with an offset index it must allow a negative
  one and leaves the loop scalar, 3 to 4 times slower). BLAS (``np.dot`` into a buffer, allocation-free) for
  the large updates was no faster than the two-column loops, nor was a blocked dense factor of the large
  supernodes, so the kernels call no BLAS (and start no BLAS threads). QDLDL's up-looking factor (qdldl's
  ``update``, on its AMD order of the same fill) took 2 to 4 times as long; SuperLU's factor 7 to 10 times.
* Solve: forward and backward substitution by supernode, the rows below a supernode gathered (or scattered)
  once per supernode: as fast as CHOLMOD's supernodal solve (cholespy) to about 10 %.

The bundles (tuples of arrays, documented where they are made): ``LDLTPattern.arrays`` for both kernels,
:func:`make_workspace` for the factor, :func:`solve_workspace` for the solve.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla
from numba import njit

from ..errors import InputError

#: Relaxed supernodes: (nrelax0, nrelax1, nrelax2, zrelax0, zrelax1, zrelax2). A supernode merges into its
#: parent while it has at most nrelax0 columns, or at most nrelax1 with a fraction of explicit zeros below
#: zrelax0, or nrelax2 below zrelax1, or any width below zrelax2 (CHOLMOD's rule; its limits are 4, 16, 48,
#: 0.8, 0.1, 0.05). These smaller ones kept the factor as fast and the solve 10 % faster (fewer zeros to read).
RELAX = (4, 8, 32, 0.8, 0.05, 0.01)
#: The loops that may reassociate (a vectorised dot product) and fuse multiply-adds; no other fast-math flag
#: (a NaN pivot must still fail ``d > 0``).
FM = {"reassoc", "contract"}

# ----------------------------------------------------------------------------- symbolic kernels (made once)


@njit(cache=True)
def _etree(n, rowptr, colind):
    """The elimination tree from the lower CSR (row k: its columns j <= k): parent (n,) int64, -1 at a root
    (Liu's algorithm with path compression)."""
    parent = np.full(n, -1, np.int64)
    ancestor = np.full(n, -1, np.int64)
    for k in range(n):
        for p in range(rowptr[k], rowptr[k + 1]):
            i = colind[p]
            while i != -1 and i < k:
                inext = ancestor[i]
                ancestor[i] = k
                if inext == -1:
                    parent[i] = k
                i = inext
    return parent


@njit(cache=True)
def _postorder(parent):
    """A postorder of the forest ``parent`` (n,) int64: post (n,) int64, post[k] = the k-th node visited."""
    n = parent.shape[0]
    head = np.full(n, -1, np.int64)
    nxt = np.full(n, -1, np.int64)
    for j in range(n - 1, -1, -1):
        if parent[j] != -1:
            nxt[j] = head[parent[j]]
            head[parent[j]] = j
    post = np.empty(n, np.int64)
    stack = np.empty(n, np.int64)
    k = 0
    for root in range(n):
        if parent[root] != -1:
            continue
        top = 0
        stack[0] = root
        while top >= 0:
            c = head[stack[top]]
            if c == -1:
                post[k] = stack[top]
                k += 1
                top -= 1
            else:
                head[stack[top]] = nxt[c]
                top += 1
                stack[top] = c
    return post


@njit(cache=True)
def _colcounts(n, rowptr, colind, parent):
    """Entries in each column of L, the diagonal included, by walking each row's subtree: count (n,) int64."""
    count = np.ones(n, np.int64)
    mark = np.full(n, -1, np.int64)
    for k in range(n):
        mark[k] = k
        for p in range(rowptr[k], rowptr[k + 1]):
            j = colind[p]
            while mark[j] != k:
                mark[j] = k
                count[j] += 1
                j = parent[j]
    return count


@njit(cache=True)
def _fundamental(parent, count):
    """Fundamental supernodes of a postordered tree: fstart (nf+1,) int64, the first column of each."""
    n = parent.shape[0]
    nchild = np.zeros(n, np.int64)
    for j in range(n):
        if parent[j] != -1:
            nchild[parent[j]] += 1
    fstart = np.empty(n + 1, np.int64)
    nf = 0
    for j in range(n):
        if j == 0 or not (parent[j - 1] == j and count[j - 1] == count[j] + 1 and nchild[j] == 1):
            fstart[nf] = j
            nf += 1
    fstart[nf] = n
    return fstart[:nf + 1].copy()


@njit(cache=True)
def _relax(parent, count, fstart, relax):
    """Merge fundamental supernodes (CHOLMOD's amalgamation, limits ``relax`` as :data:`RELAX`): super_ptr
    (nsuper+1,) int64. Supernode s joins the group starting at s+1 when that group holds s's parent."""
    nf = fstart.shape[0] - 1
    fsuper = np.empty(parent.shape[0], np.int64)
    ncol = np.empty(nf, np.int64)
    snz = np.empty(nf, np.int64)
    end = np.empty(nf, np.int64)
    for s in range(nf):
        fsuper[fstart[s]:fstart[s + 1]] = s
        ncol[s] = fstart[s + 1] - fstart[s]
        snz[s] = count[fstart[s]]
        end[s] = s
    zeros = np.zeros(nf)
    leader = np.ones(nf, np.bool_)
    for s in range(nf - 2, -1, -1):
        up = parent[fstart[s + 1] - 1]
        if up == -1 or not s + 1 <= fsuper[up] <= end[s + 1]:
            continue
        g = s + 1
        ns = ncol[s] + ncol[g]
        newz = ncol[s] * (ncol[g] + snz[g] - snz[s])
        totz = zeros[s] + zeros[g] + newz
        z = totz / (ns * (ns + 1) / 2 + ns * (snz[g] - ncol[g]))
        if (newz == 0 or ns <= relax[0] or (ns <= relax[1] and z < relax[3]) or (ns <= relax[2] and z < relax[4])
                or z < relax[5]):
            snz[s] = ncol[s] + snz[g]
            ncol[s] = ns
            zeros[s] = totz
            end[s] = end[g]
            leader[g] = False
    starts = np.flatnonzero(leader)
    super_ptr = np.empty(starts.shape[0] + 1, np.int64)
    for k in range(starts.shape[0]):
        super_ptr[k] = fstart[starts[k]]
    super_ptr[-1] = parent.shape[0]
    return super_ptr


@njit(cache=True)
def _super_rows(n, colptr, rowind, parent, super_ptr):
    """Each supernode's rows, its own columns first and then the rows below, sorted: (rows_ptr (nsuper+1,),
    rows (rows_ptr[-1],), col2super (n,)), all int64. The rows below are A's and the children's."""
    nsuper = super_ptr.shape[0] - 1
    col2super = np.empty(n, np.int64)
    for s in range(nsuper):
        col2super[super_ptr[s]:super_ptr[s + 1]] = s
    head = np.full(nsuper, -1, np.int64)
    nxt = np.full(nsuper, -1, np.int64)
    for s in range(nsuper):
        up = parent[super_ptr[s + 1] - 1]
        if up != -1:
            nxt[s] = head[col2super[up]]
            head[col2super[up]] = s
    mark = np.full(n, -1, np.int64)
    rows = np.empty(4 * n + 16, np.int64)
    rows_ptr = np.zeros(nsuper + 1, np.int64)
    buf = np.empty(n, np.int64)
    for s in range(nsuper):
        f, l1 = super_ptr[s], super_ptr[s + 1]
        m = 0
        for p in range(colptr[f], colptr[l1]):
            if rowind[p] >= l1 and mark[rowind[p]] != s:
                mark[rowind[p]] = s
                buf[m] = rowind[p]
                m += 1
        c = head[s]
        while c != -1:
            for p in range(rows_ptr[c], rows_ptr[c + 1]):
                if rows[p] >= l1 and mark[rows[p]] != s:
                    mark[rows[p]] = s
                    buf[m] = rows[p]
                    m += 1
            c = nxt[c]
        top = rows_ptr[s]
        if top + (l1 - f) + m > rows.shape[0]:
            grown = np.empty(2 * (top + (l1 - f) + m), np.int64)
            grown[:top] = rows[:top]
            rows = grown
        rows[top:top + l1 - f] = np.arange(f, l1)
        rows[top + l1 - f:top + l1 - f + m] = np.sort(buf[:m])
        rows_ptr[s + 1] = top + l1 - f + m
    return rows_ptr, rows[:rows_ptr[-1]].copy(), col2super


@njit(cache=True)
def _a_to_l(n, colptr, rowind, super_ptr, rows_ptr, rows, lx_ptr):
    """Where each entry of A's lower CSC lands in L's values: amap (nnz_a,) int64."""
    amap = np.empty(rowind.shape[0], np.int64)
    local = np.empty(n, np.int64)
    for s in range(super_ptr.shape[0] - 1):
        nr = rows_ptr[s + 1] - rows_ptr[s]
        for r in range(rows_ptr[s], rows_ptr[s + 1]):
            local[rows[r]] = r - rows_ptr[s]
        for j in range(super_ptr[s], super_ptr[s + 1]):
            for p in range(colptr[j], colptr[j + 1]):
                amap[p] = lx_ptr[s] + (j - super_ptr[s]) * nr + local[rowind[p]]
    return amap


@njit(cache=True)
def _supervariables(indptr, indices):
    """Group the nodes whose closed neighbourhoods are equal (a vertex's two dofs), by a hash and a check:
    rep (n,) int64, the group's first node for each node. ``indptr``, ``indices``: the graph's CSR, no diagonal."""
    n = indptr.shape[0] - 1
    key = np.empty(n, np.int64)
    for i in range(n):
        key[i] = (i + indices[indptr[i]:indptr[i + 1]].sum()) * (n + 1) + (indptr[i + 1] - indptr[i])
    order = np.argsort(key)
    rep = np.full(n, -1, np.int64)
    mark = np.full(n, -1, np.int64)
    a = 0
    while a < n:
        b = a + 1
        while b < n and key[order[b]] == key[order[a]]:
            b += 1
        for x in range(a, b):
            i = order[x]
            if rep[i] != -1:
                continue
            rep[i] = i
            mark[i] = i
            mark[indices[indptr[i]:indptr[i + 1]]] = i
            for y in range(x + 1, b):
                j = order[y]
                if rep[j] == -1 and mark[j] == i and np.all(mark[indices[indptr[j]:indptr[j + 1]]] == i):
                    rep[j] = i
        a = b
    return rep


# ----------------------------------------------------------------------------- the ordering (made once)


def _graph(n: int, rows: np.ndarray, cols: np.ndarray) -> sp.csr_matrix:
    """The symmetric adjacency of the entries, no diagonal: an n x n CSR of int8 ones."""
    off = rows != cols
    r = np.concatenate([rows[off], cols[off]])
    c = np.concatenate([cols[off], rows[off]])
    g = sp.csr_matrix((np.ones(r.shape[0], np.int8), (r, c)), shape=(n, n))
    g.sum_duplicates()
    g.data[:] = 1
    return g


def dense_nodes(graph: sp.csr_matrix) -> np.ndarray:
    """The nodes of degree past max(16, 10 sqrt(n)) (AMD's rule), which are ordered last: (m,) int64."""
    n = graph.shape[0]
    return np.flatnonzero(np.diff(graph.indptr) > max(16.0, 10.0 * np.sqrt(n))).astype(np.int64)


def order_mmd(graph: sp.csr_matrix) -> np.ndarray:
    """SuperLU's multiple minimum degree on A^T + A of a diagonally dominant matrix of the graph's pattern
    (no pivoting): order (n,) int64, order[k] = the node eliminated k-th."""
    n = graph.shape[0]
    if n <= 2:
        return np.arange(n, dtype=np.int64)
    a = sp.csc_matrix(-graph.astype(np.float64) + sp.diags(np.diff(graph.indptr) + 1.0))
    lu = sla.splu(a, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    return np.argsort(lu.perm_c).astype(np.int64)


def fill_order(n: int, rows: np.ndarray, cols: np.ndarray, last: np.ndarray | None = None) -> np.ndarray:
    """A fill-reducing order of the symmetric pattern (rows, cols (K,) int64): perm (n,) int64, perm[k] = the
    node eliminated k-th. MMD on the graph with indistinguishable nodes merged; ``last`` (default
    :func:`dense_nodes`) set aside and ordered last, in increasing order."""
    graph = _graph(n, rows, cols)
    last = dense_nodes(graph) if last is None else np.unique(np.asarray(last, np.int64))
    keep = np.ones(n, bool)
    keep[last] = False
    idx = np.flatnonzero(keep)
    g = graph[idx][:, idx].tocsr()
    reps, sv = np.unique(_supervariables(g.indptr.astype(np.int64), g.indices.astype(np.int64)),
                         return_inverse=True)
    coo = g.tocoo()
    r, c = sv[coo.row], sv[coo.col]
    off = r != c
    gc = sp.csr_matrix((np.ones(int(off.sum()), np.int8), (r[off], c[off])), shape=(reps.size, reps.size))
    gc.sum_duplicates()
    gc.data[:] = 1
    rank = np.empty(reps.size, np.int64)
    rank[order_mmd(gc)] = np.arange(reps.size)
    return np.concatenate([idx[np.argsort(rank[sv], kind="stable")], last]).astype(np.int64)


def _lower_csc(n: int, r: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The lower-triangle CSC pattern of entries (r, c) (K,) plus the whole diagonal, rows sorted: (colptr
    (n+1,), rowind (nnz,), slot (K,)) int64, slot[k] = the position of entry k."""
    lo = np.maximum(r, c)
    keys = np.concatenate([np.minimum(r, c) * n + lo, np.arange(n, dtype=np.int64) * (n + 1)])
    uniq, inv = np.unique(keys, return_inverse=True)
    col = uniq // n
    colptr = np.searchsorted(col, np.arange(n + 1)).astype(np.int64)
    return colptr, (uniq - col * n).astype(np.int64), inv.reshape(-1)[:r.shape[0]].astype(np.int64)


def _rows_of(n: int, colptr: np.ndarray, rowind: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The CSR (rowptr (n+1,), colind, int64, sorted) of the CSC pattern (colptr, rowind)."""
    t = sp.csc_matrix((np.ones(rowind.shape[0], np.int8), rowind, colptr), shape=(n, n)).tocsr()
    t.sort_indices()
    return t.indptr.astype(np.int64), t.indices.astype(np.int64)


# ----------------------------------------------------------------------------- the numeric kernels


@njit(cache=True, nogil=True, fastmath=FM)
def _gemv_sub(y, lx, c0, ld, ncols, x, m):
    """y[:m] -= sum_k lx[c0 + k ld : c0 + k ld + m] x[k] for k < ncols, four columns a pass over y."""
    k = 0
    while k + 4 <= ncols:
        a0 = lx[c0 + k * ld:c0 + k * ld + m]
        a1 = lx[c0 + (k + 1) * ld:c0 + (k + 1) * ld + m]
        a2 = lx[c0 + (k + 2) * ld:c0 + (k + 2) * ld + m]
        a3 = lx[c0 + (k + 3) * ld:c0 + (k + 3) * ld + m]
        x0, x1, x2, x3 = x[k], x[k + 1], x[k + 2], x[k + 3]
        for i in range(m):
            y[i] -= a0[i] * x0 + a1[i] * x1 + a2[i] * x2 + a3[i] * x3
        k += 4
    if k + 2 <= ncols:
        a0 = lx[c0 + k * ld:c0 + k * ld + m]
        a1 = lx[c0 + (k + 1) * ld:c0 + (k + 1) * ld + m]
        x0, x1 = x[k], x[k + 1]
        for i in range(m):
            y[i] -= a0[i] * x0 + a1[i] * x1
        k += 2
    if k < ncols:
        a0 = lx[c0 + k * ld:c0 + k * ld + m]
        x0 = x[k]
        for i in range(m):
            y[i] -= a0[i] * x0


@njit(cache=True, nogil=True, fastmath=FM)
def _gemv2_sub(y0, y1, lx, c0, ld, ncols, x0, x1, m):
    """y0[:m] -= sum_k lx[c0 + k ld:][:m] x0[k] and y1 likewise with x1: two targets a pass over the columns."""
    k = 0
    while k + 4 <= ncols:
        a0 = lx[c0 + k * ld:c0 + k * ld + m]
        a1 = lx[c0 + (k + 1) * ld:c0 + (k + 1) * ld + m]
        a2 = lx[c0 + (k + 2) * ld:c0 + (k + 2) * ld + m]
        a3 = lx[c0 + (k + 3) * ld:c0 + (k + 3) * ld + m]
        u0, u1, u2, u3 = x0[k], x0[k + 1], x0[k + 2], x0[k + 3]
        v0, v1, v2, v3 = x1[k], x1[k + 1], x1[k + 2], x1[k + 3]
        for i in range(m):
            y0[i] -= a0[i] * u0 + a1[i] * u1 + a2[i] * u2 + a3[i] * u3
            y1[i] -= a0[i] * v0 + a1[i] * v1 + a2[i] * v2 + a3[i] * v3
        k += 4
    while k < ncols:
        a0 = lx[c0 + k * ld:c0 + k * ld + m]
        u0, v0 = x0[k], x1[k]
        for i in range(m):
            y0[i] -= a0[i] * u0
            y1[i] -= a0[i] * v0
        k += 1


@njit(cache=True, nogil=True, fastmath=FM)
def _update(lx, d, super_ptr, rows_ptr, rows, lx_ptr, dd, s, p1, p2, local, wi, wf):
    """Subtract descendant dd's update L_dd[p1:] D_dd L_dd[p1:p2]^T from supernode s's block; its rows p1..p2
    are in s's columns. ``local`` maps a row to its place in s; ``wi``, ``wf`` scratch."""
    fd, ncd = super_ptr[dd], super_ptr[dd + 1] - super_ptr[dd]
    rd0, nrd, bd = rows_ptr[dd], rows_ptr[dd + 1] - rows_ptr[dd], lx_ptr[dd]
    f, nrs, bs = super_ptr[s], rows_ptr[s + 1] - rows_ptr[s], lx_ptr[s]
    m = nrd - p1
    rr = rows[rd0 + p1:rd0 + nrd]
    for i in range(m):
        wi[i] = local[rr[i]]
    contiguous = wi[m - 1] - wi[0] == m - 1
    x0 = wf[2 * m:2 * m + ncd]
    x1 = wf[2 * m + ncd:2 * m + 2 * ncd]
    j = 0
    while j < p2 - p1:
        two = j + 1 < p2 - p1 and not contiguous
        for k in range(ncd):
            x0[k] = lx[bd + k * nrd + p1 + j] * d[fd + k]
            if two:
                x1[k] = lx[bd + k * nrd + p1 + j + 1] * d[fd + k]
        tgt = bs + (rr[j] - f) * nrs
        if contiguous:
            _gemv_sub(lx[tgt + wi[j]:tgt + wi[j] + m - j], lx, bd + p1 + j, nrd, ncd, x0, m - j)
            j += 1
            continue
        t0 = wf[:m - j]
        t0[:] = 0.0
        col = lx[tgt:tgt + nrs]
        wj = wi[j:m]
        if two:
            t1 = wf[m:2 * m - j]
            t1[:] = 0.0
            _gemv2_sub(t0, t1, lx, bd + p1 + j, nrd, ncd, x0, x1, m - j)
            col1 = lx[bs + (rr[j + 1] - f) * nrs:bs + (rr[j + 1] - f + 1) * nrs]
            for i in range(1, m - j):
                col1[wj[i]] += t1[i]
        else:
            _gemv_sub(t0, lx, bd + p1 + j, nrd, ncd, x0, m - j)
        for i in range(m - j):
            col[wj[i]] += t0[i]
        j += 2 if two else 1


@njit(cache=True, nogil=True, fastmath=FM)
def _dense_ldlt(lx, d, bs, nr, nc, f, x):
    """LDL^T of a supernode's nr x nc column-major block at lx[bs:] in place, left-looking by column: the
    diagonal block's unit L, the rows below solved, the pivots in d[f:f+nc]. 0, or the failed pivot + 1."""
    for j in range(nc):
        col = bs + j * nr
        for k in range(j):
            x[k] = lx[bs + k * nr + j] * d[f + k]
        _gemv_sub(lx[col + j:col + nr], lx, bs + j, nr, j, x, nr - j)
        djj = lx[col + j]
        if not djj > 0.0:
            return f + j + 1
        d[f + j] = djj
        lx[col + j] = 1.0
        c = lx[col + j + 1:col + nr]
        inv = 1.0 / djj
        for i in range(nr - j - 1):
            c[i] *= inv
    return 0


@njit(cache=True, nogil=True)
def _check_factor(pattern, a_values, l_values, d, work):
    info = pattern[8]
    if a_values.shape[0] < info[1] or l_values.shape[0] < info[2] or d.shape[0] < info[0]:
        raise ValueError("ldlt_factor: a_values, l_values or d shorter than the pattern's nnz_a, l_size, n")
    lmap, head, nxt, lpos, wi, wf = work
    if (lmap.shape[0] < info[0] or head.shape[0] < info[3] or nxt.shape[0] < info[3] or lpos.shape[0] < info[3]
            or wi.shape[0] < info[4] or wf.shape[0] < info[5]):
        raise ValueError("ldlt_factor: a work array is too short (make it with make_workspace)")


@njit(cache=True, nogil=True)
def ldlt_factor(pattern, a_values, l_values, d, work):
    """Numeric LDL^T of the permuted A (no pivoting, no allocation).

    ``pattern``: :attr:`LDLTPattern.arrays`. ``a_values`` (nnz_a,) float64: A's lower triangle in the pattern's
    CSC order (assembled through ``slot``). Writes ``l_values`` (l_size,) float64 (the supernodal blocks of the
    unit lower L) and ``d`` (n,) float64 (D's diagonal), both in the permuted order. ``work``:
    :func:`make_workspace`. Returns 0 on success, or k+1 when the k-th pivot (of the permuted matrix: dof
    ``perm[k]``) is not positive; the factor is then incomplete (shift the diagonal and refactor).
    """
    _check_factor(pattern, a_values, l_values, d, work)
    perm, a_colptr, amap, super_ptr, col2super, rows_ptr, rows, lx_ptr, info = pattern
    local, head, nxt, lpos, wi, wf = work
    head[:] = -1
    for s in range(super_ptr.shape[0] - 1):
        f, l1 = super_ptr[s], super_ptr[s + 1]
        r0, nr, bs = rows_ptr[s], rows_ptr[s + 1] - rows_ptr[s], lx_ptr[s]
        for r in range(nr):
            local[rows[r0 + r]] = r
        l_values[bs:bs + nr * (l1 - f)] = 0.0
        for p in range(a_colptr[f], a_colptr[l1]):
            l_values[amap[p]] = a_values[p]
        dd = head[s]
        while dd != -1:  # every supernode with a row in s's columns, linked here by its previous target
            dnext = nxt[dd]
            rd0, nrd = rows_ptr[dd], rows_ptr[dd + 1] - rows_ptr[dd]
            p1 = lpos[dd]
            p2 = p1
            while p2 < nrd and rows[rd0 + p2] < l1:
                p2 += 1
            _update(l_values, d, super_ptr, rows_ptr, rows, lx_ptr, dd, s, p1, p2, local, wi, wf)
            lpos[dd] = p2
            if p2 < nrd:
                nxt[dd] = head[col2super[rows[rd0 + p2]]]
                head[col2super[rows[rd0 + p2]]] = dd
            dd = dnext
        status = _dense_ldlt(l_values, d, bs, nr, l1 - f, f, wf)
        if status:
            return status
        lpos[s] = l1 - f
        if l1 - f < nr:
            nxt[s] = head[col2super[rows[r0 + l1 - f]]]
            head[col2super[rows[r0 + l1 - f]]] = s
    return 0


@njit(cache=True, nogil=True, fastmath=FM)
def ldlt_solve(pattern, l_values, d, b, out, work):
    """out = A^-1 b from :func:`ldlt_factor`'s ``l_values`` and ``d``: b, out (n,) float64 in the caller's order
    (they may not alias); ``work`` (n + max_rows,) float64 (:func:`solve_workspace`). y = P b, L z = y,
    w = D^-1 z, L^T x = w, out = P^T x."""
    perm, a_colptr, amap, super_ptr, col2super, rows_ptr, rows, lx_ptr, info = pattern
    n = info[0]
    if b.shape[0] < n or out.shape[0] < n or work.shape[0] < n + info[4]:
        raise ValueError("ldlt_solve: b, out or work shorter than n, n, n + max_rows")
    y = work[:n]
    t = work[n:]
    for k in range(n):
        y[k] = b[perm[k]]
    for s in range(super_ptr.shape[0] - 1):
        f, nc = super_ptr[s], super_ptr[s + 1] - super_ptr[s]
        r0, nr, bs = rows_ptr[s], rows_ptr[s + 1] - rows_ptr[s], lx_ptr[s]
        for j in range(nc - 1):
            c = l_values[bs + j * nr + j + 1:bs + j * nr + nc]
            ys = y[f + j + 1:f + nc]
            yj = y[f + j]
            for i in range(nc - j - 1):
                ys[i] -= c[i] * yj
        if nr > nc:
            tt = t[:nr - nc]
            tt[:] = 0.0
            _gemv_sub(tt, l_values, bs + nc, nr, nc, y[f:f + nc], nr - nc)
            rr = rows[r0 + nc:r0 + nr]
            for i in range(nr - nc):
                y[rr[i]] += tt[i]
    for k in range(n):
        y[k] /= d[k]
    for s in range(super_ptr.shape[0] - 2, -1, -1):
        f, nc = super_ptr[s], super_ptr[s + 1] - super_ptr[s]
        r0, nr, bs = rows_ptr[s], rows_ptr[s + 1] - rows_ptr[s], lx_ptr[s]
        tt = t[:nr - nc]
        rr = rows[r0 + nc:r0 + nr]
        for i in range(nr - nc):
            tt[i] = y[rr[i]]
        for k in range(nc):
            c = l_values[bs + k * nr + nc:bs + (k + 1) * nr]
            acc = 0.0
            for i in range(nr - nc):
                acc += c[i] * tt[i]
            y[f + k] -= acc
        for j in range(nc - 2, -1, -1):
            c = l_values[bs + j * nr + j + 1:bs + j * nr + nc]
            ys = y[f + j + 1:f + nc]
            acc = 0.0
            for i in range(nc - j - 1):
                acc += c[i] * ys[i]
            y[f + j] -= acc
    for k in range(n):
        out[perm[k]] = y[k]


@njit(cache=True, nogil=True)
def ldlt_assemble(slot, values, a_values):
    """a_values[:] = 0, then a_values[slot[k]] += values[k]: slot (K,) int64 (:attr:`LDLTPattern.slot`),
    values (K,) float64 in the caller's entry order, a_values (nnz_a,) float64."""
    a_values[:] = 0.0
    for k in range(slot.shape[0]):
        a_values[slot[k]] += values[k]


# ----------------------------------------------------------------------------- the Python side


class LDLTPattern:
    """Symbolic analysis of a symmetric n x n pattern, made once.

    ``rows``, ``cols`` (K,) int: the entries the caller assembles, in any order, duplicates allowed. An entry
    (i, j) and an entry (j, i) are the same entry of the symmetric matrix: A_ij = A_ji is the sum of the values
    given at (i, j) and at (j, i), so give each off-diagonal value once, in either triangle (a caller with full
    symmetric element blocks keeps ``rows >= cols``). The diagonal is always in the pattern.
    ``last`` (m,) int: dofs to order last (a rigid tool's pose; the postorder keeps them last when they couple
    to the rest); default: the dense rows (:func:`dense_nodes`). ``order`` (n,) int: a fill-reducing order to
    use instead of :func:`fill_order` (order[k] = the dof eliminated k-th), which is then postordered.
    ``relax``: as :data:`RELAX`.

    Attributes: ``n``; ``slot`` (K,) int64, where each input entry lands in ``a_values`` (assembly is
    ``a_values[slot[k]] += v_k``, :func:`ldlt_assemble`); ``perm`` (n,) int64, perm[k] = the dof eliminated
    k-th; ``a_colptr`` (n+1,), ``a_rowind`` (nnz_a,) int64: the permuted lower-triangle CSC of A, rows sorted
    (the diagonal first in each column); ``nnz_a``; ``nnz_l``, L's entries with its diagonal (the fill);
    ``l_size``, the length of ``l_values`` (the supernodal blocks: also the blocks' upper triangles and the
    relaxed supernodes' zeros); ``nsuper``; ``max_rows``, ``max_cols`` of a supernode; ``fmas``, the
    factorisation's multiply-adds (sum over columns of c (c - 1) / 2, c = the column's entries).

    ``arrays``, the bundle both kernels take, all int64 and 1-d: (perm (n,), a_colptr (n+1,), amap (nnz_a,):
    the place in l_values of each entry of a_values, super_ptr (nsuper+1,): each supernode's first column,
    col2super (n,), rows_ptr (nsuper+1,), rows (rows_ptr[-1],): each supernode's rows, its columns first then
    the rows below, sorted, lx_ptr (nsuper+1,): where each supernode's nr x nc column-major block starts in
    l_values, info (6,): (n, nnz_a, l_size, nsuper, max_rows, the factor's float work length)).
    """

    def __init__(self, n: int, rows: np.ndarray, cols: np.ndarray, last: np.ndarray | None = None,
                 order: np.ndarray | None = None, relax: tuple = RELAX) -> None:
        rows = np.asarray(rows).astype(np.int64).reshape(-1)
        cols = np.asarray(cols).astype(np.int64).reshape(-1)
        n = int(n)
        if n < 1 or rows.shape != cols.shape:
            raise InputError(f"LDLTPattern: n = {n}, rows {rows.shape}, cols {cols.shape}: expected n >= 1 and "
                             "rows and cols of one length")
        if rows.size and (min(rows.min(), cols.min()) < 0 or max(rows.max(), cols.max()) >= n):
            raise InputError(f"LDLTPattern: an entry outside the {n} x {n} matrix")
        if last is not None and np.size(last) and (np.min(last) < 0 or np.max(last) >= n):
            raise InputError(f"LDLTPattern: a dof of last outside 0..{n - 1}")
        perm = fill_order(n, rows, cols, last) if order is None else np.asarray(order).astype(np.int64)
        if perm.shape != (n,) or not np.array_equal(np.sort(perm), np.arange(n)):
            raise InputError(f"LDLTPattern: order must be a permutation of 0..{n - 1}")
        iperm = np.empty(n, np.int64)
        iperm[perm] = np.arange(n)
        colptr, rowind, _ = _lower_csc(n, iperm[rows], iperm[cols])
        rowptr, colind = _rows_of(n, colptr, rowind)
        perm = perm[_postorder(_etree(n, rowptr, colind))]  # the same fill; subtrees, supernodes contiguous
        iperm[perm] = np.arange(n)
        colptr, rowind, self.slot = _lower_csc(n, iperm[rows], iperm[cols])
        rowptr, colind = _rows_of(n, colptr, rowind)
        parent = _etree(n, rowptr, colind)
        count = _colcounts(n, rowptr, colind, parent)
        super_ptr = _relax(parent, count, _fundamental(parent, count), np.array(relax, np.float64))
        rows_ptr, srows, col2super = _super_rows(n, colptr, rowind, parent, super_ptr)
        ncol, nrow = np.diff(super_ptr), np.diff(rows_ptr)
        lx_ptr = np.concatenate([[0], np.cumsum(ncol * nrow)]).astype(np.int64)
        amap = _a_to_l(n, colptr, rowind, super_ptr, rows_ptr, srows, lx_ptr)
        self.n, self.perm, self.a_colptr, self.a_rowind = n, perm, colptr, rowind
        self.nnz_a, self.nnz_l, self.l_size = int(rowind.shape[0]), int(count.sum()), int(lx_ptr[-1])
        self.nsuper, self.max_rows, self.max_cols = int(ncol.shape[0]), int(nrow.max()), int(ncol.max())
        self.fmas = int((count * (count - 1) // 2).sum())
        info = np.array([n, self.nnz_a, self.l_size, self.nsuper, self.max_rows,
                         2 * (self.max_rows + self.max_cols)], np.int64)
        self.arrays = (perm, colptr, amap, super_ptr, col2super, rows_ptr, srows, lx_ptr, info)

    def lower(self, a_values: np.ndarray) -> sp.csc_matrix:
        """The permuted A's lower triangle from ``a_values`` (nnz_a,): an n x n CSC."""
        return sp.csc_matrix((a_values, self.a_rowind, self.a_colptr), shape=(self.n, self.n))


def make_workspace(pattern: LDLTPattern) -> tuple:
    """The factor's work bundle: (local (n,) int64: a row's place in the current supernode, head, nxt, lpos
    (nsuper,) int64: the lists of supernodes waiting to update a supernode and where each is in its rows,
    wi (max_rows,) int64, wf (2 max_rows + 2 max_cols,) float64: scratch)."""
    info = pattern.arrays[-1]
    return (np.empty(info[0], np.int64), np.empty(info[3], np.int64), np.empty(info[3], np.int64),
            np.empty(info[3], np.int64), np.empty(info[4], np.int64), np.empty(info[5], np.float64))


def solve_workspace(pattern: LDLTPattern) -> np.ndarray:
    """The solve's work array: (n + max_rows,) float64."""
    return np.empty(pattern.n + pattern.max_rows, np.float64)


class LDLTFactor:
    """A factor of one pattern that allocates what the kernels need, for callers outside numba.

    ``factor(values, shift)`` assembles ``values`` (K,) (in the pattern's entry order) plus ``shift`` on the
    diagonal and factors: 0, or k+1 when the k-th pivot is not positive (then :meth:`solve` refuses until a
    factor succeeds). ``solve(b)``: A^-1 b for b (n,), a new (n,) array.
    """

    def __init__(self, pattern: LDLTPattern) -> None:
        self.pattern = pattern
        self.a_values = np.zeros(pattern.nnz_a)
        self.l_values = np.zeros(pattern.l_size)
        self.d = np.zeros(pattern.n)
        self.work = make_workspace(pattern)
        self.solve_work = solve_workspace(pattern)
        self.status = -1

    def factor(self, values: np.ndarray, shift: float = 0.0) -> int:
        values = np.ascontiguousarray(values, dtype=np.float64).reshape(-1)
        if values.shape != self.pattern.slot.shape:
            raise InputError(f"LDLTFactor.factor: values {values.shape}: expected {self.pattern.slot.shape}")
        ldlt_assemble(self.pattern.slot, values, self.a_values)
        if shift:
            self.a_values[self.pattern.a_colptr[:-1]] += shift
        self.status = int(ldlt_factor(self.pattern.arrays, self.a_values, self.l_values, self.d, self.work))
        return self.status

    def solve(self, b: np.ndarray) -> np.ndarray:
        if self.status != 0:
            raise InputError("LDLTFactor.solve: no successful factor" + (f" (pivot {self.status - 1} was not "
                                                                           "positive)" if self.status > 0 else ""))
        b = np.ascontiguousarray(b, dtype=np.float64)
        if b.shape != (self.pattern.n,):
            raise InputError(f"LDLTFactor.solve: b {b.shape}: expected ({self.pattern.n},)")
        out = np.empty(self.pattern.n)
        ldlt_solve(self.pattern.arrays, self.l_values, self.d, b, out, self.solve_work)
        return out
