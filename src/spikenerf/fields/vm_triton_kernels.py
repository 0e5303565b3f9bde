"""The Triton kernels of ``fields/vm_triton.py`` (imported by it on first use: this module needs ``triton``).

Layout as the fused CPU kernel's: planes (3, R, R, C) and lines (3, R, C) channels-last, points (M, 3) in
[−1, 1], ``align_corners=True``, zeros outside the grid; plane k reads (coord[MAT[k][0]] ↔ w,
coord[MAT[k][1]] ↔ h), line k coord[VEC[k]], with ``MAT = ((0, 1), (0, 2), (1, 2))`` and
``VEC = (2, 1, 0)`` (``fields/vm_gather.py``). Offsets are int64 (eval batches pass 2³¹ channel values).
The channel count is a compile-time constant: as a runtime int that is not a multiple of 16 (24, the
appearance rank) Triton cannot prove the rows aligned, and the backward spilled registers (3248 B of
stack a thread for sm_90, ``benchmarks/tools/triton_compile_report.py``) instead of using vector loads and
atomics; one compile per channel count.
"""

import triton
import triton.language as tl


@triton.jit
def corner(coord, size):
    # the texels either side of coord in [-1, 1] over `size` texels (align_corners=True): both indices
    # clamped into the grid, and their weights, 0 for a texel outside it, NaN for a NaN/inf coordinate
    u = (coord + 1.0) * 0.5 * (size - 1)
    finite = (u == u) & (tl.abs(u) < float("inf"))
    u = tl.minimum(tl.maximum(tl.where(finite, u, 0.0), -2.0), size + 1.0)
    low = tl.floor(u)
    frac = u - low
    lo = low.to(tl.int64)
    hi = lo + 1
    w_lo = tl.where((lo >= 0) & (lo < size), 1.0 - frac, 0.0)
    w_hi = tl.where((hi >= 0) & (hi < size), frac, 0.0)
    w_lo = tl.where(finite, w_lo, float("nan"))
    w_hi = tl.where(finite, w_hi, float("nan"))
    lo = tl.minimum(tl.maximum(lo, 0), size - 1)
    hi = tl.minimum(tl.maximum(hi, 0), size - 1)
    return lo, hi, w_lo, w_hi


@triton.jit
def slopes(coord, size):
    # the slopes along coord of corner()'s two weights: ∓(size − 1)/2 for a texel inside the grid, 0 for
    # one outside, NaN for a NaN/inf coordinate (grid_sample's gradient for its grid, zeros padding)
    u = (coord + 1.0) * 0.5 * (size - 1)
    finite = (u == u) & (tl.abs(u) < float("inf"))
    low = tl.floor(tl.minimum(tl.maximum(tl.where(finite, u, 0.0), -2.0), size + 1.0)).to(tl.int64)
    s = 0.5 * (size - 1)
    d_lo = tl.where((low >= 0) & (low < size), -s, 0.0)
    d_hi = tl.where((low + 1 >= 0) & (low + 1 < size), s, 0.0)
    return tl.where(finite, d_lo, float("nan")), tl.where(finite, d_hi, float("nan"))


@triton.jit
def texels(k, c0, c1, r0, r1, l0, l1, size, channels):
    # plane k's four texel offsets (rows r0, r1; columns c0, c1) and line k's two (l0, l1)
    base = k * size
    o00 = ((base + r0) * size + c0) * channels
    o01 = ((base + r0) * size + c1) * channels
    o10 = ((base + r1) * size + c0) * channels
    o11 = ((base + r1) * size + c1) * channels
    return o00, o01, o10, o11, (base + l0) * channels, (base + l1) * channels


@triton.jit
def pair(k, u, v, z, size, channels):
    # plane k's four texel offsets and weights at (u ↔ w, v ↔ h), line k's two at z (per point)
    c0, c1, wc0, wc1 = corner(u, size)
    r0, r1, wr0, wr1 = corner(v, size)
    l0, l1, wl0, wl1 = corner(z, size)
    o00, o01, o10, o11, q0, q1 = texels(k, c0, c1, r0, r1, l0, l1, size, channels)
    return o00, o01, o10, o11, wr0 * wc0, wr0 * wc1, wr1 * wc0, wr1 * wc1, q0, q1, wl0, wl1


@triton.jit
def axes(X, n, live, k: tl.constexpr):
    # the (w, h, line) coordinates of axis pair k: MAT[k] = (k // 2, k + 1 - k // 2), VEC[k] = 2 - k
    a: tl.constexpr = k // 2
    b: tl.constexpr = k + 1 - k // 2
    c: tl.constexpr = 2 - k
    u = tl.load(X + n * 3 + a, mask=live, other=0.0)
    v = tl.load(X + n * 3 + b, mask=live, other=0.0)
    z = tl.load(X + n * 3 + c, mask=live, other=0.0)
    return u, v, z


