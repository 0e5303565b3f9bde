"""Compile the Triton VM-lookup kernels for a GPU architecture without a GPU; print registers and spills.

Usage (from the repository root; ``triton`` installed, ``TRITON_INTERPRET`` unset)::

    .venv/bin/python -m benchmarks.tools.triton_compile_report [--arch 90] [--warps W] [--block B]
        [--channels 16,24] [--kernels vm,volume,march]

Each kernel of ``fields/vm_triton_kernels.py`` (forward, backward, point: the points' gradient) is compiled
by Triton's own compiler and the bundled ``ptxas`` to a cubin for ``sm_<arch>`` (90: H100/H200), with the
points and warps a program that ``vm_triton.LAUNCH`` launches it with (or ``--block``, ``--warps``), summed
for 16 channels (the density) and per channel for the others (24: the appearance), with float32 pointers
16-byte aligned as torch allocates them. Printed per variant: registers a thread, stack and local bytes
(spilled registers; 0 is wanted) and shared memory, from ``cuobjdump -res-usage``. A compile error fails the
run (exit 1). What the GPU then does with them (speed) is ``bench_lookup``'s to measure. ``--kernels
volume`` (in the default list) compiles the compositing kernels of ``render/volume_triton_kernels.py`` too,
as ``volume_triton.LAUNCH`` launches them (its own block and warps; segment sums of 2 and 3 columns: the
renderer's opacity and depth, and its colours), and ``--kernels march`` (also in the default list) the march
kernels of ``render/march_triton_kernels.py`` as ``march_triton.LAUNCH`` launches them.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path


def compile_variants(arch: int, warps: int | None, block: int | None, channels: list[int]) -> list[dict]:
    """One row per (kernel, channel count): its name, summed, channels, block, warps (``None``: the
    kernel's ``vm_triton.LAUNCH``) and the resource usage fields (``REG``, ``STACK``, ``LOCAL``,
    ``SHARED``) as ints."""
    if os.environ.get("TRITON_INTERPRET", "0") == "1":
        raise SystemExit("triton_compile_report: unset TRITON_INTERPRET (the interpreter does not compile)")
    import triton
    from triton.backends.compiler import GPUTarget
    from triton.compiler import ASTSource

    from spikenerf.fields import vm_triton_kernels as kernels
    from spikenerf.fields.vm_triton import LAUNCH

    tools = Path(triton.__file__).parent / "backends" / "nvidia" / "bin"
    aligned = [["tt.divisibility", 16]]
    pointers = {
        "forward": ["P", "L", "X", "OUT"],
        "backward": ["P", "L", "X", "G", "GP", "GL"],
        "point": ["P", "L", "X", "G", "GX"],  # the points' gradient (pose refinement)
    }
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, ptrs in pointers.items():
            kernel = getattr(kernels, f"{name}_kernel")
            names = kernel.arg_names
            block_k, warps_k = block or LAUNCH[name][0], warps or LAUNCH[name][1]
            for c in channels:
                summed = c == 16
                values = {"channels": c, "SUMMED": summed, "BLOCK": block_k, "CP": triton.next_power_of_2(c)}
                declared = {names[i] for i in kernel.constexprs}  # as the kernel declares them
                consts = {k: v for k, v in values.items() if k in declared}
                signature = {
                    n: "constexpr" if n in consts else "*fp32" if n in ptrs else "i32" for n in names
                }
                attrs = {(names.index(p),): aligned for p in ptrs}
                if "channels" not in declared and c % 16 == 0:  # a runtime int: as Triton specialises it
                    attrs[(names.index("channels"),)] = aligned
                source = ASTSource(fn=kernel, signature=signature, constexprs=consts, attrs=attrs)
                done = triton.compile(
                    source, target=GPUTarget("cuda", arch, 32), options={"num_warps": warps_k}
                )
                cubin = Path(tmp) / f"{name}{c}.cubin"
                cubin.write_bytes(done.asm["cubin"])
                usage = subprocess.run([str(tools / "cuobjdump"), "-res-usage", str(cubin)], check=True,
                                       capture_output=True, text=True).stdout  # fmt: skip
                fields = dict(re.findall(r"\b(REG|STACK|SHARED|LOCAL):(\d+)", usage))
                rows.append(
                    {
                        "kernel": name,
                        "summed": summed,
                        "channels": c,
                        "block": block_k,
                        "warps": warps_k,
                        **{k: int(v) for k, v in fields.items()},
                    }
                )
    return rows


def compile_volume(arch: int) -> list[dict]:
    """One row per compositing kernel (``segment_sum`` for 2 and 3 columns), as :func:`compile_variants`."""
    from spikenerf.render import volume_triton
    from spikenerf.render import volume_triton_kernels as kernels

    block, warps = volume_triton.LAUNCH["BLOCK"], volume_triton.LAUNCH["num_warps"]
    variants = [
        ("depth_before", ["TAU", "OUT"], {}),
        ("depth_before_backward", ["TAU", "G", "OUT"], {}),
        ("segment_sum", ["VAL", "OUT"], {"K": 2, "KP": 2}),
        ("segment_sum", ["VAL", "OUT"], {"K": 3, "KP": 4}),
    ]
    rows = []
    for name, floats, extra in variants:
        kernel = getattr(kernels, f"{name}_kernel")
        types = {**dict.fromkeys(floats, "*fp32"), "OFF": "*i64"}
        usage = _usage(kernel, types, {"BLOCK": block, **extra}, arch, warps, default="fp32")
        rows.append({"kernel": name, "columns": extra.get("K", ""), **usage})
    return rows


def compile_march(arch: int) -> list[dict]:
    """One row per march kernel (the count with and without the occupancy test, the write), as
    :func:`compile_variants`."""
    from spikenerf.render import march_triton
    from spikenerf.render import march_triton_kernels as kernels

    block, warps = march_triton.LAUNCH["BLOCK"], march_triton.LAUNCH["num_warps"]
    types = {**dict.fromkeys(("O", "D", "NEAR", "FAR"), "*fp32"), "GRID": "*u8", "step": "fp32"}
    types |= dict.fromkeys(("COUNT", "KEPT", "FIRST", "RAY", "K"), "*i64")
    rows = []
    for name, occupancy in (("count", True), ("count", False), ("write", True), ("write", False)):
        usage = _usage(
            getattr(kernels, f"{name}_kernel"),
            types,
            {"BLOCK": block, "OCC": occupancy},
            arch,
            warps,
            default="i32",
            fusion=False,
        )  # fmt: skip  (as march_triton launches them)
        rows.append({"kernel": name, "occupancy": occupancy, **usage})
    return rows


def _usage(kernel, types: dict[str, str], consts: dict, arch: int, warps: int, default: str,  # type: ignore[no-untyped-def]
           fusion: bool = True) -> dict:  # fmt: skip
    """Resource usage (``REG``, ``STACK``, ``LOCAL``, ``SHARED``: ints) of ``kernel`` compiled for
    ``sm_<arch>`` with ``consts``, its other arguments typed by ``types`` (else ``default``), pointers
    16-byte aligned, with floating-point contraction or (``fusion`` False) without."""
    import triton
    from triton.backends.compiler import GPUTarget
    from triton.compiler import ASTSource

    names = kernel.arg_names
    signature = {n: "constexpr" if n in consts else types.get(n, default) for n in names}
    attrs = {(names.index(n),): [["tt.divisibility", 16]] for n, t in types.items()
             if t.startswith("*") and n in names}  # fmt: skip
    source = ASTSource(fn=kernel, signature=signature, constexprs=consts, attrs=attrs)
    options = {"num_warps": warps, "enable_fp_fusion": fusion}
    done = triton.compile(source, target=GPUTarget("cuda", arch, 32), options=options)
    tools = Path(triton.__file__).parent / "backends" / "nvidia" / "bin"
    with tempfile.TemporaryDirectory() as tmp:
        cubin = Path(tmp) / "kernel.cubin"
        cubin.write_bytes(done.asm["cubin"])
        usage = subprocess.run([str(tools / "cuobjdump"), "-res-usage", str(cubin)], check=True,
                               capture_output=True, text=True).stdout  # fmt: skip
    return {k: int(v) for k, v in re.findall(r"\b(REG|STACK|SHARED|LOCAL):(\d+)", usage)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--arch", type=int, default=90, help="compute capability × 10 (90: H100/H200)")
    parser.add_argument("--warps", type=int, help="warps a program (default: each kernel's vm_triton.LAUNCH)")
    parser.add_argument(
        "--block", type=int, help="points a program (default: each kernel's vm_triton.LAUNCH)"
    )
    parser.add_argument("--channels", default="16,24")
    parser.add_argument(
        "--kernels", default="vm,volume,march", help="vm (the lookups), volume (compositing), march"
    )
    args = parser.parse_args()
    which = set(args.kernels.split(","))
    if "vm" in which:
        rows = compile_variants(args.arch, args.warps, args.block, [int(c) for c in args.channels.split(",")])
        print(f"sm_{args.arch}, points and warps a program as each row says")
        print("| kernel | channels | registers | stack B | local B (spills) | shared B | points × warps |")
        print("|---|---:|---:|---:|---:|---:|---|")
        for r in rows:
            label = f"{r['channels']}{' summed' if r['summed'] else ''}"
            usage = f"{r['REG']} | {r['STACK']} | {r['LOCAL']} | {r['SHARED']}"
            print(f"| {r['kernel']} | {label} | {usage} | {r['block']} × {r['warps']} |")
    if "volume" in which:
        rows = [(r["kernel"], str(r["columns"]), r) for r in compile_volume(args.arch)]
        _table(
            f"compositing kernels, sm_{args.arch} (volume_triton.LAUNCH)",
            "compositing kernel | columns",
            rows,
        )
    if "march" in which:
        rows = [(r["kernel"], "yes" if r["occupancy"] else "no", r) for r in compile_march(args.arch)]
        _table(f"march kernels, sm_{args.arch} (march_triton.LAUNCH)", "march kernel | occupancy", rows)


def _table(title: str, columns: str, rows: list[tuple[str, str, dict]]) -> None:
    """Print ``title`` and a table of (kernel, second column, resource usage) rows."""
    print(f"\n{title}\n| {columns} | registers | stack B | local B (spills) | shared B |")
    print("|---|---|---:|---:|---:|---:|")
    for kernel, second, usage in rows:
        print(
            f"| {kernel} | {second} | "
            + " | ".join(str(usage[k]) for k in ("REG", "STACK", "LOCAL", "SHARED"))
            + " |"
        )


if __name__ == "__main__":
    sys.exit(main())
