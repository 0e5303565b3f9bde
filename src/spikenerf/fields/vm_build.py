"""Building and loading the fused CPU kernel of ``vm_kernel.py`` (its C++ source: ``vm_cpu.cpp``, package
data beside this module, read with ``importlib.resources``: :func:`kernel_source`).

It is compiled with the system C++ compiler through ``torch.utils.cpp_extension`` (``-O3``, ``-march=native``
on x86-64, ``-fopenmp`` on Linux so its loops use torch's threads; cached under ``~/.cache/torch_extensions``
in a folder named by the source, the flags and the CPU's feature flags; 20–90 s the first time on a machine;
a process that finds the module compiled imports it at once, and concurrent first builds are serialised by an
``flock`` that dies with its holder). :func:`load` returns the module, or None where that is not possible (no
compiler, ``SPIKENERF_VM_KERNEL=0``, the source missing from the installation): callers then use
``grid_sample``. Also :func:`cpu_has`, the CPU's feature flags.
"""

from __future__ import annotations

import contextlib
import functools
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
from importlib import resources
from pathlib import Path
from typing import Any

try:
    import fcntl
except ImportError:  # pragma: no cover - not on Unix: no build lock
    fcntl = None  # type: ignore[assignment]

_MODULE: Any = None
_FAILED = False
#: the kernel's C++ source, shipped in this package (``pyproject.toml`` package-data)
SOURCE_FILE = "vm_cpu.cpp"


@functools.cache
def kernel_source() -> str:
    """The C++ text of the kernel, :data:`SOURCE_FILE` beside this module, read once (OSError where the
    installation lacks it). The build folder's name hashes this text (:func:`_name`): any change to it
    builds anew."""
    return resources.files(__package__).joinpath(SOURCE_FILE).read_text(encoding="utf-8")


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


def _name(
    cflags: list[str], ldflags: list[str], source: str | None = None, prefix: str = "spikenerf_vm_"
) -> str:
    """One build folder per source (default :func:`kernel_source`), flags (the OpenMP library's path
    included) and CPU."""
    source = kernel_source() if source is None else source
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
    names = ("forward", "forward_until", "backward", "march")
    return module if all(hasattr(module, name) for name in names) else None


def _build(cflags: list[str], ldflags: list[str]) -> Any:
    """Load the cached module, or compile it (:func:`kernel_source`), with these extra flags; None when
    another process's build held the build lock for :data:`BUILD_WAIT_S` seconds.

    Under our own ``flock`` (:func:`_build_lock`): a compiled ``.so`` is imported at once, without torch's
    build machinery; otherwise torch's own ``lock`` file is removed first (no live spikenerf process can be
    building this folder while we hold the flock, so it is stale, or, with torch ≥ 2.14, simply left in
    place after every build) and the module is built with ``load_inline``.
    """
    from torch.utils.cpp_extension import _get_build_directory, load_inline

    source = kernel_source()
    name = _name(_CFLAGS + cflags, ldflags, source)
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
            name, cpp_sources=[source], extra_cflags=_CFLAGS + cflags, extra_ldflags=ldflags, with_cuda=False
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


def load() -> Any:
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
    try:
        kernel_source()
    except OSError as err:  # a broken installation: grid_sample, as without a compiler
        warnings.warn(
            f"VM CPU kernel: its C++ source {SOURCE_FILE} is missing from the installation "
            f"({type(err).__name__}): using grid_sample, which is slower on a CPU (reinstall spikenerf)",
            stacklevel=2,
        )
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
