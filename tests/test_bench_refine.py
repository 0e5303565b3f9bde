"""benchmarks/experiments/bench_refine.py's settings: seed and hold-out reach `train`, and never mix in one
run folder."""

from __future__ import annotations

import argparse

import pytest
import yaml

from helpers import load_benchmark


def _bench():  # type: ignore[no-untyped-def]
    return load_benchmark("experiments/bench_refine")


def _args(**kw) -> argparse.Namespace:  # type: ignore[no-untyped-def]
    base = dict(method="nerf-recon", iters=20, batch=64, seed=0, holdout=False, grid_init=8, grid=16)
    return argparse.Namespace(**{**base, "pose_lr": None, "threads": 1, "window_poses": 1, **kw})


def test_run_names_keep_the_first_measurements_and_separate_seeds_and_holdout() -> None:
    name = _bench().run_name
    assert name("orbs", "exact", 0, False) == "run-orbs-exact"  # the old commands find their runs
    names = {name("orbs", "exact", s, h) for s in (0, 1) for h in (False, True)}
    assert len(names) == 4


def test_seed_and_holdout_reach_train_and_other_settings_are_refused(tmp_path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    bench = _bench()
    calls: list[list[str]] = []
    monkeypatch.setattr(bench.subprocess, "run", lambda cmd, check: calls.append(cmd))
    run, data = tmp_path / "run", tmp_path / "sim"
    a = _args(seed=3, holdout=True)
    bench.train(data, run, a, refine=False, check_steps=7)
    cmd = calls[-1]
    assert cmd[cmd.index("--seed") + 1] == "3" and "--holdout" in cmd
    assert cmd[cmd.index("--holdout-steps") + 1] == "7"
    bench.train(data, run, _args(), refine=True)
    assert "--no-holdout" in calls[-1] and calls[-1][calls[-1].index("--seed") + 1] == "0"

    # a run folder whose config.yaml (as `train` writes it) has other settings: one line, exit
    run.mkdir()
    config = {"dataset": str(data), "method": "nerf-recon", "iters": 20, "batch": 64, "seed": 3,
              "holdout": True, "holdout_steps": 7, "poses": {"refine": False},
              "field_config": {"n_voxels_init": 8**3, "n_voxels_final": 16**3}}  # fmt: skip
    (run / "config.yaml").write_text(yaml.safe_dump(config))
    bench.train(data, run, a, refine=False, check_steps=7)  # the same settings: resumes
    assert "--resume" not in calls[-1]  # (no checkpoint here)
    others = (_args(seed=1, holdout=True), _args(seed=3), _args(seed=3, holdout=True, iters=40),
              _args(seed=3, holdout=True, window_poses=8))  # fmt: skip
    for other in others:
        with pytest.raises(SystemExit, match=r"made with .*use another --out"):
            bench.train(data, run, other, refine=False, check_steps=7)
    (run / "config.yaml").write_text(yaml.safe_dump({**config, "holdout": None, "seed": 0}))
    bench.train(data, run, _args(), refine=False)  # written before the hold-out existed: same as off
    # written before window-aware targets existed: the same as --window-poses 1, not as 8
    bench.train(data, run, _args(window_poses=1), refine=False)
    assert calls[-1][calls[-1].index("--window-poses") + 1] == "1"
    with pytest.raises(SystemExit, match="made with"):
        bench.train(data, run, _args(window_poses=8), refine=False)


def test_path_views_are_the_true_frames_nearest_the_interior_check_steps(tmp_path) -> None:  # type: ignore[no-untyped-def]
    import json

    import numpy as np

    from spikenerf.cli import main
    from spikenerf.core.color import rgb_to_gray
    from spikenerf.data.dataset import load_dataset

    sim = tmp_path / "sim"
    main(["simulate", "--scene", "analytic-orbs", "--out", str(sim), "--width", "16", "--height", "16",
          "--frames", "60", "--blur-fps", "0", "--test-views", "1", "--no-progress"])  # fmt: skip
    truth = load_dataset(sim)
    run = tmp_path / "run"
    run.mkdir()
    bench = _bench()
    assert bench.path_views(run, truth, "gray") is None  # trained on every step: no held-out path views
    (run / "holdout.json").write_text(json.dumps({"check_steps": [3, 24, 36, 58], "radius": 10}))
    views = bench.path_views(run, truth, "gray")
    assert views.steps.tolist() == [20, 40]  # 24 → 20 and 36 → 40 (gt every 10); the ends are left out
    np.testing.assert_allclose(views.poses[:, 0].numpy(), truth.trajectory.poses[[20, 40]], atol=1e-6)
    (run / "holdout.json").write_text(json.dumps({"check_steps": [3, 24, 36, 58], "radius": 6}))
    assert bench.path_views(run, truth, "gray") is None  # the nearest frames lie 4 steps off: not well inside
    gt = np.asarray(truth.gt.images)[[2, 4]]
    np.testing.assert_allclose(views.images[..., 0].numpy(), rgb_to_gray(gt, channel_axis=-1), atol=1e-3)


def test_bench_axes_turns_the_world_and_keeps_the_images(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """benchmarks/experiments/bench_axes.py's turned copy: every pose (trajectory, gt, test views) turned
    about +Z and shrunk about the origin, near/far shrunk with it, the spikes and images untouched."""
    import numpy as np

    from spikenerf.cli import main
    from spikenerf.data.dataset import load_dataset

    sim = tmp_path / "sim"
    main(["simulate", "--scene", "analytic-blocks", "--out", str(sim), "--width", "16", "--height", "16",
          "--frames", "30", "--blur-fps", "0", "--test-views", "1", "--no-progress"])  # fmt: skip
    axes = load_benchmark("experiments/bench_axes")
    copy = axes.turned_copy(sim, tmp_path / "data-rot30" / "sim", 30.0, 0.5)
    before, after = load_dataset(sim), load_dataset(copy)
    c, s = np.cos(np.radians(30)), np.sin(np.radians(30))
    turn = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    for old, new in ((before.trajectory.poses, after.trajectory.poses), (before.test.poses, after.test.poses),
                     (before.gt.poses, after.gt.poses)):  # fmt: skip
        old, new = np.asarray(old), np.asarray(new)
        np.testing.assert_allclose(new[:, :3, :3], turn @ old[:, :3, :3], atol=1e-6)
        np.testing.assert_allclose(new[:, :3, 3], 0.5 * old[:, :3, 3] @ turn.T, atol=1e-6)
    assert (after.near, after.far) == (0.5 * before.near, 0.5 * before.far)
    np.testing.assert_array_equal(after.spikes(), before.spikes())
    np.testing.assert_array_equal(np.asarray(after.test.images), np.asarray(before.test.images))
    assert axes.turned_copy(sim, copy, 45.0, 0.5) == copy  # a finished copy is reused as it is
    assert not (tmp_path / "data-rot30" / "sim.partial").exists()