@triton.jit
def values(P, L, o00, o01, o10, o11, w00, w01, w10, w11, q0, q1, wl0, wl1, ch, mask):
    # the bilinear plane rows and linear line rows (BLOCK, CP) of one axis pair
    pv = w00[:, None] * tl.load(P + o00[:, None] + ch[None, :], mask=mask, other=0.0)
    pv += w01[:, None] * tl.load(P + o01[:, None] + ch[None, :], mask=mask, other=0.0)
    pv += w10[:, None] * tl.load(P + o10[:, None] + ch[None, :], mask=mask, other=0.0)
    pv += w11[:, None] * tl.load(P + o11[:, None] + ch[None, :], mask=mask, other=0.0)
    lv = wl0[:, None] * tl.load(L + q0[:, None] + ch[None, :], mask=mask, other=0.0)
    lv += wl1[:, None] * tl.load(L + q1[:, None] + ch[None, :], mask=mask, other=0.0)
    return pv, lv


@triton.jit
def forward_kernel(P, L, X, OUT, M, size, channels: tl.constexpr, SUMMED: tl.constexpr,
                   BLOCK: tl.constexpr, CP: tl.constexpr):  # fmt: skip
    n = tl.program_id(0).to(tl.int64) * BLOCK + tl.arange(0, BLOCK)
    live = n < M
    ch = tl.arange(0, CP)
    mask = live[:, None] & (ch < channels)[None, :]
    total = tl.zeros([BLOCK], dtype=tl.float32)
    for k in tl.static_range(3):
        u, v, z = axes(X, n, live, k)
        o00, o01, o10, o11, w00, w01, w10, w11, q0, q1, wl0, wl1 = pair(k, u, v, z, size, channels)
        pv, lv = values(P, L, o00, o01, o10, o11, w00, w01, w10, w11, q0, q1, wl0, wl1, ch, mask)
        if SUMMED:
            total += tl.sum(pv * lv, axis=1)
        else:
            tl.store(OUT + (n * 3 + k)[:, None] * channels + ch[None, :], pv * lv, mask=mask)
    if SUMMED:
        tl.store(OUT + n, total, mask=live)


@triton.jit
def gradient_block(G, M, SUMMED: tl.constexpr, BLOCK: tl.constexpr, CP: tl.constexpr):
    # a backward program's points n (BLOCK,), which of them exist (live), the channels (CP,) and, when
    # SUMMED, each point's one gradient (BLOCK,) (zeros otherwise)
    n = tl.program_id(0).to(tl.int64) * BLOCK + tl.arange(0, BLOCK)
    live = n < M
    g_point = tl.zeros([BLOCK], dtype=tl.float32)
    if SUMMED:
        g_point = tl.load(G + n, mask=live, other=0.0)
    return n, live, tl.arange(0, CP), g_point


@triton.jit
def gradient_rows(G, g_point, n, k, ch, mask, channels: tl.constexpr, SUMMED: tl.constexpr,
                  BLOCK: tl.constexpr, CP: tl.constexpr):  # fmt: skip
    # axis pair k's gradient rows (BLOCK, CP): the point's one gradient in every channel when SUMMED
    g = g_point[:, None] + tl.zeros([BLOCK, CP], dtype=tl.float32)
    if not SUMMED:
        g = tl.load(G + (n * 3 + k)[:, None] * channels + ch[None, :], mask=mask, other=0.0)
    return g


