"""A sparse symmetric LDL^T factorisation in numba, for matrices refactored many times on one sparsity pattern.

Prototype: symbolic analysis, supernodal left-looking numeric factor, solve.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla
from numba import njit

from ..errors import InputError

# ----------------------------------------------------------------------------- symbolic kernels (made once)


@njit(cache=True)
def _transpose(n, colptr, rowind):
    """The transpose of an n x n CSC pattern (colptr (n+1,), rowind (nnz,) int64): (rowptr, colind), rows sorted."""
    cnt = np.zeros(n + 1, np.int64)
    for p in range(rowind.shape[0]):
        cnt[rowind[p] + 1] += 1
    rowptr = np.cumsum(cnt)
    nxt = rowptr[:-1].copy()
    colind = np.empty(rowind.shape[0], np.int64)
    for j in range(n):
        for p in range(colptr[j], colptr[j + 1]):
            i = rowind[p]
            colind[nxt[i]] = j
            nxt[i] += 1
    return rowptr, colind


@njit(cache=True)
def _etree(n, rowptr, colind):
    """Elimination tree from the lower CSR (row k: columns j <= k): parent (n,) int64, -1 at a root."""
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
    """A postorder of the forest ``parent`` (n,): post (n,) int64, post[k] = the k-th node visited."""
    n = parent.shape[0]
    head = np.full(n, -1, np.int64)
    nxt = np.full(n, -1, np.int64)
    for j in range(n - 1, -1, -1):  # children lists in increasing order
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
            p = stack[top]
            c = head[p]
            if c == -1:
                top -= 1
                post[k] = p
                k += 1
            else:
                head[p] = nxt[c]
                top += 1
                stack[top] = c
    return post


@njit(cache=True)
def _colcounts(n, rowptr, colind, parent):
    """Rows in each column of L (diagonal included), by walking every row's subtree: count (n,) int64."""
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
def _supernodes(parent, count, nrelax, zrelax):
    """Relaxed supernodes of a postordered etree: super_ptr (nsuper+1,) int64, the first column of each."""
    n = parent.shape[0]
    nchild = np.zeros(n, np.int64)
    for j in range(n):
        if parent[j] != -1:
            nchild[parent[j]] += 1
    # fundamental supernodes
    fstart = np.empty(n + 1, np.int64)
    nf = 0
    for j in range(n):
        if j == 0 or not (parent[j - 1] == j and count[j - 1] == count[j] + 1 and nchild[j] == 1):
            fstart[nf] = j
            nf += 1
    fstart[nf] = n
    fsuper = np.empty(n, np.int64)
    for s in range(nf):
        fsuper[fstart[s]:fstart[s + 1]] = s
    # relaxed amalgamation (CHOLMOD's rule): merge s into the group that starts at s+1 when that group holds
    # s's parent and the merged block is small or has few explicit zeros
    ncol = np.empty(nf, np.int64)
    snz = np.empty(nf, np.int64)
    zeros = np.zeros(nf, np.float64)
    end = np.empty(nf, np.int64)
    leader = np.ones(nf, np.bool_)
    for s in range(nf):
        ncol[s] = fstart[s + 1] - fstart[s]
        snz[s] = count[fstart[s]]
        end[s] = s
    for s in range(nf - 2, -1, -1):
        last = fstart[s + 1] - 1
        if parent[last] == -1:
            continue
        q = fsuper[parent[last]]
        if q < s + 1 or q > end[s + 1]:
            continue
        g = s + 1
        ns = ncol[s] + ncol[g]
        newz = ncol[s] * (ncol[g] + snz[g] - snz[s])
        totz = zeros[s] + zeros[g] + newz
        if newz == 0:
            merge = True
        else:
            z = totz / (ns * (ns + 1) / 2 + ns * (snz[g] - ncol[g]))
            merge = (ns <= nrelax[0] or (ns <= nrelax[1] and z < zrelax[0])
                     or (ns <= nrelax[2] and z < zrelax[1]) or z < zrelax[2])
        if merge:
            snz[s] = ncol[s] + snz[g]
            ncol[s] = ns
            zeros[s] = totz
            end[s] = end[g]
            leader[g] = False
    nsuper = 0
    for s in range(nf):
        if leader[s]:
            nsuper += 1
    super_ptr = np.empty(nsuper + 1, np.int64)
    k = 0
    for s in range(nf):
        if leader[s]:
            super_ptr[k] = fstart[s]
            k += 1
    super_ptr[nsuper] = n
    return super_ptr


