// The fused CPU kernel of the VM lookup (fields/vm_kernel.py): forward P_m(x)·L_m(x) per axis pair and channel
// (float32, the bf16 decoder's padded rows, or summed: the density), backward the scatter into channels-last
// gradients (each thread owns a band of plane rows: the same bits on any number of threads) and the points'
// gradient (pose refinement), the density's lookup up to each ray's early stop, and the packed march
// (render/march_cpu.py). Compiled on first use by fields/vm_build.py, whose build folder's name hashes this
// file's text: any change to it builds anew.

#include <torch/extension.h>
#include <ATen/Parallel.h>
#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>

// planes (3, R, R, C), lines (3, R, C) channels last; xyz (M, 3) in [-1, 1]; align_corners=True.
// plane m: col = coord[MAT[m][0]], row = coord[MAT[m][1]]; line m: coord[VEC[m]].
static const int MAT0[3] = {0, 0, 1}, MAT1[3] = {1, 2, 2}, VEC[3] = {2, 1, 0};

// zeros padding as grid_sample: texel i gets weight a, texel i + 1 weight b (0 for a texel outside [0, r-1]);
// a NaN/inf coordinate gives NaN weights (grid_sample's NaN) on an in-range index, never a wild read.
static inline void cell(float x, int r, int &i, float &a, float &b) {
  const float u = (x + 1.f) * 0.5f * (r - 1);
  i = 0;
  if (!std::isfinite(u)) { a = b = std::numeric_limits<float>::quiet_NaN(); return; }
  const float fl = std::floor(u), f = u - fl;
  if (fl < -1.f || fl > (float)(r - 1)) { a = b = 0.f; return; }  // both texels outside
  if (fl == -1.f) { a = f; b = 0.f; return; }                       // only texel 0, at index 0
  if (fl == (float)(r - 1)) { i = r - 2; a = 0.f; b = 1.f - f; return; }  // only texel r-1, at index r-2
  i = (int)fl; a = 1.f - f; b = f;
}

// the cells of a point's three coordinates: each is a plane column, a plane row and a line coordinate of
// the three axis pairs, so cell() runs 3 times a point, not 9 (the same values)
struct Cells { int i[3]; float a[3], b[3]; };
static inline void point_cells(const float *x, int r, Cells &q) {
  for (int d = 0; d < 3; ++d) cell(x[d], r, q.i[d], q.a[d], q.b[d]);
}
// axis pair k's plane column ic (weights ac, bc), plane row ir (ar, br) and line texel il (al, bl) from cells q
#define PAIR_CELLS(q, k)                                                                                  \
  const int ic = q.i[MAT0[k]], ir = q.i[MAT1[k]], il = q.i[VEC[k]];                                      \
  const float ac = q.a[MAT0[k]], bc = q.b[MAT0[k]], ar = q.a[MAT1[k]], br = q.b[MAT1[k]], al = q.a[VEC[k]], \
              bl = q.b[VEC[k]]

// software prefetch of the texels point x will read (the lookups are random; the OoO window is too short)
static const int64_t PF = 8;  // points ahead
static inline void prefetch_point(const float *P, const float *L, const float *x, int64_t r, int64_t c,
                                  int64_t lo, int64_t hi) {
  Cells q; point_cells(x, r, q);
  for (int k = 0; k < 3; ++k) {
    const int ic = q.i[MAT0[k]], ir = q.i[MAT1[k]], il = q.i[VEC[k]];
    if (ir + 1 < lo || ir >= hi) continue;  // rows [lo, hi) only (the backward's band of a thread)
    const char *p0 = (const char *)(P + ((k * r + ir) * r + ic) * c), *p1 = p0 + r * c * sizeof(float);
    for (int64_t o = 0; o < 2 * c * (int64_t)sizeof(float); o += 64) { __builtin_prefetch(p0 + o); __builtin_prefetch(p1 + o); }
    __builtin_prefetch(L + (k * r + il) * c);
  }
}

