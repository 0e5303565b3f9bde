"""One entry point for the performance benchmarks: every row compares ours with a reference in the same run.

    .venv/bin/python -m benchmarks.suites.run_all        # camera + fields (minutes on 2 cores)
    .venv/bin/python -m benchmarks.suites.run_all --all  # + time-to-PSNR grid vs mlp (+ Blender if installed)

Results are recorded in docs/performance.md.
"""

from __future__ import annotations

import argparse
import importlib
import platform

import torch

from benchmarks._table import Row, format_table

SUITES = {
    "dat": "benchmarks.suites.bench_dat",
    "simulator": "benchmarks.suites.bench_simulator",
    "fields": "benchmarks.suites.bench_fields",
    "learned-recon": "benchmarks.experiments.bench_learned_recon",
}
SLOW_SUITES = {"time-to-psnr": "benchmarks.suites.bench_time_to_psnr"}


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--all", action="store_true", help="also run the slow suites (training to a PSNR)")
    parser.add_argument("--only", choices=[*SUITES, *SLOW_SUITES], action="append", help="run only these")
    args = parser.parse_args()
    suites = {**SUITES, **(SLOW_SUITES if args.all else {})}
    if args.only:
        suites = {k: v for k, v in {**SUITES, **SLOW_SUITES}.items() if k in args.only}
    device = torch.cuda.get_device_name(0) if torch.cuda.is_available() else "no GPU"
    threads = torch.get_num_threads()
    print(f"python {platform.python_version()}, torch {torch.__version__}, {threads} threads, {device}")
    rows: list[Row] = []
    for name, module_name in suites.items():
        print(f"running {name} …", flush=True)
        rows += importlib.import_module(module_name).measure()
    print(format_table(rows))


if __name__ == "__main__":
    main()