@njit(cache=True)
def _super_rows(n, colptr, rowind, parent, super_ptr):
    """Each supernode's rows (its own columns first, then the rows below, sorted): rows_ptr (nsuper+1,), rows."""
    nsuper = super_ptr.shape[0] - 1
    col2super = np.empty(n, np.int64)
    for s in range(nsuper):
        col2super[super_ptr[s]:super_ptr[s + 1]] = s
    head = np.full(nsuper, -1, np.int64)
    nxt = np.full(nsuper, -1, np.int64)
    for s in range(nsuper):
        last = super_ptr[s + 1] - 1
        if parent[last] != -1:
            q = col2super[parent[last]]
            nxt[s] = head[q]
            head[q] = s
    mark = np.full(n, -1, np.int64)
    cap = 4 * n + 16
    rows = np.empty(cap, np.int64)
    rows_ptr = np.zeros(nsuper + 1, np.int64)
    buf = np.empty(n, np.int64)
    top = 0
    for s in range(nsuper):
        f, l1 = super_ptr[s], super_ptr[s + 1]
        m = 0
        for j in range(f, l1):
            for p in range(colptr[j], colptr[j + 1]):
                i = rowind[p]
                if i >= l1 and mark[i] != s:
                    mark[i] = s
                    buf[m] = i
                    m += 1
        c = head[s]
        while c != -1:
            for p in range(rows_ptr[c], rows_ptr[c + 1]):
                i = rows[p]
                if i >= l1 and mark[i] != s:
                    mark[i] = s
                    buf[m] = i
                    m += 1
            c = nxt[c]
        below = np.sort(buf[:m])
        need = top + (l1 - f) + m
        if need > cap:
            cap = max(2 * cap, need)
            grown = np.empty(cap, np.int64)
            grown[:top] = rows[:top]
            rows = grown
        for j in range(f, l1):
            rows[top] = j
            top += 1
        rows[top:top + m] = below
        top += m
        rows_ptr[s + 1] = top
    return rows_ptr, rows[:top].copy(), col2super


@njit(cache=True)
def _a_to_l(n, colptr, rowind, super_ptr, rows_ptr, rows, lx_ptr):
    """Where each entry of A's lower CSC lands in L's supernodal values: amap (nnz_a,) int64."""
    amap = np.empty(rowind.shape[0], np.int64)
    lmap = np.empty(n, np.int64)
    for s in range(super_ptr.shape[0] - 1):
        f, l1 = super_ptr[s], super_ptr[s + 1]
        nr = rows_ptr[s + 1] - rows_ptr[s]
        for r in range(rows_ptr[s], rows_ptr[s + 1]):
            lmap[rows[r]] = r - rows_ptr[s]
        for j in range(f, l1):
            for p in range(colptr[j], colptr[j + 1]):
                amap[p] = lx_ptr[s] + (j - f) * nr + lmap[rowind[p]]
    return amap


# ----------------------------------------------------------------------------- numeric kernels


FM = {"reassoc", "contract"}


@njit(cache=True, nogil=True, fastmath=FM)
def _gemv_sub(y, lx, c0, ld, ncols, x, m):
    """y[:m] -= sum_k lx[c0 + k ld : + m] x[k], four columns at a time (one pass over y per four)."""
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
    while k < ncols:
        a0 = lx[c0 + k * ld:c0 + k * ld + m]
        x0 = x[k]
        for i in range(m):
            y[i] -= a0[i] * x0
        k += 1


