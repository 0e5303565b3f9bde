"""What several test modules share: running the CLI in-process, and the tiny trainer flags of benchmark tests.

Import it as ``from helpers import ...`` (pytest puts ``tests/`` on ``sys.path``: the folder has no
``__init__.py``)."""

from __future__ import annotations

import ast
import importlib.util
import json
import re
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import pytest

from spikenerf.cli import main

#: ``train`` flags of the tiny benchmarks (``BenchmarkConfig.extra_train_args``): a few rays, one eval view
BENCHMARK_TRAIN = ["--batch", "64", "--eval-every", "2", "--eval-views", "1", "--spike-window", "8",
                   "--spike-pixels", "8"]  # fmt: skip


def run_cli(capsys: pytest.CaptureFixture[str], *args: object) -> tuple[int, str, str]:
    """``spikenerf ARGS`` in this process: (exit code, stdout, stderr)."""
    try:
        main([str(a) for a in args])
        code = 0
    except SystemExit as exit_:
        code = int(exit_.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def assert_refused(call: Callable[[], object], param: str) -> None:
    """``call()`` raises an InputError whose message and ``params`` name ``param`` (a refusal test)."""
    from spikenerf.core.errors import InputError

    with pytest.raises(InputError, match=param) as err:
        call()
    assert param in err.value.params


def refusal_test(cases: list[tuple[str, Callable[[], object], str]]) -> Callable[..., None]:
    """A test over ``cases`` (name, call, parameter): each call is refused naming its parameter
    (:func:`assert_refused`). Bind it to a ``test_…`` name in a test module for pytest to collect it."""

    @pytest.mark.parametrize(("call", "param"), [c[1:] for c in cases], ids=[c[0] for c in cases])
    def test(call: Callable[[], object], param: str) -> None:
        assert_refused(call, param)

    return test


def edit_json(path: Path, change: Callable[[dict], object]) -> Path:
    """``change(meta)`` applied in place to the JSON object of ``path``, written back; returns ``path``."""
    meta = json.loads(path.read_text())
    change(meta)
    path.write_text(json.dumps(meta))
    return path


def write_recording(path: Path, steps: int, height: int, width: int) -> Path:
    """A random 30 % spike recording (``steps``, ``height``, ``width``) at ``path`` with a SpikeCV
    ``config.yaml`` beside it giving its size; returns ``path``."""
    import numpy as np

    from spikenerf.camera.io import write_dat

    write_dat(path, (np.random.default_rng(0).random((steps, height, width)) < 0.3).astype(np.uint8))
    (path.parent / "config.yaml").write_text(f"spike_h: {height}\nspike_w: {width}\n")
    return path


def load_benchmark(name: str) -> ModuleType:
    """``benchmarks/NAME.py`` imported from its file, e.g. ``experiments/bench_refine`` (benchmarks are
    scripts, not part of the wheel)."""
    path = Path(__file__).resolve().parents[1] / "benchmarks" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(f"{Path(name).name}_under_test", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # a dataclass in it looks its module up there
    spec.loader.exec_module(module)
    return module


def triton_device():  # type: ignore[no-untyped-def]
    """Where a test module's Triton kernels run: CUDA, else Triton's CPU interpreter (``TRITON_INTERPRET=1``,
    which ``conftest.py`` sets). Skips the calling module where ``triton`` is missing or neither applies."""
    import torch

    from spikenerf.fields import vm_triton

    pytest.importorskip("triton", reason="the triton package (pip install triton) runs these kernels")
    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if device.type == "cpu" and not vm_triton.interpreted():
        pytest.skip(
            "TRITON_INTERPRET=1 is needed without CUDA (tests/conftest.py sets it)", allow_module_level=True
        )
    return device


def _torch_below(major: int, minor: int) -> bool:
    import torch

    found = tuple(int(part) for part in re.findall(r"\d+", torch.__version__)[:2])
    return found < (major, minor)


#: a test that counts ``torch.compile``'s graphs or graph breaks: Dynamo before torch 2.6 splits the same
#: functions into more graphs (they still train; docs/getting-started.md)
counts_graphs = pytest.mark.skipif(
    _torch_below(2, 6), reason="counts torch.compile graphs: Dynamo before torch 2.6 makes more"
)


def defined_names(source: str, top_level: bool = False) -> set[str]:
    """The names a module's source defines (functions, classes, assigned names), not those it imports: at
    its top level only, or at any depth."""
    tree = ast.parse(source)
    names: set[str] = set()
    for node in tree.body if top_level else ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names.update(n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name))
    return names
