"""Ctrl-C at an awkward moment, and output paths without a name of their own (docs/reliability.md).

An interrupt inside a library's constructor is still one line; one between the two renames of a folder swap
loses nothing (one as a temporary is made: tests/test_core.py).
``--out .`` and ``--out X/..`` name the folder itself: the work folder and the retired copy of a replacement
go beside it, never inside it, and the folder the shell stands in is never swapped away.
"""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from spikenerf.cli import main
from spikenerf.core.atomic import atomic_path
from spikenerf.core.marker import MARKER
from spikenerf.core.replacement import retire

SIM = ["simulate", "--scene", "analytic-orbs", "--width", "8", "--height", "8", "--frames", "20",
       "--test-views", "1", "--blur-fps", "0", "--no-progress"]  # fmt: skip

#: Ctrl-C lands inside imageio's PNG writer's ``__init__``, before it sets the attribute its ``__del__``
#: reads (its optional ``pillow_heif`` import is where it spends most of that time)
PROBE = """
import sys, types
import numpy as np
from spikenerf.camera.io import write_dat
from spikenerf.cli import main

fake = types.ModuleType("pillow_heif")
def interrupt(name):
    raise KeyboardInterrupt
fake.__getattr__ = interrupt
sys.modules["pillow_heif"] = fake
dat = sys.argv[1] + "/s.dat"
write_dat(dat, (np.random.default_rng(0).random((50, 8, 8)) < 0.3).astype(np.uint8))
main(["reconstruct", dat, "--method", "tfp", "--window", "5", "--frame", "10", "--width", "8", "--height",
      "8", "--out", sys.argv[1] + "/f.png"])
"""


def test_ctrl_c_inside_a_librarys_constructor_is_still_one_line(tmp_path: Path) -> None:
    """The half-built writer's ``__del__`` raised AttributeError, printed as a traceback after the line."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    done = subprocess.run(
        [sys.executable, "-c", PROBE, str(tmp_path)], env=env, capture_output=True, text=True
    )
    assert done.returncode == 130
    assert done.stderr.split() == ["spikenerf:", "aborted"], done.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.dat"]


#: Ctrl-C after the command has printed its result, while Python shuts down (an atexit handler runs)
LATE = """
import atexit, os, signal, sys
atexit.register(lambda: os.kill(os.getpid(), signal.SIGINT))
sys.argv = ["spikenerf", "simulate", "--list-scenes"]
from spikenerf.cli import main
main()
"""


def test_ctrl_c_while_python_shuts_down_ends_by_the_signal_without_a_line() -> None:
    """It printed "Exception ignored in atexit callback" and a KeyboardInterrupt traceback, and exited 0."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    done = subprocess.run([sys.executable, "-c", LATE], env=env, capture_output=True, text=True)
    assert done.returncode == -signal.SIGINT, (done.returncode, done.stderr)
    assert done.stderr == "" and "analytic-orbs" in done.stdout  # (flushed before the signal ends it)


def test_an_in_process_call_keeps_the_callers_ctrl_c_handler(capsys) -> None:  # type: ignore[no-untyped-def]
    before = signal.getsignal(signal.SIGINT)
    main(["simulate", "--list-scenes"])
    assert "analytic-orbs" in capsys.readouterr().out
    assert signal.getsignal(signal.SIGINT) is before is not signal.SIG_DFL


def test_an_interrupt_between_a_folder_swaps_renames_keeps_the_previous_folder(
    tmp_path: Path, monkeypatch
) -> None:  # type: ignore[no-untyped-def]
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "old.txt").write_text("previous")
    real, calls = Path.rename, []

    def rename(self: Path, target):  # type: ignore[no-untyped-def]
        calls.append(self.name)
        if len(calls) == 2:  # the finished folder's rename into place: Ctrl-C just before it
            raise KeyboardInterrupt
        return real(self, target)

    with pytest.raises(KeyboardInterrupt), atomic_path(tmp_path / "out") as tmp:
        tmp.mkdir()
        (tmp / "new.txt").write_text("new")
        monkeypatch.setattr(Path, "rename", rename)
    monkeypatch.undo()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    assert (tmp_path / "out" / "old.txt").read_text() == "previous"


