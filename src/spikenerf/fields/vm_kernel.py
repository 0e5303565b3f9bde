"""A fused CPU kernel for the VM lookup (bilinear planes × linear lines) and its backward, built on first use.

``grid_sample`` on a CPU spends most of a training step in its backward (a strided scatter per channel). This
kernel reads the factors channels-last and does one pass over the points: forward ``P_m(x)·L_m(x)`` for the
three axis pairs; backward the scatter of ``∂/∂P`` and ``∂/∂L`` into channels-last gradients (≈ 11 M
multiply-adds for a 58 k-point, 16-channel batch). No races and no per-thread copy of the plane gradients:
each thread owns a band of plane rows, balanced by a sample of the points' rows, and scatters only there (so
the plane gradients have the same bits on any number of threads); the small line gradients are per-thread
buffers, summed at the end.
For the density (``summed``) it adds the products up itself, so that no (M, 3, C) tensor is written,
summed by torch and, in the backward, expanded back into a contiguous copy.
The lookups are random reads of a grid larger than the L2 cache, so each loop prefetches the texels of the
point 8 ahead. It is compiled with the system C++ compiler through ``torch.utils.cpp_extension`` (``-O3``,
``-march=native`` on x86-64, ``-fopenmp`` on Linux so its loops use torch's threads; cached under
``~/.cache/torch_extensions`` in a folder named by the source, the flags and the CPU's feature flags;
20–90 s the first time on a machine; a process that finds the module compiled imports it at once, and
concurrent first builds are serialised by an ``flock`` that dies with its holder). Where that is not possible (no
compiler, a CUDA tensor, float64, gradients wanted for the points, ``SPIKENERF_VM_KERNEL=0``, inside
:func:`suspended`) callers fall back to ``grid_sample``; :func:`available` says which path is used.
The forward and the backward are ``torch.library`` custom ops, so ``torch.compile(fullgraph=True)`` keeps them
in its graph (``train --compile`` on a CPU; before, the compiled step fell back to ``grid_sample``).
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.util
import os
import platform
import shlex
import shutil
import sys
import time
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from spikenerf.core.tracing import constant_result
from spikenerf.fields.vm_ops import channels_last, register_pair

try:
    import fcntl
except ImportError:  # pragma: no cover - not on Unix: no build lock
    fcntl = None  # type: ignore[assignment]

_SOURCE = r"""
#include <torch/extension.h>
#include <ATen/Parallel.h>
#include <algorithm>
#include <cmath>
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

// software prefetch of the texels point x will read (the lookups are random; the OoO window is too short)
static const int64_t PF = 8;  // points ahead
static inline void prefetch_point(const float *P, const float *L, const float *x, int64_t r, int64_t c,
                                  int64_t lo, int64_t hi) {
  for (int k = 0; k < 3; ++k) {
    int ic, ir, il; float a, b;
    cell(x[MAT1[k]], r, ir, a, b);
    if (ir + 1 < lo || ir >= hi) continue;  // rows [lo, hi) only (the backward's band of a thread)
    cell(x[MAT0[k]], r, ic, a, b); cell(x[VEC[k]], r, il, a, b);
    const char *p0 = (const char *)(P + ((k * r + ir) * r + ic) * c), *p1 = p0 + r * c * sizeof(float);
    for (int64_t o = 0; o < 2 * c * (int64_t)sizeof(float); o += 64) { __builtin_prefetch(p0 + o); __builtin_prefetch(p1 + o); }
    __builtin_prefetch(L + (k * r + il) * c);
  }
}

// the bilinear plane value and linear line value of channel j at point weights w.. / a., b. (the four texels
// p00 … p11, the two l0, l1)
#define PLANE_J(j) (w00 * p00[j] + w01 * p01[j] + w10 * p10[j] + w11 * p11[j])
#define LINE_J(j) (al * l0[j] + bl * l1[j])