// the bilinear plane value and linear line value of channel j at point weights w.. / a., b. (the four texels
// p00 … p11, the two l0, l1)
#define PLANE_J(j) (w00 * p00[j] + w01 * p01[j] + w10 * p10[j] + w11 * p11[j])
#define LINE_J(j) (al * l0[j] + bl * l1[j])

// summed = false: O (M, 3, C), the product per axis pair and channel (of type T: float, or bfloat16 rounded
// to nearest even as torch's conversion); summed = true: O (M,), the sum of those 3·C products (the density:
// no (M, 3, C) intermediate is written, read back or kept for backward)
template <typename T>
static void forward_points(const float *P, const float *L, const float *X, T *O, int64_t m, int64_t r, int64_t c,
                           bool summed) {
  at::parallel_for(0, m, 256, [&](int64_t b, int64_t e) {
    for (int64_t n = b; n < e; ++n) {
      if (n + PF < e) prefetch_point(P, L, X + (n + PF) * 3, r, c, 0, r);
      float total = 0.f;
      Cells q; point_cells(X + n * 3, r, q);
      for (int k = 0; k < 3; ++k) {
        PAIR_CELLS(q, k);
        const float *p00 = P + ((k * r + ir) * r + ic) * c, *p01 = p00 + c, *p10 = p00 + r * c, *p11 = p10 + c;
        const float *l0 = L + (k * r + il) * c, *l1 = l0 + c;
        const float w00 = ar * ac, w01 = ar * bc, w10 = br * ac, w11 = br * bc;
        if (summed) {
          float acc = 0.f;
#pragma omp simd reduction(+ : acc)
          for (int64_t j = 0; j < c; ++j) acc += PLANE_J(j) * LINE_J(j);
          total += acc;
        } else {
          T *o = O + (n * 3 + k) * c;
          for (int64_t j = 0; j < c; ++j) o[j] = T(PLANE_J(j) * LINE_J(j));
        }
      }
      if (summed) O[n] = T(total);
    }
  });
}

torch::Tensor vm_forward(torch::Tensor planes, torch::Tensor lines, torch::Tensor xyz, bool summed) {
  const int64_t m = xyz.size(0), r = planes.size(1), c = planes.size(3);
  auto out = summed ? torch::empty({m}, xyz.options()) : torch::empty({m, 3, c}, xyz.options());
  forward_points(planes.data_ptr<float>(), lines.data_ptr<float>(), xyz.data_ptr<float>(), out.data_ptr<float>(),
                 m, r, c, summed);
  return out;
}

// vm_forward's (M, 3, C) products as the first M of `rows` zero-padded bfloat16 rows (rows, 3·C): the grid
// decoder's bf16 input (fields/row_buckets.py) without a float32 copy in between
torch::Tensor vm_forward_rows(torch::Tensor planes, torch::Tensor lines, torch::Tensor xyz, int64_t rows) {
  const int64_t m = xyz.size(0), r = planes.size(1), c = planes.size(3);
  TORCH_CHECK(rows >= m, "forward_rows: ", rows, " rows cannot hold the ", m, " points");
  auto out = torch::empty({rows, 3 * c}, xyz.options().dtype(torch::kBFloat16));
  out.narrow(0, m, rows - m).zero_();
  forward_points(planes.data_ptr<float>(), lines.data_ptr<float>(), xyz.data_ptr<float>(),
                 out.data_ptr<at::BFloat16>(), m, r, c, false);
  return out;
}