@njit(cache=True, nogil=True, fastmath=FM)
def _update(lx, d, rows, rd0, bd, nrd, ncd, p1, p2, fd, bs, nrs, f, lmap, wf, wi):
    """Subtract descendant d's update L_d[p1:] D_d L_d[p1:p2]^T from the target supernode's block."""
    m = nrd - p1
    for i in range(m):
        wi[i] = lmap[rows[rd0 + p1 + i]]
    contiguous = wi[m - 1] - wi[0] == m - 1
    x = wf[m:m + ncd]
    for j in range(p2 - p1):
        cj = rows[rd0 + p1 + j] - f
        for k in range(ncd):
            x[k] = lx[bd + k * nrd + p1 + j] * d[fd + k]
        if contiguous:
            tgt = bs + cj * nrs + wi[j]
            _gemv_sub(lx[tgt:tgt + m - j], lx, bd + p1 + j, nrd, ncd, x, m - j)
        else:
            t = wf[:m - j]
            t[:] = 0.0
            _gemv_sub(t, lx, bd + p1 + j, nrd, ncd, x, m - j)
            col = lx[bs + cj * nrs:bs + (cj + 1) * nrs]
            for i in range(m - j):
                col[wi[j + i]] += t[i]


@njit(cache=True, nogil=True, fastmath=FM)
def _dense_ldlt(lx, d, bs, nr, nc, f, x):
    """LDL^T of a supernode's column-major block in place (left-looking); 0 or the failed pivot + 1."""
    for j in range(nc):
        col = bs + j * nr
        for k in range(j):
            x[k] = lx[bs + k * nr + j] * d[f + k]
        _gemv_sub(lx[col + j:col + nr], lx, bs + j, nr, j, x, nr - j)
        djj = lx[col + j]
        if not djj > 0.0:
            return f + j + 1
        d[f + j] = djj
        inv = 1.0 / djj
        lx[col + j] = 1.0
        c = lx[col + j + 1:col + nr]
        for i in range(nr - j - 1):
            c[i] *= inv
    return 0


@njit(cache=True, nogil=True)
def ldlt_factor(pattern, a_values, l_values, d, work):
    """Numeric LDL^T of the permuted A; 0 on success, k+1 when the k-th pivot is not positive."""
    perm, iperm, a_colptr, a_rowind, amap, super_ptr, col2super, rows_ptr, rows, lx_ptr, info = pattern
    lmap, head, nxt, lpos, wi, wf = work
    nsuper = super_ptr.shape[0] - 1
    head[:] = -1
    for s in range(nsuper):
        f, l1 = super_ptr[s], super_ptr[s + 1]
        nc = l1 - f
        r0 = rows_ptr[s]
        nr = rows_ptr[s + 1] - r0
        bs = lx_ptr[s]
        for r in range(nr):
            lmap[rows[r0 + r]] = r
        l_values[bs:bs + nr * nc] = 0.0
        for p in range(a_colptr[f], a_colptr[l1]):
            l_values[amap[p]] = a_values[p]
        dd = head[s]
        while dd != -1:
            dnext = nxt[dd]
            fd = super_ptr[dd]
            rd0 = rows_ptr[dd]
            nrd = rows_ptr[dd + 1] - rd0
            p1 = lpos[dd]
            p2 = p1
            while p2 < nrd and rows[rd0 + p2] < l1:
                p2 += 1
            _update(l_values, d, rows, rd0, lx_ptr[dd], nrd, super_ptr[dd + 1] - fd, p1, p2, fd, bs, nr, f,
                    lmap, wf, wi)
            lpos[dd] = p2
            if p2 < nrd:
                t = col2super[rows[rd0 + p2]]
                nxt[dd] = head[t]
                head[t] = dd
            dd = dnext
        status = _dense_ldlt(l_values, d, bs, nr, nc, f, wf)
        if status:
            return status
        lpos[s] = nc
        if nc < nr:
            t = col2super[rows[r0 + nc]]
            nxt[s] = head[t]
            head[t] = s
    return 0


