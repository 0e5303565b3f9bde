"""What spikenerf did not write stays as it is: lock files that are not ours, temporaries that are not ours,
folders that only look like runs, outputs nested inside datasets; and a run's own state stays honest
(another run's checkpoint, a diverged run, a refused setup, a moved dataset, a stale metrics.json)."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
from pathlib import Path

import pytest

from helpers import run_cli
from spikenerf.cli import main
from spikenerf.core.atomic import clean_stale_temps
from spikenerf.core.errors import InputError
from spikenerf.core.lock import lock_path, output_lock
from spikenerf.core.marker import check_output, mark

TRAIN = [
    "--iters",
    "4",
    "--batch",
    "64",
    "--eval-every",
    "0",
    "--eval-views",
    "1",
    "--device",
    "cpu",
    "--quiet",
]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("safety") / "ds"
    main(["simulate", "--scene", "analytic-orbs", "--width", "16", "--height", "16", "--frames", "60",
          "--test-views", "1", "--blur-fps", "0", "--no-progress", "--out", str(root)])  # fmt: skip
    return root


def test_a_lock_path_that_is_a_link_or_a_users_file_is_refused_and_left_alone(tmp_path: Path) -> None:
    precious = tmp_path / "precious.txt"
    precious.write_text("my thesis")
    link = lock_path(tmp_path / "a")
    link.symlink_to(precious)
    with pytest.raises(InputError, match="symbolic link"), output_lock(tmp_path / "a"):
        pass
    notes = lock_path(tmp_path / "b")
    notes.write_text("my notes about locks\n")
    with pytest.raises(InputError, match="not spikenerf's lock file"), output_lock(tmp_path / "b"):
        pass
    assert precious.read_text() == "my thesis" and link.is_symlink() and notes.read_text().startswith("my")
    stale = lock_path(tmp_path / "c")
    stale.write_text("999999\n")  # a killed writer's lock: taken over, and removed after
    with output_lock(tmp_path / "c") as held:
        assert held.read_text() == f"{os.getpid()}\n"
    assert not stale.exists()


def test_only_our_temporaries_are_removed(tmp_path: Path) -> None:
    ours = [".checkpoint.pt.k2m9q0zz.tmp", ".render.x8_41abq.old.tmp"]
    theirs = [".draft.tmp", ".cache.tmp", ".notes.short.tmp", "x.abcdefgh.tmp"]
    for name in ours + theirs:
        (tmp_path / name).write_text("x")
    assert sorted(clean_stale_temps(tmp_path)) == sorted(ours)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(theirs)


def test_an_empty_folder_the_user_added_to_a_dataset_is_not_replaced(tmp_path: Path) -> None:
    ours = tmp_path / "ds"
    (ours / "cache").mkdir(parents=True)  # an empty folder our writer left: listed, replaced with the rest
    (ours / "config.yaml").write_text("x")
    mark(ours, "dataset", files=True)
    check_output(ours, "dataset", overwrite=True, replace=True)
    (ours / "notes").mkdir()  # the user's, empty: --overwrite would delete it
    with pytest.raises(InputError, match=r"did not write \(notes/\)"):
        check_output(ours, "dataset", overwrite=True, replace=True)
    old = tmp_path / "old"  # a marker from before empty folders were listed: they are not counted
    (old / "notes").mkdir(parents=True)
    (old / "config.yaml").write_text("x")
    (old / ".spikenerf").write_text(json.dumps({"kind": "dataset", "files": ["config.yaml"]}))
    check_output(old, "dataset", overwrite=True, replace=True)
    mark(old, "dataset", ["config.yaml", "preview.png"])  # extending an old list keeps its meaning
    check_output(old, "dataset", overwrite=True, replace=True)


def test_a_folder_that_only_looks_like_a_run_keeps_its_files(capsys, dataset: Path, tmp_path: Path) -> None:
    mine = tmp_path / "project"
    (mine / ".cache.k2m9q0zz.tmp").mkdir(parents=True)  # even one named as ours: no marker, not ours
    (mine / ".cache.k2m9q0zz.tmp" / "data").write_text("precious")
    (mine / "config.yaml").write_text("lr: 1\n")
    (mine / "checkpoint.pt").write_text("notes")
    code, _, err = run_cli(capsys, "train", dataset, *TRAIN, "--out", mine)
    assert code == 2 and "already holds a training run" in err, err
    assert (mine / ".cache.k2m9q0zz.tmp" / "data").read_text() == "precious"


def test_outputs_are_not_nested_in_a_dataset_but_renders_live_in_runs(tmp_path: Path) -> None:
    for kind in ("dataset", "run", "benchmark", "render"):
        (tmp_path / kind).mkdir()
        mark(tmp_path / kind, kind)
    with pytest.raises(InputError, match="lies inside the dataset folder"):
        check_output(tmp_path / "dataset" / "runs" / "r1", "run")
    with pytest.raises(InputError, match="lies inside the run folder"):
        check_output(tmp_path / "run" / "sub", "run")
    check_output(tmp_path / "run" / "render", "render")
    for kind in ("dataset", "run", "render"):
        check_output(tmp_path / "benchmark" / "x" / kind, kind)
    check_output(tmp_path / "render" / "file", "render")  # a render beside another's views
    check_output(tmp_path / "render" / "frames", "frames")  # reconstruct of a render's novel spike stream
    check_output(tmp_path / "dataset" / ".." / "dataset", "dataset", overwrite=True)  # the folder itself
    (tmp_path / "link").symlink_to(tmp_path / "dataset")
    with pytest.raises(InputError, match="lies inside the dataset folder"):
        check_output(tmp_path / "link" / "runs" / "r1", "run")


def test_resume_refuses_another_runs_checkpoint(capsys, dataset: Path, tmp_path: Path) -> None:
    a, b = tmp_path / "a", tmp_path / "b"
    assert run_cli(capsys, "train", dataset, *TRAIN, "--seed", "1", "--out", a)[0] == 0
    assert run_cli(capsys, "train", dataset, *TRAIN, "--out", b)[0] == 0
    shutil.copy(a / "checkpoint.pt", b / "checkpoint.pt")
    code, _, err = run_cli(capsys, "train", dataset, *TRAIN[:1], "8", *TRAIN[2:], "--resume", "--out", b)
    assert code == 2 and "belongs to another run: seed 1" in err, err


def test_a_diverged_run_stops_in_one_line_and_checkpoints_nothing(
    capsys, dataset: Path, tmp_path: Path
) -> None:
    run = tmp_path / "run"
    code, _, err = run_cli(capsys, "train", dataset, *TRAIN, "--log-every", "2", "--lr", "1e30", "--out", run)
    assert code == 2 and err.count("\n") == 1 and "training diverged by iteration 2" in err, err
    assert "no checkpoint was written: lower --lr" in err and not (run / "checkpoint.pt").exists()


def test_a_refused_setup_leaves_no_folder(capsys, dataset: Path, tmp_path: Path) -> None:
    out = tmp_path / "new" / "run"
    code, _, err = run_cli(capsys, "train", dataset, *TRAIN, "--method", "nerf-recon", "--recon", "learned",
                           "--holdout", "--holdout-radius", "100000", "--out", out)  # fmt: skip
    assert code == 2 and "--holdout-radius" in err, err
    assert not (tmp_path / "new").exists()


def test_a_failed_setup_leaves_no_folder(dataset: Path, tmp_path: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """An OSError while setting up (the learned weights gone) left a folder holding only the marker."""
    from spikenerf.train import trainer

    def fails(config, out: Path, *args, **kw):  # type: ignore[no-untyped-def]
        out.mkdir(parents=True, exist_ok=True)  # as a Trainer does before it builds its targets
        mark(out, "run")
        raise OSError("disk gone")

    monkeypatch.setattr(trainer, "Trainer", fails)
    with pytest.raises(SystemExit):  # (the CLI says "spikenerf: error: disk gone")
        main(["train", str(dataset), *TRAIN, "--out", str(tmp_path / "run")])
    assert not (tmp_path / "run").exists()
    (tmp_path / "mine").mkdir()  # the user's empty folder: emptied again, not removed nor left marked
    with pytest.raises(SystemExit):
        main(["train", str(dataset), *TRAIN, "--out", str(tmp_path / "mine")])
    assert (tmp_path / "mine").is_dir() and not any((tmp_path / "mine").iterdir())


def test_a_moved_dataset_resumes_and_a_stale_metrics_file_is_named(
    capsys, dataset: Path, tmp_path: Path
) -> None:
    moved, run = tmp_path / "moved", tmp_path / "run"
    shutil.copytree(dataset, moved)
    assert run_cli(capsys, "train", moved, *TRAIN, "--out", run)[0] == 0
    assert (
        run_cli(capsys, "eval", run, "--device", "cpu", "--lpips", "none", "--noref", "off", "--quiet")[0]
        == 0
    )
    moved.rename(tmp_path / "elsewhere")
    code, _, err = run_cli(capsys, "train", "--resume", "--out", run, "--quiet")  # read only "not found"
    assert code == 2 and "if it moved: spikenerf train NEW_PATH --resume --out" in err, err
    code, _, err = run_cli(capsys, "train", tmp_path / "elsewhere", *TRAIN[:1], "6", *TRAIN[2:], "--resume",
                           "--out", run)  # fmt: skip
    assert code == 0, err
    assert json.loads((run / "summary.json").read_text())["iteration"] == 6
    code, out, err = run_cli(capsys, "info", run)
    assert code == 0 and "[of iteration 4, not 6: run eval again]" in out, out + err


def test_a_folder_with_another_tools_results_json_is_not_a_benchmark(capsys, tmp_path: Path) -> None:
    mine = tmp_path / "results"
    mine.mkdir()
    for name, text in (("results.json", '{"my": "results"}'), ("table2.md", "my notes")):
        (mine / name).write_text(text)
    bench = ["benchmark", "--scenes", "analytic-orbs", "--methods", "nerf-gt", "--color", "gray",
             "--size", "16", "--frames", "60", "--iters", "2"]  # fmt: skip
    code, _, err = run_cli(capsys, *bench, "--out", mine)
    assert code == 2 and "did not write" in err, err
    assert sorted(p.name for p in mine.iterdir()) == ["results.json", "table2.md"]
    assert (mine / "table2.md").read_text() == "my notes"


def test_a_benchmark_refuses_a_dataset_simulated_with_other_settings(dataset: Path, tmp_path: Path) -> None:
    from spikenerf.pipelines.benchmark import BenchmarkConfig
    from spikenerf.pipelines.benchmark.run import _check_datasets, dataset_settings

    shutil.copytree(dataset, tmp_path / "datasets" / "analytic-orbs")
    have = dataset_settings(tmp_path / "datasets" / "analytic-orbs")
    assert (have["size"], have["frames"], have["test_views"], have["colors"]) == ([16, 16], 60, 1, ["gray"])
    base = {"scenes": ["analytic-orbs"], "variants": ["nerf-gt"], "colors": ["gray"], "out": tmp_path,
            "size": 16, "frames": 60, "test_views": 1, "blur_views": have["blur_views"]}  # fmt: skip
    _check_datasets(BenchmarkConfig(**base))  # the same settings: adopted
    for change, flag in (({"size": 24}, "size"), ({"frames": 80}, "frames"), ({"seed": 5}, "seed"),
                         ({"test_views": 2}, "test_views"), ({"colors": ["rgb"]}, "color")):  # fmt: skip
        with pytest.raises(InputError) as err:
            _check_datasets(BenchmarkConfig(**{**base, **change}))
        assert err.value.params == (flag,), (change, err.value.params)


def test_a_cell_whose_metrics_were_deleted_is_scored_again(tmp_path: Path) -> None:
    from spikenerf.pipelines.benchmark import BenchmarkConfig, cell_keys, run_dir
    from spikenerf.pipelines.benchmark.run import forget_unscored
    from spikenerf.pipelines.benchmark.settings import _options
    from spikenerf.pipelines.report_figures import shown_seed

    cfg = BenchmarkConfig(["analytic-orbs"], ["nerf-gt", "spike-nerf"], ["gray"], tmp_path)
    keys = cell_keys(cfg)
    for key in keys:
        (run_dir(cfg, *key) / "render").mkdir(parents=True)
        (run_dir(cfg, *key) / "render" / "render.json").write_text("{}")
    (run_dir(cfg, *keys[0]) / "metrics.json").write_text("{}")
    forget_unscored(cfg, keys)
    assert (run_dir(cfg, *keys[0]) / "render" / "render.json").is_file()
    assert not (run_dir(cfg, *keys[1]) / "render" / "render.json").exists()
    assert _options(["--set", "lr=0.01", "--set", "batch=64"]) == {"--set lr": "0.01", "--set batch": "64"}
    assert shown_seed(cfg) == 0 and shown_seed(dataclasses.replace(cfg, seeds=[3, 4])) == 3