// vm_forward's summed value of one point x (3,): the sum of its 3·C products (the same operations in the
// same order)
static inline float point_sum(const float *P, const float *L, const float *x, int64_t r, int64_t c) {
  float total = 0.f;
  Cells q; point_cells(x, r, q);
  for (int k = 0; k < 3; ++k) {
    PAIR_CELLS(q, k);
    const float *p00 = P + ((k * r + ir) * r + ic) * c, *p01 = p00 + c, *p10 = p00 + r * c, *p11 = p10 + c;
    const float *l0 = L + (k * r + il) * c, *l1 = l0 + c;
    const float w00 = ar * ac, w01 = ar * bc, w10 = br * ac, w11 = br * bc;
    float acc = 0.f;
#pragma omp simd reduction(+ : acc)
    for (int64_t j = 0; j < c; ++j) acc += PLANE_J(j) * LINE_J(j);
    total += acc;
  }
  return total;
}

// a lower bound of softplus(z) = log(1 + e^z) without exp or log1p (which cost as much as a lookup): the
// largest of 0, z and its tangents at z = ±4, ±2, 0 (softplus is convex); at most 0.09 under it
static inline float softplus_below(float z) {
  static const float A[5] = {0.0900947678f, 0.365333855f, 0.693147181f, 0.365333855f, 0.0900947678f};
  static const float B[5] = {0.0179862100f, 0.119202922f, 0.5f, 0.880797078f, 0.982013790f};
  float b = z > 0.f ? z : 0.f;
  for (int i = 0; i < 5; ++i) {
    const float t = A[i] + B[i] * z;
    b = t > b ? t : b;
  }
  return b;
}

// the density's summed lookup of packed samples, along each ray only up to its early stop: the samples of ray
// i are offsets[i] … offsets[i + 1] − 1, in order; a sample is looked up while a lower bound of the optical
// depth of the ray's earlier samples, Σ scale · softplus_below(raw + shift) · δ (the density is scale ·
// softplus(raw + shift); each term clamped to 1e3, a NaN to 1e3, as packed_depth_before does), is at most
// `limit`; the later ones get −inf (a density of 0). A ray's first PF samples are prefetched before its
// loop. Offsets that do not run from 0 to M without decreasing are refused (they would read and write
// outside the samples, or leave some unwritten). out (M,)
torch::Tensor vm_forward_until(torch::Tensor planes, torch::Tensor lines, torch::Tensor xyz, torch::Tensor offsets,
                               torch::Tensor deltas, double shift, double scale, double limit) {
  TORCH_CHECK(xyz.dim() == 2 && xyz.size(1) == 3 && offsets.dim() == 1 && offsets.size(0) >= 1 &&
                  deltas.numel() == xyz.size(0),
              "forward_until: expected xyz (M, 3), offsets (N + 1,) and deltas (M,)");
  const int64_t m = xyz.size(0), n = offsets.size(0) - 1, r = planes.size(1), c = planes.size(3);
  const float *P = planes.data_ptr<float>(), *L = lines.data_ptr<float>(), *X = xyz.data_ptr<float>();
  const float *DELTA = deltas.data_ptr<float>();
  const int64_t *OFF = offsets.data_ptr<int64_t>();
  bool ordered = OFF[0] == 0 && OFF[n] == m;
  for (int64_t i = 0; i < n && ordered; ++i) ordered = OFF[i] <= OFF[i + 1];
  TORCH_CHECK(ordered, "forward_until: offsets must run from 0 to the ", m, " samples without decreasing");
  auto out = torch::empty({m}, xyz.options());
  float *O = out.data_ptr<float>();
  const float none = -std::numeric_limits<float>::infinity(), sh = (float)shift, sc = (float)scale;
  at::parallel_for(0, n, 64, [&](int64_t b, int64_t e) {
    for (int64_t i = b; i < e; ++i) {
      const int64_t hi = OFF[i + 1];
      int64_t s = OFF[i];
      for (int64_t q = s; q < std::min(hi, s + PF); ++q) prefetch_point(P, L, X + q * 3, r, c, 0, r);
      double depth = 0.0;
      for (; s < hi && depth <= limit; ++s) {
        if (s + PF < hi) prefetch_point(P, L, X + (s + PF) * 3, r, c, 0, r);
        const float raw = point_sum(P, L, X + s * 3, r, c);
        O[s] = raw;
        const float tau = sc * softplus_below(raw + sh) * DELTA[s];
        depth += tau <= 1e3f ? tau : 1e3f;
      }
      for (; s < hi; ++s) O[s] = none;
    }
  });
  return out;
}