@triton.jit
def backward_kernel(P, L, X, G, GP, GL, M, size, channels: tl.constexpr, SUMMED: tl.constexpr,
                    BLOCK: tl.constexpr, CP: tl.constexpr):  # fmt: skip
    n, live, ch, g_point = gradient_block(G, M, SUMMED, BLOCK, CP)
    if SUMMED:
        live = live & (g_point != 0.0)  # e.g. behind a ray's early stop: nothing to add
    mask = live[:, None] & (ch < channels)[None, :]
    for k in tl.static_range(3):
        u, v, z = axes(X, n, live, k)
        o00, o01, o10, o11, w00, w01, w10, w11, q0, q1, wl0, wl1 = pair(k, u, v, z, size, channels)
        pv, lv = values(P, L, o00, o01, o10, o11, w00, w01, w10, w11, q0, q1, wl0, wl1, ch, mask)
        g = gradient_rows(G, g_point, n, k, ch, mask, channels, SUMMED, BLOCK, CP)
        gp, gl = g * lv, g * pv
        cols = ch[None, :]
        tl.atomic_add(GP + o00[:, None] + cols, w00[:, None] * gp, mask=mask, sem="relaxed")
        tl.atomic_add(GP + o01[:, None] + cols, w01[:, None] * gp, mask=mask, sem="relaxed")
        tl.atomic_add(GP + o10[:, None] + cols, w10[:, None] * gp, mask=mask, sem="relaxed")
        tl.atomic_add(GP + o11[:, None] + cols, w11[:, None] * gp, mask=mask, sem="relaxed")
        tl.atomic_add(GL + q0[:, None] + cols, wl0[:, None] * gl, mask=mask, sem="relaxed")
        tl.atomic_add(GL + q1[:, None] + cols, wl1[:, None] * gl, mask=mask, sem="relaxed")


@triton.jit
def point_kernel(P, L, X, G, GX, M, size, channels: tl.constexpr, SUMMED: tl.constexpr,
                 BLOCK: tl.constexpr, CP: tl.constexpr):  # fmt: skip
    # the points' gradient (M, 3) of Σ G·P_k(x)·L_k(x): per axis pair, the plane's bilinear slope along its
    # two coordinates times the line's value, and the line's slope times the plane's value (no atomics:
    # each point is its own)
    n, live, ch, g_point = gradient_block(G, M, SUMMED, BLOCK, CP)
    mask = live[:, None] & (ch < channels)[None, :]
    gx0 = tl.zeros([BLOCK], dtype=tl.float32)
    gx1 = tl.zeros([BLOCK], dtype=tl.float32)
    gx2 = tl.zeros([BLOCK], dtype=tl.float32)
    for k in tl.static_range(3):
        u, v, z = axes(X, n, live, k)
        c0, c1, wc0, wc1 = corner(u, size)
        r0, r1, wr0, wr1 = corner(v, size)
        l0, l1, wl0, wl1 = corner(z, size)
        dc0, dc1 = slopes(u, size)
        dr0, dr1 = slopes(v, size)
        dl0, dl1 = slopes(z, size)
        o00, o01, o10, o11, q0, q1 = texels(k, c0, c1, r0, r1, l0, l1, size, channels)
        g = gradient_rows(G, g_point, n, k, ch, mask, channels, SUMMED, BLOCK, CP)
        # one pair of texel rows at a time (fewer live tiles: no register spill at 24 channels)
        e0 = tl.load(L + q0[:, None] + ch[None, :], mask=mask, other=0.0)
        e1 = tl.load(L + q1[:, None] + ch[None, :], mask=mask, other=0.0)
        gl = g * (wl0[:, None] * e0 + wl1[:, None] * e1)  # gradient × line value
        g_dl = g * (dl0[:, None] * e0 + dl1[:, None] * e1)  # gradient × line slope
        p0 = tl.load(P + o00[:, None] + ch[None, :], mask=mask, other=0.0)
        p1 = tl.load(P + o01[:, None] + ch[None, :], mask=mask, other=0.0)
        top = wc0[:, None] * p0 + wc1[:, None] * p1
        d_top = dc0[:, None] * p0 + dc1[:, None] * p1
        p0 = tl.load(P + o10[:, None] + ch[None, :], mask=mask, other=0.0)
        p1 = tl.load(P + o11[:, None] + ch[None, :], mask=mask, other=0.0)
        bottom = wc0[:, None] * p0 + wc1[:, None] * p1
        d_bottom = dc0[:, None] * p0 + dc1[:, None] * p1
        du = tl.sum(gl * (wr0[:, None] * d_top + wr1[:, None] * d_bottom), axis=1)
        dv = tl.sum(gl * (dr0[:, None] * top + dr1[:, None] * bottom), axis=1)
        dz = tl.sum(g_dl * (wr0[:, None] * top + wr1[:, None] * bottom), axis=1)
        # axis pair k reads u = coord[k // 2], v = coord[k + 1 − k // 2], z = coord[2 − k] (axes())
        if k == 0:
            gx0 += du
            gx1 += dv
            gx2 += dz
        elif k == 1:
            gx0 += du
            gx2 += dv
            gx1 += dz
        else:
            gx1 += du
            gx2 += dv
            gx0 += dz
    tl.store(GX + n * 3, gx0, mask=live)
    tl.store(GX + n * 3 + 1, gx1, mask=live)
    tl.store(GX + n * 3 + 2, gx2, mask=live)