@njit(cache=True, nogil=True, fastmath=FM)
def ldlt_solve(pattern, l_values, d, b, out, work):
    """out = A^-1 b from the factor (b, out (n,) float64, not aliased; work (2n,) float64)."""
    perm, iperm, a_colptr, a_rowind, amap, super_ptr, col2super, rows_ptr, rows, lx_ptr, info = pattern
    n = perm.shape[0]
    y = work[:n]
    t = work[n:]
    for k in range(n):
        y[k] = b[perm[k]]
    nsuper = super_ptr.shape[0] - 1
    for s in range(nsuper):
        f = super_ptr[s]
        nc = super_ptr[s + 1] - f
        r0 = rows_ptr[s]
        nr = rows_ptr[s + 1] - r0
        bs = lx_ptr[s]
        m = nr - nc
        for j in range(nc):
            yj = y[f + j]
            c = l_values[bs + j * nr + j + 1:bs + j * nr + nc]
            ys = y[f + j + 1:f + nc]
            for i in range(nc - j - 1):
                ys[i] -= c[i] * yj
        if m == 0:
            continue
        tt = t[:m]
        tt[:] = 0.0
        _gemv_sub(tt, l_values, bs + nc, nr, nc, y[f:f + nc], m)
        rr = rows[r0 + nc:r0 + nr]
        for i in range(m):
            y[rr[i]] += tt[i]
    for k in range(n):
        y[k] /= d[k]
    for s in range(nsuper - 1, -1, -1):
        f = super_ptr[s]
        nc = super_ptr[s + 1] - f
        r0 = rows_ptr[s]
        nr = rows_ptr[s + 1] - r0
        bs = lx_ptr[s]
        m = nr - nc
        tt = t[:m]
        rr = rows[r0 + nc:r0 + nr]
        for i in range(m):
            tt[i] = y[rr[i]]
        for k in range(nc):
            c = l_values[bs + k * nr + nc:bs + (k + 1) * nr]
            acc = 0.0
            for i in range(m):
                acc += c[i] * tt[i]
            y[f + k] -= acc
        for j in range(nc - 1, -1, -1):
            c = l_values[bs + j * nr + j + 1:bs + j * nr + nc]
            ys = y[f + j + 1:f + nc]
            acc = 0.0
            for i in range(nc - j - 1):
                acc += c[i] * ys[i]
            y[f + j] -= acc
    for k in range(n):
        out[perm[k]] = y[k]


# ----------------------------------------------------------------------------- orderings


def _graph(n, rows, cols):
    """The symmetric adjacency (no diagonal) of the entries: CSR indptr (n+1,), indices, both int64."""
    off = rows != cols
    r = np.concatenate([rows[off], cols[off]])
    c = np.concatenate([cols[off], rows[off]])
    g = sp.csr_matrix((np.ones(r.shape[0], np.int8), (r, c)), shape=(n, n))
    g.sum_duplicates()
    return g.indptr.astype(np.int64), g.indices.astype(np.int64)


def order_mmd(indptr, indices):
    """SuperLU's multiple minimum degree on the graph (CSR without diagonal): order (n,) int64."""
    n = indptr.shape[0] - 1
    deg = np.diff(indptr).astype(np.float64)
    a = sp.csc_matrix((np.full(indices.shape[0], -1.0), indices, indptr), shape=(n, n)) + sp.diags(deg + 1.0)
    lu = sla.splu(sp.csc_matrix(a), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                  options={"SymmetricMode": True})
    return np.argsort(lu.perm_c).astype(np.int64)


def fill_order(n, rows, cols, method="mmd"):
    g_ptr, g_ind = _graph(n, rows, cols)
    return order_mmd(g_ptr, g_ind)


def _lower_csc(n, r, c):
    lo = np.maximum(r, c)
    hi = np.minimum(r, c)
    keys = np.concatenate([hi * n + lo, np.arange(n, dtype=np.int64) * (n + 1)])
    uniq, inv = np.unique(keys, return_inverse=True)
    col = uniq // n
    row = uniq - col * n
    colptr = np.searchsorted(col, np.arange(n + 1)).astype(np.int64)
    return colptr, row.astype(np.int64), inv[: r.shape[0]].astype(np.int64)