// one point and axis pair of the backward: the scatter of the gradient g (channel j: g[j], or g[0] for every
// channel when SUMMED) into the plane gradient's rows ir (row0) and ir + 1 (row1) and into the line gradient
// (line); ALL: all three (the common case, a point inside a thread's rows)
template <bool SUMMED, bool ALL>
static inline void scatter_pair(int64_t c, const float *__restrict__ P, const float *__restrict__ L,
                                float *__restrict__ GP, float *__restrict__ GL, int64_t o00, int64_t o01,
                                int64_t o10, int64_t o11, int64_t q0, int64_t q1, float w00, float w01,
                                float w10, float w11, float al, float bl, const float *__restrict__ g,
                                bool row0, bool row1, bool line) {
#pragma GCC ivdep
  for (int64_t j = 0; j < c; ++j) {
    const float gj = SUMMED ? g[0] : g[j];
    const float pv = w00 * P[o00 + j] + w01 * P[o01 + j] + w10 * P[o10 + j] + w11 * P[o11 + j];
    const float lv = al * L[q0 + j] + bl * L[q1 + j];
    const float gpl = gj * lv, glp = gj * pv;
    if (ALL || row0) { GP[o00 + j] += w00 * gpl; GP[o01 + j] += w01 * gpl; }
    if (ALL || row1) { GP[o10 + j] += w10 * gpl; GP[o11 + j] += w11 * gpl; }
    if (ALL || line) { GL[q0 + j] += al * glp; GL[q1 + j] += bl * glp; }
  }
}

// the rare case out of line (so that the common one stays as compact as before): a point whose rows ir and
// ir + 1 lie in two threads' bands; the line gradient goes with row ir
__attribute__((noinline)) static void edge_pair(bool summed, int64_t c, const float *P, const float *L, float *GP,
                                                float *GL, int64_t o00, int64_t o01, int64_t o10, int64_t o11,
                                                int64_t q0, int64_t q1, float w00, float w01, float w10,
                                                float w11, float al, float bl, const float *g, bool row0,
                                                bool row1) {
  if (summed)
    scatter_pair<true, false>(c, P, L, GP, GL, o00, o01, o10, o11, q0, q1, w00, w01, w10, w11, al, bl, g, row0,
                              row1, row0);
  else
    scatter_pair<false, false>(c, P, L, GP, GL, o00, o01, o10, o11, q0, q1, w00, w01, w10, w11, al, bl, g,
                               row0, row1, row0);
}

// the plane rows of each of nt threads: thread t owns rows [bound[t], bound[t + 1]) of all three planes, split
// where a subsample of the points' rows (those with a gradient) reaches t / nt of its count, so that the
// threads scatter about as many points each
static std::vector<int64_t> row_bounds(const float *X, const float *G, bool summed, int64_t m, int64_t r,
                                       int64_t nt) {
  std::vector<int64_t> count(r, 0), bound(nt + 1, r);
  bound[0] = 0;
  if (nt == 1) return bound;
  const int64_t stride = std::max<int64_t>(1, m / 8192) | 1;  // odd: not in step with a periodic gradient
  int64_t total = 0;
  for (int64_t n = 0; n < m; n += stride) {
    if (summed && G[n] == 0.0f) continue;
    for (int k = 0; k < 3; ++k) {
      int ir; float a, b;
      cell(X[n * 3 + MAT1[k]], r, ir, a, b);
      ++count[ir]; ++total;
    }
  }
  if (total == 0) {  // no sampled point has a gradient: equal bands
    for (int64_t t = 1; t < nt; ++t) bound[t] = t * r / nt;
    return bound;
  }
  int64_t acc = 0, t = 1;
  for (int64_t i = 0; i < r && t < nt; ++i) {
    acc += count[i];
    while (t < nt && acc * nt >= total * t) bound[t++] = i + 1;
  }
  return bound;
}