def test_a_folder_that_cannot_be_moved_away_stays_unretired(tmp_path: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """A mount point cannot be renamed (EBUSY): the folder stayed, marked retired, as if swapped out."""
    out = tmp_path / "ds"
    out.mkdir()
    (out / MARKER).write_text(json.dumps({"kind": "dataset", "files": []}) + "\n")

    def busy(self: Path, target):  # type: ignore[no-untyped-def]
        raise OSError(errno.EBUSY, "Device or resource busy", str(self))

    monkeypatch.setattr(Path, "rename", busy)
    with pytest.raises(OSError, match="busy"):
        retire(out)
    assert json.loads((out / MARKER).read_text()) == {"kind": "dataset", "files": []}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("dot") / "ds"
    main([*SIM, "--out", str(out)])
    return out


def _refused(capsys, args: list[str], said: str) -> None:  # type: ignore[no-untyped-def]
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit_:
        main(args)
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.count("\n") == 1 and said in err, err


def test_out_dot_in_an_empty_folder_is_refused_in_one_line(capsys, tmp_path: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """``--out .`` crashed with a traceback (``PosixPath('.') has an empty name``)."""
    monkeypatch.chdir(tmp_path)
    _refused(capsys, [*SIM, "--out", "."], "--out: is the current folder")
    assert list(tmp_path.iterdir()) == [] and not tmp_path.with_name(tmp_path.name + ".partial").exists()


def test_the_dataset_the_shell_stands_in_is_not_replaced(capsys, dataset: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """``cd DS/test; simulate --out .. --overwrite`` wrote its work folder into DS/test, marked DS retired
    and then failed (the current folder's parent cannot be renamed)."""
    before = sorted(str(p.relative_to(dataset)) for p in dataset.rglob("*"))
    marker = (dataset / MARKER).read_text()
    for where, out in ((dataset / "test", ".."), (dataset, ".")):
        monkeypatch.chdir(where)
        _refused(capsys, [*SIM, "--overwrite", "--out", out], "--out: is the current folder or holds it")
    assert sorted(str(p.relative_to(dataset)) for p in dataset.rglob("*")) == before
    assert (dataset / MARKER).read_text() == marker


def test_out_ending_in_dotdot_replaces_the_folder_it_names(dataset: Path, tmp_path: Path) -> None:
    """``--out DS/test/.. --overwrite`` put ``DS/test/...partial`` inside the dataset, then failed."""
    copy = tmp_path / "ds"
    main([*SIM, "--out", str(copy)])
    main([*SIM, "--overwrite", "--out", str(copy / "test" / "..")])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]
    names = [sorted(p.name for p in (folder / "test").iterdir()) for folder in (copy, dataset)]
    assert names[0] == names[1]
    assert "retired" not in json.loads((copy / MARKER).read_text())


def test_a_simulated_datasets_marker_lists_only_the_files_it_holds(dataset: Path) -> None:
    """The list was taken before the frame cache was deleted: it named 20 ``.frames/*.npy`` files that the
    published dataset does not hold (and ``--overwrite`` would have deleted a user's files of those names)."""
    listed = json.loads((dataset / MARKER).read_text())["files"]
    assert listed and all((dataset / name).exists() for name in listed), [
        n for n in listed if not (dataset / n).exists()
    ][:3]


#: the smallest benchmark (a 16 px dataset of 40 steps, one cell of 2 iterations, no renders: ~15 s)
BENCH = ["--quiet", "--threads", "1", "benchmark", "--scenes", "analytic-orbs", "--methods", "nerf-gt",
         "--color", "gray", "--size", "16", "--frames", "40", "--iters", "2", "--test-views", "1",
         "--no-render", "--device", "cpu", "--set", "batch=64", "--out"]  # fmt: skip


def test_a_benchmarks_records_name_its_folder_from_any_folder(capsys, tmp_path: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """``--out .`` and ``--out X/..`` stand for the real path (``OutPath``), and a plain relative ``--out b``
    is made absolute too: it recorded ``b``, ``b/datasets/...`` and ``b/runs/...`` in results.json's config
    and commands, the dataset's config.yaml and the report's commands, wrong read from any other folder."""
    from helpers import run_cli

    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    assert run_cli(capsys, *BENCH, "b")[0] == 0
    out = work / "b"

    def recorded() -> tuple[dict, list[str]]:
        results = json.loads((out / "results.json").read_text())
        commands = [
            *results["commands"]["datasets"].values(),
            *results["commands"]["cells"]["analytic-orbs/gray/nerf-gt"],
        ]
        return results, [arg for command in commands for arg in command if "/" in arg]

    results, paths = recorded()
    assert results["config"]["out"] == str(out)
    assert len(paths) == 4 and all(p.startswith(f"{out}/") for p in paths), paths  # simulate, train, eval
    assert (
        f"--out {out}/datasets/analytic-orbs"
        in (out / "datasets" / "analytic-orbs" / "config.yaml").read_text()
    )
    assert " b/" not in (out / "report.html").read_text()
    # resumed from other folders, through `..` and `.`: the same folder and records, nothing run again
    for where, given in ((tmp_path, "work/b/runs/.."), (out, ".")):
        monkeypatch.chdir(where)
        assert run_cli(capsys, *BENCH, given)[0] == 0
        results, again = recorded()
        assert (
            results["config"]["out"] == str(out) and again == paths and results["commands"]["this_run"] == []
        )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["work"] and sorted(
        p.name for p in work.iterdir()
    ) == ["b"]