class LDLTPattern:
    """Symbolic analysis of a symmetric n x n pattern, made once."""

    def __init__(self, n, rows, cols, order=None, nrelax=(4, 16, 48), zrelax=(0.8, 0.1, 0.05)):
        rows = np.asarray(rows, dtype=np.int64)
        cols = np.asarray(cols, dtype=np.int64)
        if rows.shape != cols.shape or rows.ndim != 1:
            raise InputError("rows and cols must be 1-d arrays of one length")
        if rows.size and (min(rows.min(), cols.min()) < 0 or max(rows.max(), cols.max()) >= n):
            raise InputError(f"entries outside the {n} x {n} matrix")
        self.n = n
        perm = fill_order(n, rows, cols) if order is None else np.asarray(order, np.int64)
        iperm = np.empty(n, np.int64)
        iperm[perm] = np.arange(n)
        colptr, rowind, _ = _lower_csc(n, iperm[rows], iperm[cols])
        rowptr, colind = _transpose(n, colptr, rowind)
        post = _postorder(_etree(n, rowptr, colind))
        perm = perm[post]
        iperm[perm] = np.arange(n)
        colptr, rowind, slot = _lower_csc(n, iperm[rows], iperm[cols])
        rowptr, colind = _transpose(n, colptr, rowind)
        parent = _etree(n, rowptr, colind)
        count = _colcounts(n, rowptr, colind, parent)
        super_ptr = _supernodes(parent, count, np.array(nrelax, np.int64), np.array(zrelax, np.float64))
        rows_ptr, srows, col2super = _super_rows(n, colptr, rowind, parent, super_ptr)
        ncol = np.diff(super_ptr)
        nrow = np.diff(rows_ptr)
        lx_ptr = np.concatenate([[0], np.cumsum(ncol * nrow)]).astype(np.int64)
        amap = _a_to_l(n, colptr, rowind, super_ptr, rows_ptr, srows, lx_ptr)
        self.slot = slot
        self.nnz_a = int(rowind.shape[0])
        self.nnz_l = int(count.sum())
        self.l_size = int(lx_ptr[-1])
        self.flops = float((count.astype(np.float64) ** 2).sum())
        self.nsuper = int(super_ptr.shape[0] - 1)
        self.max_rows = int(nrow.max()) if n else 0
        self.max_cols = int(ncol.max()) if n else 0
        info = np.array([n, self.nnz_a, self.l_size, self.nsuper], np.int64)
        self.arrays = (perm, iperm, colptr, rowind, amap, super_ptr, col2super, rows_ptr, srows, lx_ptr, info)


def make_workspace(pattern):
    n = pattern.n
    ns = pattern.nsuper
    return (np.empty(n, np.int64), np.empty(ns, np.int64), np.empty(ns, np.int64), np.empty(ns, np.int64),
            np.empty(pattern.max_rows, np.int64), np.empty(max(pattern.max_rows * pattern.max_cols, n), np.float64))


class LDLTFactor:
    def __init__(self, pattern):
        self.pattern = pattern
        self.l_values = np.empty(pattern.l_size)
        self.d = np.empty(pattern.n)
        self.work = make_workspace(pattern)
        self.a_values = np.empty(pattern.nnz_a)
        self._solve_work = np.empty(2 * pattern.n)

    def factor(self, values):
        self.a_values[:] = np.bincount(self.pattern.slot, weights=values, minlength=self.pattern.nnz_a)
        return ldlt_factor(self.pattern.arrays, self.a_values, self.l_values, self.d, self.work)

    def solve(self, b):
        out = np.empty(self.pattern.n)
        ldlt_solve(self.pattern.arrays, self.l_values, self.d, np.ascontiguousarray(b, np.float64), out,
                   self._solve_work)
        return out