// one thread's share of the backward: every point's scatter into the plane rows [lo, hi) (all: 0, r)
template <bool SUMMED, typename GT>
static void scatter_band(const float *__restrict__ P, const float *__restrict__ L, const float *__restrict__ X,
                         const GT *__restrict__ G, float *__restrict__ GP, float *__restrict__ GL, int64_t m,
                         int64_t r, int64_t c, int64_t lo, int64_t hi) {
  const bool all = lo == 0 && hi == r;
  std::vector<float> wide(std::is_same<GT, float>::value ? 0 : 3 * c);  // a bfloat16 point's gradient as float
  for (int64_t n = 0; n < m; ++n) {
    if (SUMMED && (float)G[n] == 0.0f) continue;  // e.g. behind a ray's early stop: nothing to scatter
    if (n + PF < m) prefetch_point(P, L, X + (n + PF) * 3, r, c, lo, hi);
    Cells q; point_cells(X + n * 3, r, q);
    const float *gn = nullptr;  // the point's (3, C) gradient
    if constexpr (std::is_same<GT, float>::value) {
      gn = G + n * 3 * c;
    } else if (!SUMMED) {
      for (int64_t j = 0; j < 3 * c; ++j) wide[j] = (float)G[n * 3 * c + j];
      gn = wide.data();
    }
    for (int k = 0; k < 3; ++k) {
      PAIR_CELLS(q, k);
      const bool row0 = all || (ir >= lo && ir < hi), row1 = all || (ir + 1 >= lo && ir + 1 < hi);
      if (!row0 && !row1) continue;  // another thread's rows
      const int64_t o00 = ((k * r + ir) * r + ic) * c, o01 = o00 + c, o10 = o00 + r * c, o11 = o10 + c;
      const int64_t q0 = (k * r + il) * c, q1 = q0 + c;
      const float w00 = ar * ac, w01 = ar * bc, w10 = br * ac, w11 = br * bc;
      const float *g = SUMMED ? (const float *)G + n : gn + k * c;
      if (row0 && row1)
        scatter_pair<SUMMED, true>(c, P, L, GP, GL, o00, o01, o10, o11, q0, q1, w00, w01, w10, w11, al, bl, g,
                                   true, true, true);
      else  // a point on the edge of the band: one of its rows, and its line where ir is ours
        edge_pair(SUMMED, c, P, L, GP, GL, o00, o01, o10, o11, q0, q1, w00, w01, w10, w11, al, bl, g, row0, row1);
    }
  }
}