// summed = false: out (M, 3, C), the product per axis pair and channel; summed = true: out (M,), the sum of
// those 3·C products (the density: no (M, 3, C) intermediate is written, read back or kept for backward)
torch::Tensor vm_forward(torch::Tensor planes, torch::Tensor lines, torch::Tensor xyz, bool summed) {
  const int64_t m = xyz.size(0), r = planes.size(1), c = planes.size(3);
  auto out = summed ? torch::empty({m}, xyz.options()) : torch::empty({m, 3, c}, xyz.options());
  const float *P = planes.data_ptr<float>(), *L = lines.data_ptr<float>(), *X = xyz.data_ptr<float>();
  float *O = out.data_ptr<float>();
  at::parallel_for(0, m, 256, [&](int64_t b, int64_t e) {
    for (int64_t n = b; n < e; ++n) {
      if (n + PF < e) prefetch_point(P, L, X + (n + PF) * 3, r, c, 0, r);
      float total = 0.f;
      for (int k = 0; k < 3; ++k) {
        int ic, ir, il; float ac, bc, ar, br, al, bl;
        cell(X[n * 3 + MAT0[k]], r, ic, ac, bc); cell(X[n * 3 + MAT1[k]], r, ir, ar, br);
        cell(X[n * 3 + VEC[k]], r, il, al, bl);
        const float *p00 = P + ((k * r + ir) * r + ic) * c, *p01 = p00 + c, *p10 = p00 + r * c, *p11 = p10 + c;
        const float *l0 = L + (k * r + il) * c, *l1 = l0 + c;
        const float w00 = ar * ac, w01 = ar * bc, w10 = br * ac, w11 = br * bc;
        if (summed) {
          float acc = 0.f;
#pragma omp simd reduction(+ : acc)
          for (int64_t j = 0; j < c; ++j) acc += PLANE_J(j) * LINE_J(j);
          total += acc;
        } else {
          float *o = O + (n * 3 + k) * c;
          for (int64_t j = 0; j < c; ++j) o[j] = PLANE_J(j) * LINE_J(j);
        }
      }
      if (summed) O[n] = total;
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
template <bool SUMMED>
static void scatter_band(const float *__restrict__ P, const float *__restrict__ L, const float *__restrict__ X,
                         const float *__restrict__ G, float *__restrict__ GP, float *__restrict__ GL, int64_t m,
                         int64_t r, int64_t c, int64_t lo, int64_t hi) {
  const bool all = lo == 0 && hi == r;
  for (int64_t n = 0; n < m; ++n) {
    if (SUMMED && G[n] == 0.0f) continue;  // e.g. behind a ray's early stop: nothing to scatter
    if (n + PF < m) prefetch_point(P, L, X + (n + PF) * 3, r, c, lo, hi);
    for (int k = 0; k < 3; ++k) {
      int ic, ir, il; float ac, bc, ar, br, al, bl;
      cell(X[n * 3 + MAT1[k]], r, ir, ar, br);
      const bool row0 = all || (ir >= lo && ir < hi), row1 = all || (ir + 1 >= lo && ir + 1 < hi);
      if (!row0 && !row1) continue;  // another thread's rows
      cell(X[n * 3 + MAT0[k]], r, ic, ac, bc); cell(X[n * 3 + VEC[k]], r, il, al, bl);
      const int64_t o00 = ((k * r + ir) * r + ic) * c, o01 = o00 + c, o10 = o00 + r * c, o11 = o10 + c;
      const int64_t q0 = (k * r + il) * c, q1 = q0 + c;
      const float w00 = ar * ac, w01 = ar * bc, w10 = br * ac, w11 = br * bc;
      const float *g = SUMMED ? G + n : G + (n * 3 + k) * c;
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
  // grad: (M, 3, C), or (M,) for a summed forward (one value for all 3·C products of a point).
  const int64_t m = xyz.size(0), r = planes.size(1), c = planes.size(3);
  const bool summed = grad.dim() == 1;
  const int64_t threads = std::min<int64_t>(64, at::get_num_threads());
  const int64_t nt = std::max<int64_t>(1, std::min<int64_t>({threads, (m + 4095) / 4096, r - 1}));
  auto gp = torch::empty({3, r, r, c}, planes.options()), gl = torch::zeros({nt, 3, r, c}, lines.options());
  const float *__restrict__ P = planes.data_ptr<float>(), *__restrict__ L = lines.data_ptr<float>();
  const float *__restrict__ X = xyz.data_ptr<float>(), *__restrict__ G = grad.data_ptr<float>();
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
      else
        scatter_band<false>(P, L, X, G, GP, GL0 + t * sl, m, r, c, lo, hi);
    }
  });
  return {gp, nt == 1 ? gl[0] : gl.sum(0)};
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
  m.def("backward", &vm_backward);
}
"""

_MODULE: Any = None
_FAILED = False


def _cflags() -> list[str]:
    """``-O3 -ffp-contract=off``, plus ``-march=native`` on x86-64 (AVX2/AVX-512 for the scatter loops:
    backward 1.6× faster). No fused multiply-adds: the compiler contracted ``a * b + c`` in one instance of
    the scatter and not in another (a band's edge), so a plane gradient differed in its last bit between 1
    and 2 threads on an AVX-512 CPU (tests/test_gradients.py)."""
    native = ["-march=native"] if platform.machine().lower() in ("x86_64", "amd64") else []
    return ["-O3", "-ffp-contract=off", *native]


# ``at::parallel_for`` is a header template over ``#pragma omp parallel``: an extension built without
# ``-fopenmp`` runs it on one thread whatever ``torch.get_num_threads()`` says. So the kernel is compiled with
# ``-fopenmp`` and linked against the very GNU OpenMP library torch has loaded (its wheels bundle one, named
# ``libgomp.so.1`` or, after auditwheel, ``libgomp-<hash>.so.1``), never a second runtime with its own
# thread pool. Where torch uses another runtime (LLVM libomp, Intel iomp5) or none is found, the kernel is
# built without OpenMP and runs on one thread, as before.


def _torch_gomp() -> str:
    """The path of the GNU OpenMP library mapped into this process after importing torch ("" if none)."""
    try:
        maps = Path("/proc/self/maps").read_text()
    except OSError:
        return ""
    found = {
        line.split()[-1] for line in maps.splitlines() if "/libgomp" in line and line.split()[-1][0] == "/"
    }
    return min(found) if len(found) == 1 else ""


def _openmp_flags() -> tuple[list[str], list[str]]:
    """(compile flags, link flags) for OpenMP, or ([], []) where the kernel is built without it."""
    if not sys.platform.startswith("linux"):
        return [], []
    gomp = _torch_gomp()
    if not gomp:
        return [], []
    return ["-fopenmp"], [gomp, f"-Wl,-rpath,{Path(gomp).parent}"]


_OPENMP_CFLAGS, _OPENMP_LDFLAGS = _openmp_flags()


def _cpu_fingerprint() -> str:
    """The CPU's feature flags (Linux), so that a cache folder shared by different CPUs never serves one a
    binary built with ``-march=native`` for another; "" where they cannot be read."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return ""
    return next((line for line in text.splitlines() if line.startswith(("flags", "Features"))), "")


_CPU = _cpu_fingerprint()


def cpu_has(*flags: str) -> bool:
    """Whether the CPU lists any of ``flags`` (Linux ``/proc/cpuinfo``; False where it cannot be read)."""
    return any(flag in _CPU.split() for flag in flags)


# without the CPU's flags a shared cache folder could not tell CPUs apart: no -march=native then
_CFLAGS = _cflags() if _CPU else ["-O3", "-ffp-contract=off"]


def _name(cflags: list[str], ldflags: list[str], source: str = _SOURCE, prefix: str = "spikenerf_vm_") -> str:
    """One build folder per source, flags (the OpenMP library's path included) and CPU."""
    return prefix + hashlib.sha256("\0".join([source, *cflags, *ldflags, _CPU]).encode()).hexdigest()[:12]


BUILD_WAIT_S = 900.0  # the longest we wait for another process's build before using grid_sample
_BUILD_LOCK = "spikenerf-build.lock"  # our own lock file in the build folder (torch's is ``lock``)


@contextlib.contextmanager
def _build_lock(build_dir: Path, wait_s: float | None = None) -> Iterator[bool]:
    """Hold an exclusive ``flock`` on ``build_dir/spikenerf-build.lock`` for the block; yields False when
    another process held it for ``wait_s`` seconds (default :data:`BUILD_WAIT_S`).

    The kernel drops a ``flock`` when its holder dies (even by SIGKILL), so a lock file left behind never
    blocks anyone: only a live process building the kernel is waited for. Without ``fcntl`` (not Unix)
    nothing is locked.
    """
    if fcntl is None:  # pragma: no cover - not on Unix
        yield True
        return
    wait_s = BUILD_WAIT_S if wait_s is None else wait_s
    build_dir.mkdir(parents=True, exist_ok=True)
    fd = os.open(build_dir / _BUILD_LOCK, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        deadline, told = time.monotonic() + wait_s, False
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() >= deadline:
                    yield False
                    return
                if not told:
                    print("waiting for another process building the fused CPU kernel…", file=sys.stderr)
                    told = True
                time.sleep(0.2)
        try:
            yield True
        finally:
            fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)


def _import_built(name: str, library: Path) -> Any:
    """Import an already compiled extension module from its ``.so`` (None when it cannot be loaded: a
    truncated or foreign file, which the caller then rebuilds)."""
    spec = importlib.util.spec_from_file_location(name, library)
    if spec is None or spec.loader is None:
        return None
    try:
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    except ImportError:
        return None
    return module if hasattr(module, "forward") and hasattr(module, "backward") else None


def _build(cflags: list[str], ldflags: list[str]) -> Any:
    """Load the cached module, or compile it, with these extra flags; None when another process's build
    held the build lock for :data:`BUILD_WAIT_S` seconds.

    Under our own ``flock`` (:func:`_build_lock`): a compiled ``.so`` is imported at once, without torch's
    build machinery; otherwise torch's own ``lock`` file is removed first (no live spikenerf process can be
    building this folder while we hold the flock, so it is stale, or, with torch ≥ 2.14, simply left in
    place after every build) and the module is built with ``load_inline``.
    """
    from torch.utils.cpp_extension import _get_build_directory, load_inline

    name = _name(_CFLAGS + cflags, ldflags)
    build_dir = Path(_get_build_directory(name, verbose=False))
    with _build_lock(build_dir) as locked:
        if not locked:
            warnings.warn(
                f"VM CPU kernel: another process held {build_dir / _BUILD_LOCK} for {BUILD_WAIT_S:.0f} s"
                " while building the kernel, using grid_sample",
                stacklevel=3,
            )
            return None
        library = build_dir / f"{name}.so"
        if library.exists():
            module = _import_built(name, library)
            if module is not None:
                return module
        with contextlib.suppress(FileNotFoundError):
            (build_dir / "lock").unlink()
        print("building the fused CPU kernel (once, ~1 min)…", file=sys.stderr, flush=True)
        _find_ninja()
        return load_inline(
            name, cpp_sources=[_SOURCE], extra_cflags=_CFLAGS + cflags, extra_ldflags=ldflags, with_cuda=False
        )


def _find_ninja() -> None:
    """Put the ``ninja`` of the pip package (a dependency) on ``PATH`` when none is there: torch's build
    runs ``ninja`` by name, and a virtual environment's ``bin`` is not on ``PATH`` unless it is activated."""
    if shutil.which("ninja") is not None:
        return
    with contextlib.suppress(ImportError, AttributeError):
        import ninja  # type: ignore[import-not-found,import-untyped,unused-ignore]

        if shutil.which("ninja", path=ninja.BIN_DIR) is not None:
            os.environ["PATH"] = os.pathsep.join([ninja.BIN_DIR, os.environ.get("PATH", "")])


def _built_any() -> bool:
    """Whether a compiled module of either build variant is in torch's extension cache already (then no
    compiler is needed)."""
    from torch.utils.cpp_extension import _get_build_directory

    for cflags, ldflags in ((_OPENMP_CFLAGS, _OPENMP_LDFLAGS), ([], [])):
        name = _name(_CFLAGS + cflags, ldflags)
        try:  # (torch makes the folder: an unwritable cache is "nothing built", not an error)
            folder = Path(_get_build_directory(name, verbose=False))
        except OSError:
            continue
        if (folder / f"{name}.so").exists():
            return True
    return False


def _load() -> Any:
    """The compiled module, or None (compiled once per process; a failure is reported once and remembered).

    With OpenMP first where torch's GNU OpenMP library was found; if that build fails (e.g. a compiler
    without OpenMP support), once more without it (single-threaded) before giving up on the kernel.
    """
    global _MODULE, _FAILED
    if _MODULE is not None or _FAILED:
        return _MODULE
    if os.environ.get("SPIKENERF_VM_KERNEL", "1") == "0":
        _FAILED = True
        return None
    compiler = os.environ.get("CXX", "c++")
    try:  # CXX may hold a wrapper and flags ("ccache g++")
        words = shlex.split(compiler) or ["c++"]
    except ValueError:
        words = compiler.split() or ["c++"]
    if not any(shutil.which(word) for word in words[:2]) and not _built_any():
        warnings.warn(
            f"VM CPU kernel: no C++ compiler ({compiler}) to build it: using grid_sample, which is slower on "
            "a CPU (install g++ or clang++, or set CXX)",
            stacklevel=2,
        )
        _FAILED = True
        return None
    variants = [(_OPENMP_CFLAGS, _OPENMP_LDFLAGS)] if _OPENMP_CFLAGS else []
    variants.append(([], []))
    for i, (cflags, ldflags) in enumerate(variants):
        try:
            with warnings.catch_warnings():  # torch's multi-line compiler banners: ours says it in one line
                warnings.filterwarnings("ignore", module=r"torch\.utils\.cpp_extension")
                _MODULE = _build(cflags, ldflags)
            break
        except (
            Exception
        ) as err:  # no compiler, no ninja, no headers, no OpenMP: try the next, then grid_sample
            last = i == len(variants) - 1
            fallback = "using grid_sample" if last else "building it without OpenMP"
            hint = " (the build needs a C++ compiler, g++ or clang++, and ninja)" if last else ""
            first = next((line.strip() for line in str(err).splitlines() if line.strip()), "")[:200]
            warnings.warn(f"VM CPU kernel: {fallback}{hint} ({type(err).__name__}: {first})", stacklevel=2)
    _FAILED = _MODULE is None
    return _MODULE


def parallel_threads(n: int = 64) -> int:
    """How many threads the kernel's ``at::parallel_for`` uses over ``n`` items (1 without OpenMP).

    Raises:
        RuntimeError: the kernel cannot be built or is disabled.
    """
    if _load() is None:
        raise RuntimeError("parallel_threads: the fused VM CPU kernel is unavailable")
    return int(_MODULE.parallel_threads(n))


@constant_result  # builds or imports on the first call: a constant to a trace
def available() -> bool:
    """Whether the fused CPU kernel can be used in this process (builds it on the first call)."""
    return _load() is not None


#: set within :func:`suspended`: :func:`usable` says no (read by ``torch.compile`` as a guarded constant)
_SUSPENDED = False


@contextlib.contextmanager
def suspended() -> Iterator[None]:
    """Within: the kernel is not used (:func:`usable` is False), so callers take the ``grid_sample`` path (to
    compare the two). Outside it, nothing changes."""
    global _SUSPENDED
    before, _SUSPENDED = _SUSPENDED, True
    try:
        yield
    finally:
        _SUSPENDED = before


def usable(planes: Tensor, xyz: Tensor) -> bool:
    """The kernel applies: not :func:`suspended`, CPU float32 tensors, no gradient wanted for the points, and
    it builds."""
    return (
        not _SUSPENDED
        and planes.device.type == "cpu"
        and planes.dtype == torch.float32
        and xyz.dtype == torch.float32
        and not xyz.requires_grad
        and available()
    )


def _backward(planes: Tensor, lines: Tensor, xyz: Tensor, grad: Tensor) -> tuple[Tensor, Tensor]:
    gp, gl = _MODULE.backward(planes, lines, xyz, grad)  # (M,) grad after a summed forward
    return gp, gl


#: ``spikenerf::vm_cpu_forward`` (and ``_backward``): the kernel as custom ops, so compiled graphs keep it
_OP = register_pair("vm_cpu", lambda p, ln, x, summed: _MODULE.forward(p, ln, x, summed), _backward)


def vm_lookup(planes: Tensor, lines: Tensor, xyz: Tensor, summed: bool = False) -> Tensor:
    """``P_m(xyz)·L_m(xyz)`` per axis pair with the fused kernel (check :func:`usable` first).

    Args:
        planes: (3, C, R, R). lines: (3, C, R, 1). xyz: (M, 3), normally in [−1, 1]; outside, zeros padding
            as ``grid_sample`` (a NaN coordinate gives NaN).
        summed: return the sum over axis pairs and channels instead, computed in the kernel (the density:
            no (M, 3, C) tensor is written forward or materialised for the backward).
    Returns:
        (M, 3, C), the same values as :func:`spikenerf.fields.grid.sample_vm` transposed; (M,) when
        ``summed``.
    Raises:
        RuntimeError: the kernel cannot be built or is disabled (:func:`usable` is False).
    """
    if _load() is None:
        raise RuntimeError("vm_lookup: the fused VM CPU kernel is unavailable (check vm_kernel.usable first)")
    return _OP(*channels_last(planes, lines), xyz.contiguous(), summed)