std::vector<torch::Tensor> vm_backward(torch::Tensor planes, torch::Tensor lines, torch::Tensor xyz,
                                       torch::Tensor grad) {
  // no races and no per-thread copy of the plane gradient: each thread owns a band of rows of all three
  // planes (row_bounds), zeroes it, walks all points and scatters only into its rows; a point's line
  // gradient goes to the thread that owns its row ir, into that thread's own (small) line buffer, summed at
  // the end. Each plane gradient element is summed in point order by one thread: the same bits on any
  // number of threads; the line gradients' sum order depends on the thread count.
  // grad: (M, 3, C), or (M,) for a summed forward (one value for all 3·C products of a point); (M, 3, C)
  // bfloat16 for vm_forward_rows (read as it is: its float values exactly).
  const int64_t m = xyz.size(0), r = planes.size(1), c = planes.size(3);
  const bool summed = grad.dim() == 1, bf16 = grad.scalar_type() == torch::kBFloat16;
  TORCH_CHECK(grad.is_contiguous() && (!bf16 || !summed), "backward: expected a contiguous grad, bf16 (M, 3, C)");
  const int64_t threads = std::min<int64_t>(64, at::get_num_threads());
  const int64_t nt = std::max<int64_t>(1, std::min<int64_t>({threads, (m + 4095) / 4096, r - 1}));
  auto gp = torch::empty({3, r, r, c}, planes.options()), gl = torch::zeros({nt, 3, r, c}, lines.options());
  const float *__restrict__ P = planes.data_ptr<float>(), *__restrict__ L = lines.data_ptr<float>();
  const float *__restrict__ X = xyz.data_ptr<float>(), *__restrict__ G = bf16 ? nullptr : grad.data_ptr<float>();
  const at::BFloat16 *GB = bf16 ? grad.data_ptr<at::BFloat16>() : nullptr;
  float *__restrict__ GP = gp.data_ptr<float>();
  float *GL0 = gl.data_ptr<float>();
  const int64_t sl = 3 * r * c;
  const std::vector<int64_t> bound = row_bounds(X, G, summed, m, r, nt);
  at::parallel_for(0, nt, 1, [&](int64_t tb, int64_t te) {
    for (int64_t t = tb; t < te; ++t) {
      const int64_t lo = bound[t], hi = bound[t + 1];
      for (int k = 0; k < 3; ++k) std::fill(GP + (k * r + lo) * r * c, GP + (k * r + hi) * r * c, 0.0f);
      if (summed)
        scatter_band<true>(P, L, X, G, GP, GL0 + t * sl, m, r, c, lo, hi);
      else if (bf16)
        scatter_band<false>(P, L, X, GB, GP, GL0 + t * sl, m, r, c, lo, hi);
      else
        scatter_band<false>(P, L, X, G, GP, GL0 + t * sl, m, r, c, lo, hi);
    }
  });
  return {gp, nt == 1 ? gl[0] : gl.sum(0)};
}

// the slopes of cell()'s weights a, b along x (one texel's weight rises where the other falls; 0 where both
// texels lie outside, NaN for a NaN/inf coordinate): grid_sample's gradient for its grid, zeros padding
static inline void cell_slope(float x, int r, float &da, float &db) {
  const float s = 0.5f * (r - 1), u = (x + 1.f) * s;
  if (!std::isfinite(u)) { da = db = std::numeric_limits<float>::quiet_NaN(); return; }
  const float fl = std::floor(u);
  if (fl < -1.f || fl > (float)(r - 1)) { da = db = 0.f; return; }
  if (fl == -1.f) { da = s; db = 0.f; return; }
  if (fl == (float)(r - 1)) { da = 0.f; db = -s; return; }
  da = -s; db = s;
}

// the gradient for the points (M, 3) of sum_n,k,j G[n,k,j] P_kj(x_n) L_kj(x_n) (G (M, 3, C) float or
// bfloat16, or (M,) for a summed forward): per point and axis pair, the slope of the plane's bilinear value
// along its column and row coordinates times the line's value, and the line's slope times the plane's value.
// Each point is its own: parallel over points, no scatter, the same bits on any number of threads.
template <bool SUMMED, typename GT>
static void point_grads(const float *__restrict__ P, const float *__restrict__ L, const float *__restrict__ X,
                        const GT *__restrict__ G, float *__restrict__ GX, int64_t m, int64_t r, int64_t c) {
  at::parallel_for(0, m, 256, [&](int64_t b, int64_t e) {
    std::vector<float> wide(SUMMED ? 1 : 3 * c);
    for (int64_t n = b; n < e; ++n) {
      float gx[3] = {0.f, 0.f, 0.f};
      if (SUMMED && (float)G[n] == 0.0f) {  // e.g. behind a ray's early stop: no gradient
        std::copy(gx, gx + 3, GX + n * 3);
        continue;
      }
      if (n + PF < e) prefetch_point(P, L, X + (n + PF) * 3, r, c, 0, r);
      for (int64_t j = 0; j < (SUMMED ? 1 : 3 * c); ++j) wide[j] = (float)G[SUMMED ? n : n * 3 * c + j];
      Cells q; point_cells(X + n * 3, r, q);
      float da[3], db[3];
      for (int d = 0; d < 3; ++d) cell_slope(X[n * 3 + d], r, da[d], db[d]);
      for (int k = 0; k < 3; ++k) {
        PAIR_CELLS(q, k);
        const float dac = da[MAT0[k]], dbc = db[MAT0[k]], dar = da[MAT1[k]], dbr = db[MAT1[k]];
        const float dal = da[VEC[k]], dbl = db[VEC[k]];
        const float *p00 = P + ((k * r + ir) * r + ic) * c, *p01 = p00 + c, *p10 = p00 + r * c, *p11 = p10 + c;
        const float *l0 = L + (k * r + il) * c, *l1 = l0 + c;
        const float *g = wide.data() + (SUMMED ? 0 : k * c);
        float sc = 0.f, sr = 0.f, sl = 0.f;
        for (int64_t j = 0; j < c; ++j) {
          const float gj = g[SUMMED ? 0 : j];
          const float top = ac * p00[j] + bc * p01[j], bottom = ac * p10[j] + bc * p11[j];
          const float lv = gj * LINE_J(j), pv = gj * (ar * top + br * bottom);
          sc += lv * (ar * (dac * p00[j] + dbc * p01[j]) + br * (dac * p10[j] + dbc * p11[j]));
          sr += lv * (dar * top + dbr * bottom);
          sl += pv * (dal * l0[j] + dbl * l1[j]);
        }
        gx[MAT0[k]] += sc; gx[MAT1[k]] += sr; gx[VEC[k]] += sl;
      }
      std::copy(gx, gx + 3, GX + n * 3);
    }
  });
}

// vm_backward's gradient for the points instead of the factors (pose refinement moves the points): (M, 3)
torch::Tensor vm_point_backward(torch::Tensor planes, torch::Tensor lines, torch::Tensor xyz, torch::Tensor grad) {
  const int64_t m = xyz.size(0), r = planes.size(1), c = planes.size(3);
  const bool summed = grad.dim() == 1, bf16 = grad.scalar_type() == torch::kBFloat16;
  TORCH_CHECK(grad.is_contiguous() && (!bf16 || !summed), "point_backward: expected a contiguous grad, bf16 (M, 3, C)");
  auto gx = torch::empty({m, 3}, xyz.options());
  const float *P = planes.data_ptr<float>(), *L = lines.data_ptr<float>(), *X = xyz.data_ptr<float>();
  float *GX = gx.data_ptr<float>();
  if (summed)
    point_grads<true>(P, L, X, grad.data_ptr<float>(), GX, m, r, c);
  else if (bf16)
    point_grads<false>(P, L, X, grad.data_ptr<at::BFloat16>(), GX, m, r, c);
  else
    point_grads<false>(P, L, X, grad.data_ptr<float>(), GX, m, r, c);
  return gx;
}

// the grid renderer's packed march (render/march_cpu.py; GridModel._march): of ray i's counts[i] steps, those
// whose start near + step·k lies before far and (occupancy) whose midpoint's cell is set, as
// GridModel._kept tests them, in the same float32 operations in the same order (built without contraction:
// each product and sum rounds as torch's separate kernels do, so the same steps are kept). o_n, d_n (N, 3),
// near, far (N,) float32; counts (N,) int64; grid (G, G, G) bool. Returns ray and k (M,) int64, ray after
// ray: chunks of rays fill their share of the candidate slots in parallel, then move up into place.
std::vector<torch::Tensor> march(torch::Tensor o_n, torch::Tensor d_n, torch::Tensor near, torch::Tensor far,
                                 torch::Tensor counts, torch::Tensor grid, double step, bool occupancy) {
  const int64_t n = near.size(0), g = grid.size(0);
  TORCH_CHECK(o_n.numel() == 3 * n && d_n.numel() == 3 * n && far.numel() == n && counts.numel() == n &&
                  grid.dim() == 3 && grid.numel() == g * g * g,
              "march: expected o_n, d_n (N, 3), near, far, counts (N,) and grid (G, G, G)");
  const float *O = o_n.data_ptr<float>(), *D = d_n.data_ptr<float>();
  const float *NEAR = near.data_ptr<float>(), *FAR = far.data_ptr<float>();
  const int64_t *COUNT = counts.data_ptr<int64_t>();
  const bool *GRID = grid.data_ptr<bool>();
  std::vector<int64_t> first(n + 1, 0);  // each ray's first candidate slot
  for (int64_t i = 0; i < n; ++i) first[i + 1] = first[i] + std::max<int64_t>(COUNT[i], 0);
  auto ray = torch::empty({first[n]}, counts.options()), kk = torch::empty({first[n]}, counts.options());
  int64_t *RAY = ray.data_ptr<int64_t>(), *K = kk.data_ptr<int64_t>();
  const int64_t chunks = std::min<int64_t>(n, 64), per = chunks ? (n + chunks - 1) / chunks : 0;
  std::vector<int64_t> kept(chunks, 0);
  const float s = (float)step, half = 0.5f * (float)g, top = (float)(g - 1);
  at::parallel_for(0, chunks, 1, [&](int64_t cb, int64_t ce) {
    for (int64_t c = cb; c < ce; ++c) {
      const int64_t rb = std::min(n, c * per), re = std::min(n, rb + per);
      int64_t *rw = RAY + first[rb], *kw = K + first[rb];
      int64_t w = 0;
      for (int64_t i = rb; i < re; ++i) {
        const float nr = NEAR[i], fr = FAR[i];
        const float *o = O + i * 3, *d = D + i * 3;
        for (int64_t k = 0; k < COUNT[i]; ++k) {
          const float ts = nr + s * (float)k;
          if (!(ts < fr)) continue;
          if (occupancy) {
            const float left = fr - ts, tm = ts + 0.5f * (left > s ? s : left);  // clamp(max=step)
            int64_t cell = 0;
            for (int a = 0; a < 3; ++a) {
              const float u = (o[a] + tm * d[a] + 1.0f) * half;
              // as OccupancyGrid.cell_index: clamped, truncated (a NaN point: cell 0 of the axis)
              const int64_t j = u > 0.f ? (int64_t)(u < top ? u : top) : 0;
              cell = cell * g + j;
            }
            if (!GRID[cell]) continue;
          }
          rw[w] = i; kw[w] = k; ++w;
        }
      }
      kept[c] = w;
    }
  });
  int64_t total = 0;  // the chunks' kept slots moved up, in order, behind each other
  for (int64_t c = 0; c < chunks; ++c) {
    const int64_t from = first[std::min(n, c * per)];
    if (from != total && kept[c]) {
      std::memmove(RAY + total, RAY + from, kept[c] * sizeof(int64_t));
      std::memmove(K + total, K + from, kept[c] * sizeof(int64_t));
    }
    total += kept[c];
  }
  return {ray.narrow(0, 0, total), kk.narrow(0, 0, total)};
}

// how many threads an at::parallel_for of this build spreads over (1 where it was built without OpenMP)
int64_t parallel_threads(int64_t n) {
  std::vector<int> used(std::max<int64_t>(256, at::get_num_threads()), 0);
  at::parallel_for(0, std::max<int64_t>(1, n), 1, [&](int64_t, int64_t) {
    const int t = at::get_thread_num();
    if (t >= 0 && t < (int)used.size()) used[t] = 1;
  });
  return std::count(used.begin(), used.end(), 1);
}

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("parallel_threads", &parallel_threads);
  m.def("forward", &vm_forward);
  m.def("forward_rows", &vm_forward_rows);
  m.def("backward", &vm_backward);
  m.def("point_backward", &vm_point_backward);
  m.def("forward_until", &vm_forward_until);
  m.def("march", &march);
}
