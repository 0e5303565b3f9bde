"""The fault suite: bad inputs against every command, table-driven (docs/reliability.md).

Each case runs the CLI in this process and asserts: exit code 2, exactly one line on stderr that names the
flag or file, no traceback, and a sandbox (a tiny dataset, a trained run, foreign files) left byte-for-byte
as it was, with nothing new written (no partial output).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import pickle
import re
import shutil
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from spikenerf.cli import main
from spikenerf.core.lock import output_lock

SIM = [
    "simulate",
    "--scene",
    "analytic-orbs",
    "--width",
    "16",
    "--height",
    "16",
    "--frames",
    "12",
    "--test-views",
    "1",
    "--no-progress",
]
TINY_GRID = ["--field-option", "n_voxels_init=512", "--field-option", "n_voxels_final=1000"]
TRAIN = [
    "--iters",
    "2",
    "--batch",
    "32",
    "--eval-every",
    "0",
    "--eval-views",
    "1",
    "--spike-warmup",
    "1",
    "--spike-window",
    "4",
    "--spike-pixels",
    "4",
    "--device",
    "cpu",
    "--quiet",
    "--ignore-unused",  # (the spike flags serve the spike-nerf cases)
    *TINY_GRID,
]
#: the slowest case seen, in seconds (reported in docs/reliability.md; the issue asks for ≤ 2 s)
TIMES: dict[str, float] = {}


class Evil:
    """A pickle whose loading would create the file named in ``PWNED`` (it must never be loaded)."""

    def __reduce__(self) -> tuple:
        return (Path.touch, (Path(PWNED[0]),))


PWNED: list[str] = [""]


def _cli(*args: object) -> None:
    main([str(a) for a in args])


def _tree(root: Path) -> dict[str, str]:
    """Every path under ``root`` with a hash of its bytes ('dir' for folders)."""
    return {
        str(p.relative_to(root)): "dir" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
    }


@pytest.fixture(scope="module")
def sandbox(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A dataset, a trained run, a second (different) dataset and foreign or broken files, built once."""
    root = tmp_path_factory.mktemp("faults")
    _cli(*SIM, "--frames", "40", "--out", root / "ds")
    _cli("train", root / "ds", *TRAIN, "--out", root / "run")
    _cli(*SIM, "--width", "12", "--height", "12", "--out", root / "other_ds")
    (root / "afile").write_text("a regular file\n")
    (root / "thesis").mkdir()
    (root / "thesis" / "thesis.tex").write_text("\\documentclass{article}\n")
    (root / "garbage.json").write_text("{not json")
    (root / "list.json").write_text("[1, 2]")
    (root / "bad.yaml").write_text("a: [1\n  b: :\n")
    (root / "garbage.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 20)
    (root / "trunc.dat").write_bytes(b"\xff" * 33)
    np.save(root / "obj.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    for name, ckpt in (("garbage_ckpt", b"\x00garbage" * 10), ("pickle_ckpt", pickle.dumps(Evil()))):
        (root / name).mkdir()
        shutil.copy(root / "run" / "config.yaml", root / name / "config.yaml")
        (root / name / "checkpoint.pt").write_bytes(ckpt)
    (root / "bad_yaml_run").mkdir()
    shutil.copy(root / "run" / "checkpoint.pt", root / "bad_yaml_run" / "checkpoint.pt")
    (root / "bad_yaml_run" / "config.yaml").write_text("method: [spike-nerf\n")
    for run, metrics in (("bad_metrics_run", '{"split": "test", "views": '),
                         ("odd_metrics_run", '{"split": "test", "views": 2, "mean": ["psnr"]}')):  # fmt: skip
        (root / run).mkdir()
        for name in ("checkpoint.pt", "config.yaml"):
            shutil.copy(root / "run" / name, root / run / name)
        (root / run / "metrics.json").write_text(metrics)
    seq = root / "seq"
    seq.mkdir()
    pose = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]
    frames = [{"file_path": "a.png", "transform_matrix": pose}]
    (seq / "transforms.json").write_text(json.dumps({"camera_angle_x": 0.7, "frames": frames}))
    shutil.copy(root / "ds" / "test" / "00000.png", seq / "a.png")
    bad_ds = root / "bad_ds"
    shutil.copytree(root / "ds", bad_ds)
    (bad_ds / "spikes_gray.dat").write_bytes((bad_ds / "spikes_gray.dat").read_bytes()[:-5])
    yaml_ds = root / "yaml_ds"
    shutil.copytree(root / "ds", yaml_ds)
    (yaml_ds / "config.yaml").write_text("spike_h: [16\n")
    png_ds = root / "png_ds"
    shutil.copytree(root / "ds", png_ds)
    (png_ds / "test" / "00000.png").write_bytes(b"\x89PNG\r\n\x1a\nbroken")
    json_ds = root / "json_ds"
    shutil.copytree(root / "ds", json_ds)
    (json_ds / "transforms.json").write_text('{"frames": 3}')
    _round_two(root)
    _round_three(root)
    _round_four(root)
    _round_five(root)
    PWNED[0] = str(root / "PWNED")
    return root


def _round_four(root: Path) -> None:
    """Damaged records: render folders whose ``render.json`` lists no file names or a wrong size, a one-line
    curves.csv."""
    _cli("render", root / "run", "--device", "cpu", "--quiet", "--out", root / "bad_render")
    record = json.loads((root / "bad_render" / "render.json").read_text())
    _cli("render", root / "run", "--spikes", "--device", "cpu", "--quiet", "--out", root / "size_render")
    spiked = json.loads((root / "size_render" / "render.json").read_text())
    assert any(name.endswith(".dat") for name in spiked["files"]["spikes"])
    (root / "size_render" / "render.json").write_text(json.dumps({**spiked, "size": [7, 5]}))
    record["files"]["spikes"] = 5
    (root / "bad_render" / "render.json").write_text(json.dumps(record))
    shutil.copytree(root / "run", root / "line_curves_run")
    (root / "line_curves_run" / "curves.csv").write_text("garbage\n")


def _round_five(root: Path) -> None:
    """The hostile-input audit: folders where a run's files go, a dataset whose config.yaml says topdown."""
    shutil.copytree(root / "run", root / "dir_metrics_run")
    (root / "dir_metrics_run" / "metrics.json").mkdir()
    shutil.copytree(root / "run", root / "dir_curves_run")
    (root / "dir_curves_run" / "curves.csv").unlink()
    (root / "dir_curves_run" / "curves.csv").mkdir()
    shutil.copytree(root / "ds", root / "topdown_ds")
    config = root / "topdown_ds" / "config.yaml"
    config.write_text(config.read_text().replace("layout: spikecv", "layout: topdown"))
    assert "layout: topdown" in config.read_text()
    frames = json.loads((root / "ds" / "transforms_test.json").read_text())["frames"]
    for name, cam in (("nan_fov", {"camera_angle_x": float("nan")}), ("text_fov", {"camera_angle_x": "wide"}),
                      ("zero_fov", {"camera_angle_x": 0}), ("neg_fl", {"fl_x": -5.0})):  # fmt: skip
        (root / f"{name}.json").write_text(json.dumps({**cam, "frames": frames}))  # (NaN: JSON's NaN)
    for name, file in (("garbage_summary_run", "summary.json"), ("garbage_marker_run", ".spikenerf")):
        shutil.copytree(root / "run", root / name)
        (root / name / file).write_text("{garbage")
    (root / "empty_dir").mkdir()


def _round_three(root: Path) -> None:
    """The CLI sweep's cases: damaged curves and run configs, a frame step past 64 bits, a user's image."""
    for name, change in (("bad_curves_run", ("curves.csv", "a,b\n1,2,3\n")),
                         ("neg_iters_run", ("config.yaml", None))):  # fmt: skip
        (root / name).mkdir()
        for file in ("checkpoint.pt", "config.yaml", "curves.csv"):
            shutil.copy(root / "run" / file, root / name / file)
        if change[1] is not None:
            (root / name / change[0]).write_text(change[1])
    config = root / "neg_iters_run" / "config.yaml"
    config.write_text(re.sub(r"(?m)^iters: .*$", "iters: -5", config.read_text()))
    data = json.loads((root / "ds" / "transforms.json").read_text())
    for i, frame in enumerate(data["frames"]):
        frame["step"] = 10**30 if i == 1 else i
    (root / "huge_step.json").write_text(json.dumps(data))
    data["frames"][1]["step"] = 1.5
    (root / "frac_step.json").write_text(json.dumps(data))
    data["frames"][1]["step"] = 1
    del data["frames"][2]["step"]
    (root / "gap_step.json").write_text(json.dumps(data))
    data["frames"][2]["step"] = 1
    (root / "dup_step.json").write_text(json.dumps(data))
    (root / "mine.png").write_bytes(b"the user's own picture")
    (root / "no_config_run").mkdir()
    for file in (".spikenerf", "checkpoint.pt"):
        shutil.copy(root / "run" / file, root / "no_config_run" / file)


def _round_two(root: Path) -> None:
    """Issue 29's sandbox: look-alike and mixed folders, links, broken checkpoints, bad poses, PNG bombs."""
    (root / "userds").mkdir()  # a user's folder that looks like a dataset: no marker
    for name in ("transforms.json", "config.yaml"):
        shutil.copy(root / "ds" / name, root / "userds" / name)
    (root / "userds" / "notes.txt").write_text("mine\n")
    shutil.copytree(root / "ds", root / "mixed_ds")  # a dataset the user added notes to
    (root / "mixed_ds" / "notes.txt").write_text("mine\n")
    shutil.copytree(root / "ds", root / "nested_ds")  # a dataset with a trained run inside it
    shutil.copytree(root / "run", root / "nested_ds" / "run")
    shutil.copytree(root / "ds", root / "oldcase")  # beside it the user's own .oldcase.old
    (root / ".oldcase.old").mkdir()
    (root / ".oldcase.old" / "mine.txt").write_text("mine\n")
    (root / "link_ds").symlink_to(root / "ds")
    (root / "link_run").symlink_to(root / "run")
    (root / "photos").mkdir()  # a user's photos, one named like a frame
    shutil.copy(root / "ds" / "test" / "00000.png", root / "photos" / "00000.png")
    shutil.copy(root / "ds" / "test" / "00000.png", root / "photos" / "00009.png")
    ckpt = torch.load(root / "run" / "checkpoint.pt", weights_only=True)
    first = next(iter(ckpt["model"]))
    broken = {
        "ck_missing": {k: v for k, v in ckpt.items() if k != "model"},
        "ck_type": {**ckpt, "model": [1, 2], "iteration": "two"},
        "ck_shape": {**ckpt, "model": {**ckpt["model"], first: torch.zeros(3)}},
        "ck_rng": {**ckpt, "rng": {"torch": "none"}, "optimizer": {"state": 5}},
    }
    for name, data in broken.items():
        shutil.copytree(root / "run", root / name)
        torch.save(data, root / name / "checkpoint.pt")
    shutil.copytree(root / "run", root / "run_resim")  # its dataset changed since (another digest)
    torch.save(
        {**ckpt, "dataset": {**ckpt["dataset"], "content": "0" * 16}}, root / "run_resim" / "checkpoint.pt"
    )
    shutil.copytree(root / "run", root / "ck_foreign")  # another run's checkpoint copied into a run
    config = (root / "run" / "config.yaml").read_text()
    (root / "ck_foreign" / "config.yaml").write_text(config.replace("seed: 0", "seed: 7"))
    for name, edit in (("zero_pose_ds", _zero_pose), ("dec_time_ds", _decreasing_time)):
        shutil.copytree(root / "ds", root / name)
        data = json.loads((root / name / "transforms.json").read_text())
        edit(data["frames"])
        (root / name / "transforms.json").write_text(json.dumps(data))
    w = h = 40000  # a 16-bit PNG bomb: its header claims 9.6 GB; and a small header over a big payload
    (root / "bomb.png").write_bytes(_png16(w, h, b"\0" * 1_000_000))
    (root / "liar.png").write_bytes(_png16(16, 16, b"\0" * 20_000_000))
    shutil.copytree(root / "ds", root / "bomb_ds")
    shutil.copy(root / "bomb.png", root / "bomb_ds" / "test" / "00000.png")
    for name in ("bomb", "liar"):
        (root / f"seq_{name}").mkdir()
        text = (root / "seq" / "transforms.json").read_text().replace("a.png", f"{name}.png")
        (root / f"seq_{name}" / "transforms.json").write_text(text)
        shutil.copy(root / f"{name}.png", root / f"seq_{name}" / f"{name}.png")


def _zero_pose(frames: list[dict]) -> None:
    for f in frames:
        f["transform_matrix"] = [[0.0] * 4 for _ in range(4)]


def _decreasing_time(frames: list[dict]) -> None:
    frames[3]["time"], frames[4]["time"] = frames[4]["time"], frames[3]["time"]


def _png16(w: int, h: int, payload: bytes) -> bytes:
    """A 16-bit RGB PNG of size ``w``×``h`` whose IDAT inflates to ``payload``."""
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", w, h, 16, 2, 0, 0, 0)
    idat = zlib.compress(payload, 9)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


R = "{root}"
#: (case id, argv with {root} for the sandbox, a fragment the one-line message must contain)
T = ["train", f"{R}/ds", *TRAIN]
B = ["benchmark", "--scenes", "analytic-orbs"]
IMP = ["import", f"{R}/ds/spikes_gray.dat", "--poses", "orbit", "--orbit", "4,30", "--fov", "40",
       "--keyframe-every", "5", "--window", "3"]  # fmt: skip
DAT = ["reconstruct", f"{R}/ds/spikes_gray.dat", "--method", "tfp"]
# fmt: off
CASES: list[tuple[str, list[str], str]] = [
    # simulate: sizes, non-finite numbers, outputs
    ("sim-memory-bomb", [*SIM, "--width", "100000", "--height", "100000", "--out", f"{R}/o"], "--width"),
    ("sim-frames-bomb", [*SIM, "--frames", "100000000", "--out", f"{R}/o"], "--frames"),
    ("sim-size-not-8", [*SIM, "--width", "15", "--height", "15", "--out", f"{R}/o"], "multiple of 8"),
    ("sim-size-not-8-raw", [*SIM, "--width", "15", "--height", "15", "--raw-width", "16", "--out", f"{R}/o"],
     "multiple of 8"),
    ("sim-seq-width-bomb", ["simulate", "--sequence", f"{R}/seq/transforms.json", "--width", "100000",
                            "--out", f"{R}/o"], "--width"),
    ("sim-fps-nan", [*SIM, "--fps", "nan", "--out", f"{R}/o"], "--fps"),
    ("sim-fps-inf", [*SIM, "--fps", "inf", "--out", f"{R}/o"], "--fps"),
    ("sim-fps-zero", [*SIM, "--fps", "0", "--out", f"{R}/o"], "--fps"),
    ("sim-radius-inf", [*SIM, "--radius", "inf", "--out", f"{R}/o"], "--radius"),
    ("sim-radius-nan", [*SIM, "--radius", "nan", "--out", f"{R}/o"], "--radius"),
    ("sim-elevation-nan", [*SIM, "--elevation", "nan", "--out", f"{R}/o"], "--elevation"),
    ("sim-turns-inf", [*SIM, "--turns", "inf", "--out", f"{R}/o"], "--turns"),
    ("sim-duration-nan", [*SIM, "--duration", "nan", "--out", f"{R}/o"], "--duration"),
    ("sim-threshold-nan", [*SIM, "--threshold", "nan", "--out", f"{R}/o"], "threshold"),
    ("sim-threshold-neg", [*SIM, "--threshold", "-1", "--out", f"{R}/o"], "threshold"),
    ("sim-blur-fps-nan", [*SIM, "--blur-fps", "nan", "--out", f"{R}/o"], "--blur-fps"),
    ("sim-width-zero", [*SIM, "--width", "0", "--out", f"{R}/o"], "--width"),
    ("sim-spp-zero", [*SIM, "--spp", "0", "--out", f"{R}/o"], "--spp"),
    ("sim-gt-every-zero", [*SIM, "--gt-every", "0", "--out", f"{R}/o"], "--gt-every"),
    ("sim-frames-abc", [*SIM, "--frames", "abc", "--out", f"{R}/o"], "--frames"),
    ("sim-unknown-scene", ["simulate", "--scene", "no-such-scene", "--out", f"{R}/o"], "no-such-scene"),
    ("sim-out-under-file", [*SIM, "--out", f"{R}/afile/ds"], "afile"),
    ("sim-out-is-file", [*SIM, "--overwrite", "--out", f"{R}/afile"], "afile"),
    ("sim-overwrite-foreign", [*SIM, "--overwrite", "--out", f"{R}/thesis"], "thesis"),
    ("sim-overwrite-run", [*SIM, "--overwrite", "--out", f"{R}/run"], "run folder"),
    ("sim-exists", [*SIM, "--out", f"{R}/ds"], "--overwrite"),
    ("sim-seq-missing", ["simulate", "--sequence", f"{R}/nope.json", "--out", f"{R}/o"], "nope.json"),
    ("sim-seq-garbage", ["simulate", "--sequence", f"{R}/garbage.json", "--out", f"{R}/o"], "garbage.json"),
    ("sim-eval-views-list", [*SIM[:-3], "--no-progress", "--eval-views", f"{R}/list.json", "--out",
                             f"{R}/o"], "list.json"),
    ("sim-out-virtual-fs", [*SIM, "--out", "/proc/spikenerf-fault/ds"], "--out: cannot write there: /proc"),
    ("sim-seq-steps-per-frame-bomb", ["simulate", "--sequence", f"{R}/seq/transforms.json",
                                      "--steps-per-frame", "99999999999", "--out", f"{R}/o"],
     "--steps-per-frame: this needs"),
    # train
    ("train-no-dataset", ["train", f"{R}/nope", *TRAIN, "--out", f"{R}/o"], "nope"),
    ("train-resume-missing", [*T, "--resume", "--out", f"{R}/o"], "--resume"),
    ("train-lambda-nan", [*T, "--lambda", "nan", "--out", f"{R}/o"], "--lambda"),
    ("train-lambda-inf", [*T, "--lambda", "inf", "--out", f"{R}/o"], "--lambda"),
    ("train-lr-nan", [*T, "--lr", "nan", "--out", f"{R}/o"], "--lr"),
    ("train-iters-zero", [*T, "--iters", "0", "--out", f"{R}/o"], "--iters"),
    ("train-window-even", [*T, "--window", "4", "--out", f"{R}/o"], "--window"),
    ("train-batch-bomb", [*T, "--batch", "1000000000", "--out", f"{R}/o"], "--batch"),
    ("train-spike-window-long", [*T, "--method", "spike-nerf", "--spike-window", "100000", "--out", f"{R}/o"],
     "--spike-window: a 100000-step window"),
    ("train-spike-pixels-bomb", [*T, "--method", "spike-nerf", "--spike-pixels", "100000000",
                                 "--out", f"{R}/o"], "--spike-pixels"),
    ("train-grid-bomb", [*T, "--field-option", "n_voxels_final=1000000000000",
                         "--out", f"{R}/o"], "--field-option"),
    ("train-fopt-abc", [*T, "--field-option", "lr=abc", "--out", f"{R}/o"], "lr"),
    ("train-compile-optimizer-fp16", [*T, "--compile-optimizer", "--amp", "fp16", "--out", f"{R}/o"],
     "--compile-optimizer"),
    ("train-fopt-neg", [*T, "--field-option", "n_voxels_init=-1", "--out", f"{R}/o"],
     "n_voxels_init"),
    ("train-fopt-noeq", [*T, "--field-option", "novalue", "--out", f"{R}/o"],
     "--field-option"),
    ("train-fopt-unknown", [*T, "--field-option", "warp=1", "--out", f"{R}/o"], "warp"),
    ("train-fopt-voxels-3", [*T, "--field-option", "n_voxels_init=3", "--out", f"{R}/o"], "n_voxels_init"),
    ("train-fopt-occupancy-0", [*T, "--field-option", "occupancy_every=0", "--out", f"{R}/o"],
     "occupancy_every"),
    ("train-fopt-occupancy-grid-0", [*T, "--field-option", "occupancy_max_resolution=0", "--out", f"{R}/o"],
     "occupancy_max_resolution"),
    ("train-set-lr-ratio-neg", [*T, "--set", "lr_final_ratio=-1", "--out", f"{R}/o"], "lr_final_ratio"),
    ("train-set-lr-ratio-nan", [*T, "--set", "lr_final_ratio=.nan", "--out", f"{R}/o"], "lr_final_ratio"),
    ("train-set-mask-n-0", [*T, "--set", "targets.mask_n=0", "--out", f"{R}/o"], "--set targets.mask_n"),
    ("train-set-paper-warmup", [*T, "--set", "spike.paper_warmup=-5", "--out", f"{R}/o"], "paper"),
    ("train-fopt-yaml", [*T, "--field-option", "lr=[1", "--out", f"{R}/o"], "lr"),
    ("train-out-under-file", [*T, "--out", f"{R}/afile/run"], "afile"),
    ("train-out-dataset", [*T, "--out", f"{R}/other_ds"], "other_ds"),
    ("train-out-foreign", [*T, "--out", f"{R}/thesis"], "thesis"),
    ("train-out-exists", [*T, "--out", f"{R}/run"], "--resume"),
    ("train-resume-other", [*T, "--method", "nerf-gt", "--resume", "--out", f"{R}/run"],
     "method"),
    ("train-device-tpu", [*T, "--device", "tpu", "--out", f"{R}/o"], "device"),
    ("train-dataset-file", ["train", f"{R}/afile", *TRAIN, "--out", f"{R}/o"], "afile"),
    ("train-truncated-dat", ["train", f"{R}/bad_ds", *TRAIN, "--out", f"{R}/o"], "spikes_gray.dat"),
    ("train-bad-yaml-ds", ["train", f"{R}/yaml_ds", *TRAIN, "--out", f"{R}/o"], "config.yaml"),
    ("train-bad-png-ds", ["train", f"{R}/png_ds", *TRAIN, "--out", f"{R}/o"], "00000.png"),
    ("train-bad-json-ds", ["train", f"{R}/json_ds", *TRAIN, "--out", f"{R}/o"], "transforms.json"),
    ("train-resume-garbage", [*T, "--resume", "--out", f"{R}/garbage_ckpt"],
     "checkpoint.pt"),
    ("train-resume-pickle", [*T, "--resume", "--out", f"{R}/pickle_ckpt"],
     "checkpoint.pt"),
    # eval
    ("eval-missing", ["eval", f"{R}/nope", "--device", "cpu"], "nope"),
    ("eval-dataset-folder", ["eval", f"{R}/ds", "--device", "cpu"], "is a dataset folder, not a run folder"),
    ("render-dataset-folder", ["render", f"{R}/ds", "--out", f"{R}/o"], "is a dataset folder, not a run"),
    ("eval-garbage-ckpt", ["eval", f"{R}/garbage_ckpt", "--device", "cpu"], "checkpoint.pt"),
    ("eval-pickle-ckpt", ["eval", f"{R}/pickle_ckpt", "--device", "cpu"], "checkpoint.pt"),
    ("eval-bad-yaml", ["eval", f"{R}/bad_yaml_run", "--device", "cpu"], "config.yaml"),
    ("eval-other-dataset", ["eval", f"{R}/run", "--dataset", f"{R}/other_ds", "--device", "cpu", "--quiet"],
     "--dataset"),
    ("eval-chunk-negative", ["eval", f"{R}/run", "--chunk", "-1"], "--chunk"),
    # render
    ("render-out-dataset", ["render", f"{R}/run", "--spikes", "--device", "cpu", "--out", f"{R}/ds"], "ds"),
    ("render-out-run", ["render", f"{R}/run", "--device", "cpu", "--out", f"{R}/run"], "run"),
    ("render-out-foreign", ["render", f"{R}/run", "--device", "cpu", "--out", f"{R}/thesis"], "thesis"),
    ("render-out-under-file", ["render", f"{R}/run", "--device", "cpu", "--out", f"{R}/afile/r"], "afile"),
    ("render-orbit-bomb", ["render", f"{R}/run", "--trajectory", "orbit", "--orbit-frames", "1000000000",
                           "--device", "cpu", "--out", f"{R}/o"], "--orbit-frames"),
    ("render-spiral-bomb", ["render", f"{R}/run", "--trajectory", "spiral", "--orbit-frames", "1000000000",
                            "--device", "cpu", "--out", f"{R}/o"], "--orbit-frames"),
    ("render-traj-garbage", ["render", f"{R}/run", "--trajectory", f"{R}/garbage.json", "--device", "cpu",
                             "--out", f"{R}/o"], "garbage.json"),
    ("render-traj-missing", ["render", f"{R}/run", "--trajectory", f"{R}/nope.json", "--out", f"{R}/o"],
     "--trajectory"),
    ("render-fps-nan", ["render", f"{R}/run", "--fps-video", "nan", "--out", f"{R}/o"], "--fps-video"),
    ("render-fps-tiny", ["render", f"{R}/run", "--fps-video", "1e-5", "--out", f"{R}/o"],
     "--fps-video must lie in [0.01, 100000]"),
    ("eval-spike-pixels-huge", ["eval", f"{R}/run", "--device", "cpu", "--noref", "on", "--spike-pixels",
                                "9" * 23], "--spike-pixels"),
    ("train-resume-ckpt-foreign", [*T, "--seed", "7", "--resume", "--out", f"{R}/ck_foreign"],
     "belongs to another run: seed 0"),
    ("train-out-in-dataset", [*T, "--out", f"{R}/ds/runs/r"], "lies inside the dataset folder"),
    ("render-pickle-ckpt", ["render", f"{R}/pickle_ckpt", "--out", f"{R}/o"], "checkpoint.pt"),
    # reconstruct, info
    ("recon-truncated", ["reconstruct", f"{R}/trunc.dat", "--height", "4", "--width", "4", "--method", "tfp",
                         "--out", f"{R}/o.npy"], "trunc.dat"),
    ("recon-out-under-file", [*DAT, "--height", "16", "--width", "16", "--frame", "3",
                              "--out", f"{R}/afile/x.png"], "afile"),
    ("recon-height-zero", [*DAT, "--height", "0", "--width", "16", "--out", f"{R}/o.npy"],
     "--height and --width"),
    ("recon-window-even", [*DAT, "--window", "4", "--frame", "3", "--out", f"{R}/o.npy"],
     "--window must be an odd number"),
    ("recon-learned-threshold-neg", [*DAT[:3], "learned", "--threshold", "-1", "--frame", "3",
                                     "--out", f"{R}/o.npy"], "--threshold φ must be a positive number"),
    ("recon-missing-file", [*DAT[:1], f"{R}/nope.dat", *DAT[2:], "--frame", "1", "--out", f"{R}/o.png"],
     "nope.dat: file not found"),
    ("recon-data-threshold-huge", ["recon-data", "--train-draws", "1", "--val-draws", "2", "--size", "16",
                                   "--threshold", "1e39", "--out", f"{R}/o"], "--threshold φ must"),
    ("recon-data-color-twice", ["recon-data", "--color", "gray,gray", "--out", f"{R}/o"],
     "--color: gray is given twice"),
    ("info-missing", ["info", f"{R}/nope"], "nope"),
    ("info-pickle-ckpt", ["info", f"{R}/pickle_ckpt"], "checkpoint.pt"),
    ("info-bad-yaml-ds", ["info", f"{R}/yaml_ds"], "config.yaml"),
    ("info-bad-metrics", ["info", f"{R}/bad_metrics_run"], "metrics.json"),
    ("info-odd-metrics", ["info", f"{R}/odd_metrics_run"], "metrics.json"),
    # import: outputs (the dataset's own spikes and config.yaml are a valid recording)
    ("import-overwrite-foreign", [*IMP, "--overwrite", "--out", f"{R}/thesis"], "thesis"),
    ("import-overwrite-run", [*IMP, "--overwrite", "--out", f"{R}/run"], "run folder"),
    ("import-exists", [*IMP, "--out", f"{R}/ds"], "--overwrite"),
    ("import-overwrite-own-input", [*IMP, "--overwrite", "--out", f"{R}/ds"], "holds the input"),
    ("sim-seq-overwrite-own-input", ["simulate", "--sequence", f"{R}/ds/transforms_test.json", "--overwrite",
     "--out", f"{R}/ds"], "holds the input"),
    ("import-out-is-file", [*IMP, "--overwrite", "--out", f"{R}/afile"], "afile"),
    ("import-out-under-file", [*IMP, "--out", f"{R}/afile/ds"], "afile"),
    # benchmark, demo
    ("bench-out-under-file", [*B, "--out", f"{R}/afile/b"], "afile"),
    ("bench-size-bomb", [*B, "--size", "100000", "--out", f"{R}/o"],
     "--size"),
    ("bench-frames-bomb", [*B, "--frames", "100000000",
                           "--out", f"{R}/o"], "--frames"),
    ("bench-unknown-scene", ["benchmark", "--scenes", "nope", "--out", f"{R}/o"], "--scenes"),
    ("bench-out-foreign", [*B, "--out", f"{R}/thesis"], "thesis"),
    ("demo-size-zero", ["demo", "--size", "0", "--out", f"{R}/o"], "--size"),
    ("demo-iters-zero", ["demo", "--iters", "0", "--out", f"{R}/o"], "--iters"),
    ("demo-out-under-file", ["demo", "--quick", "--out", f"{R}/afile/demo"], "afile"),
    ("global-threads-zero", ["--threads", "0", "info", f"{R}/ds"], "--threads"),
    # sequences with broken images
    ("sim-seq-pickle-npy", ["simulate", "--sequence", f"{R}/seq_npy/transforms.json", "--out", f"{R}/o"],
     "obj.npy"),
    # round two (issue 29): ownership, never destroying what spikenerf did not write
    ("sim-overwrite-lookalike", [*SIM, "--overwrite", "--out", f"{R}/userds"], "userds"),
    ("import-overwrite-lookalike", [*IMP, "--overwrite", "--out", f"{R}/userds"], "userds"),
    ("sim-overwrite-mixed", [*SIM, "--overwrite", "--out", f"{R}/mixed_ds"], "notes.txt"),
    ("import-overwrite-mixed", [*IMP, "--overwrite", "--out", f"{R}/mixed_ds"], "notes.txt"),
    ("sim-overwrite-nested-run", [*SIM, "--overwrite", "--out", f"{R}/nested_ds"], "run"),
    ("sim-overwrite-user-old", [*SIM, "--overwrite", "--out", f"{R}/oldcase"], ".oldcase.old"),
    ("import-overwrite-user-old", [*IMP, "--overwrite", "--out", f"{R}/oldcase"], ".oldcase.old"),
    ("sim-overwrite-symlink", [*SIM, "--overwrite", "--out", f"{R}/link_ds"], "link_ds"),
    ("import-overwrite-symlink", [*IMP, "--overwrite", "--out", f"{R}/link_ds"], "link_ds"),
    ("recon-out-photos", [*DAT, "--frames", "0:2", "--out", f"{R}/photos"], "photos"),
    ("recon-out-dataset", [*DAT, "--frames", "0:2", "--out", f"{R}/ds/test"], "test"),
    ("recon-data-out-dataset", ["recon-data", "--train-draws", "2", "--val-draws", "2", "--size", "16",
                                "--out", f"{R}/ds"], "dataset folder"),
    ("recon-data-out-foreign", ["recon-data", "--train-draws", "2", "--val-draws", "2", "--size", "16",
                                "--out", f"{R}/thesis"], "thesis"),
    ("recon-train-out-dataset", ["recon-train", f"{R}/nope", "--out", f"{R}/ds"], "dataset folder"),
    ("recon-train-out-foreign", ["recon-train", f"{R}/nope", "--out", f"{R}/thesis"], "thesis"),
    # second writers: {R}/run is locked by this process during these cases (LOCKED)
    ("locked-eval-link", ["eval", f"{R}/link_run", "--device", "cpu", "--quiet"], "in use"),
    ("locked-render", ["render", f"{R}/run", "--device", "cpu", "--quiet", "--out", f"{R}/o"], "in use"),
    ("locked-train-link", [*T, "--resume", "--out", f"{R}/link_run"], "in use"),
    ("locked-recon-train", ["recon-train", f"{R}/nope", "--out", f"{R}/run_recon"], "in use"),
    # checkpoints with the right format tag but wrong contents
    ("eval-ckpt-missing", ["eval", f"{R}/ck_missing", "--device", "cpu"], "checkpoint.pt"),
    ("render-ckpt-missing", ["render", f"{R}/ck_missing", "--device", "cpu", "--out", f"{R}/o"],
     "checkpoint.pt"),
    ("info-ckpt-missing", ["info", f"{R}/ck_missing"], "checkpoint.pt"),
    ("train-resume-ckpt-missing", [*T, "--resume", "--out", f"{R}/ck_missing"], "checkpoint.pt"),
    ("eval-ckpt-type", ["eval", f"{R}/ck_type", "--device", "cpu"], "checkpoint.pt"),
    ("info-ckpt-type", ["info", f"{R}/ck_type"], "checkpoint.pt"),
    ("train-resume-ckpt-type", [*T, "--resume", "--out", f"{R}/ck_type"], "checkpoint.pt"),
    ("eval-ckpt-shape", ["eval", f"{R}/ck_shape", "--device", "cpu"], "checkpoint.pt"),
    ("render-ckpt-shape", ["render", f"{R}/ck_shape", "--device", "cpu", "--out", f"{R}/o"],
     "checkpoint.pt"),
    ("train-resume-ckpt-shape", [*T, "--resume", "--out", f"{R}/ck_shape"], "checkpoint.pt"),
    ("train-resume-ckpt-rng", [*T, "--resume", "--out", f"{R}/ck_rng"], "checkpoint.pt"),
    ("eval-ckpt-foreign", ["eval", f"{R}/ck_foreign", "--device", "cpu"], "checkpoint.pt"),
    ("info-ckpt-foreign", ["info", f"{R}/ck_foreign"], "belongs to another run"),
    ("eval-test-pose-opt-huge", ["eval", f"{R}/run", "--device", "cpu", "--test-pose-opt", "9" * 20],
     "--test-pose-opt"),
    ("eval-noref-steps-huge", ["eval", f"{R}/run", "--device", "cpu", "--noref", "on", "--noref-steps",
                               "9" * 20], "--noref-steps"),
    ("sim-warmup-huge", [*SIM, "--warmup", "9" * 20, "--out", f"{R}/o"], "--warmup"),
    ("sim-spp-bomb", [*SIM, "--spp", "99999999999999", "--out", f"{R}/o"], "--spp"),
    ("render-ckpt-foreign", ["render", f"{R}/ck_foreign", "--device", "cpu", "--out", f"{R}/o"],
     "checkpoint.pt"),
    # integers out of range, binary configs, non-finite orbits
    ("sim-seed-huge", [*SIM, "--seed", "99999999999999999999999", "--out", f"{R}/o"], "--seed"),
    ("train-seed-huge", [*T, "--seed", "99999999999999999999999", "--out", f"{R}/o"], "--seed"),
    ("train-set-seed-huge", [*T, "--set", "seed=99999999999999999999999", "--out", f"{R}/o"], "seed"),
    ("train-iters-huge", [*T, "--iters", "99999999999999999999999", "--out", f"{R}/o"], "--iters"),
    ("render-seed-huge", ["render", f"{R}/run", "--seed", "99999999999999999999999", "--out", f"{R}/o"],
     "--seed"),
    ("recon-data-seed-huge", ["recon-data", "--seed", "99999999999999999999999", "--out", f"{R}/o"],
     "--seed"),
    ("train-config-png", [*T, "--config", f"{R}/ds/test/00000.png", "--out", f"{R}/o"], "00000.png"),
    ("train-config-dat", [*T, "--config", f"{R}/ds/spikes_gray.dat", "--out", f"{R}/o"], "spikes_gray.dat"),
    ("import-orbit-nan", [*IMP, "--orbit", "nan,30", "--out", f"{R}/o"], "--orbit"),
    ("import-orbit-inf-turns", [*IMP, "--orbit", "4,30,inf", "--out", f"{R}/o"], "--orbit"),
    ("import-orbit-inf-elevation", [*IMP, "--orbit", "4,inf", "--out", f"{R}/o"], "--orbit"),
    ("import-orbit-nan-azimuth", [*IMP, "--orbit", "4,30,1,nan", "--out", f"{R}/o"], "--orbit"),
    # wrong successes
    ("train-zero-poses", ["train", f"{R}/zero_pose_ds", *TRAIN, "--out", f"{R}/o"], "transforms.json"),
    ("train-decreasing-times", ["train", f"{R}/dec_time_ds", *TRAIN, "--out", f"{R}/o"], "time"),
    ("info-fps-nan", ["info", f"{R}/ds/spikes_gray.dat", "--fps", "nan"], "--fps"),
    ("info-fps-inf", ["info", f"{R}/ds/spikes_gray.dat", "--fps", "inf"], "--fps"),
    ("train-resume-resimulated", [*T, "--resume", "--out", f"{R}/run_resim"], "its files differ from"),
    ("eval-resimulated", ["eval", f"{R}/run_resim", "--device", "cpu"], "its files differ from"),
    ("train-resume-iters-below", [*T, "--resume", "--iters", "1", "--out", f"{R}/run"], "--iters"),
    # the CLI sweep: refused up front in one line, nothing half-written, no traceback
    ("sim-frames-huge", [*SIM, "--frames", "100000000000", "--out", f"{R}/o"], "--frames"),
    ("sim-elevation-huge", [*SIM, "--elevation", "1e308", "--out", f"{R}/o"], "--elevation"),
    ("sim-turns-huge", [*SIM, "--turns", "1e308", "--out", f"{R}/o"], "--turns"),
    ("import-orbit-turns-overflow", [*IMP, "--orbit", "4,30,1e308", "--out", f"{R}/o"], "--orbit"),
    ("import-orbit-elevation-big", [*IMP, "--orbit", "4,1e308", "--out", f"{R}/o"], "--orbit"),
    ("import-step-huge", [*IMP[:3], f"{R}/huge_step.json", *IMP[6:], "--out", f"{R}/o"], "frames[1].step"),
    ("import-step-fraction", [*IMP[:3], f"{R}/frac_step.json", *IMP[6:], "--out", f"{R}/o"],
     "frames[1].step: expected an integer"),
    ("import-step-missing", [*IMP[:3], f"{R}/gap_step.json", *IMP[6:], "--out", f"{R}/o"],
     "frames[2]: has no step"),
    ("import-step-twice", [*IMP[:3], f"{R}/dup_step.json", *IMP[6:], "--out", f"{R}/o"],
     "frames[1] and frames[2] share step 1"),
    ("import-a-folder", ["import", f"{R}/ds", *IMP[2:], "--out", f"{R}/o"], "is a folder, not a .dat"),
    ("info-bad-curves", ["info", f"{R}/bad_curves_run"], "curves.csv"),
    ("info-run-config-value", ["info", f"{R}/neg_iters_run"], "config.yaml: iters"),
    ("render-run-config-value", ["render", f"{R}/neg_iters_run", "--out", f"{R}/o"], "config.yaml: iters"),
    ("recon-train-lr-inf", ["recon-train", f"{R}/nope", "--lr", "inf", "--out", f"{R}/o"], "--lr"),
    ("recon-train-iters-zero", ["recon-train", f"{R}/nope", "--iters", "0", "--out", f"{R}/o"],
     "'--iters': 0 is out of range: expected 1 to"),
    ("recon-train-iters-negative", ["recon-train", f"{R}/nope", "--iters", "-1", "--out", f"{R}/o"],
     "'--iters': -1 is out of range: expected 1 to"),
    ("recon-out-existing-file", [*DAT, "--height", "16", "--width", "16", "--frame", "3",
                                 "--out", f"{R}/mine.png"], "--overwrite"),
    ("recon-out-in-dataset", [*DAT, "--height", "16", "--width", "16", "--frame", "3",
                              "--out", f"{R}/ds/test/00000.png", "--overwrite"], "dataset folder"),
    ("recon-out-in-run", [*DAT, "--height", "16", "--width", "16", "--frame", "3",
                          "--out", f"{R}/run/x.npy"], "run folder"),
    ("recon-mp4-in-dataset", [*DAT, "--height", "16", "--width", "16", "--stride", "5",
                              "--out", f"{R}/ds/preview.mp4"], "dataset folder"),
    ("recon-mp4-fps-inf", [*DAT, "--height", "16", "--width", "16", "--fps-video", "inf",
                           "--out", f"{R}/o.mp4"], "--fps-video must lie in"),
    ("recon-mp4-one-frame", [*DAT, "--height", "16", "--width", "16", "--frame", "3", "--out", f"{R}/o.mp4"],
     "a video needs a frame range"),
    ("demo-device-mps", ["demo", "--quick", "--device", "mps", "--out", f"{R}/o"], "--device"),
    ("bench-device-mps", [*B, "--device", "mps", "--out", f"{R}/o"], "--device"),
    ("bench-set-batch-neg", [*B, "--set", "batch=-1", "--out", f"{R}/o"], "batch"),
    ("bench-set-method", [*B, "--set", "method=nerf-gt", "--out", f"{R}/o"], "--set method"),
    ("bench-set-seed", [*B, "--set", "seed=7", "--out", f"{R}/o"], "--seeds"),
    ("bench-color-twice", [*B, "--color", "gray,gray", "--out", f"{R}/o"], "gray is given twice"),
    ("bench-set-variant-key", [*B, "--set", "targets.mask=false", "--out", f"{R}/o"],
     "--set targets.mask: the benchmark's variants set it"),
    ("bench-set-field-typo", [*B, "--set", "field_config.bogus=1", "--out", f"{R}/o"],
     "unknown grid field config keys ['bogus']"),
    ("recon-data-window-bomb", ["recon-data", "--train-draws", "1", "--val-draws", "2", "--size", "16",
                                "--window", "99999999", "--out", f"{R}/o"], "--window"),
    ("recon-data-draws-bomb", ["recon-data", "--train-draws", "99999999999", "--val-draws", "2",
                               "--size", "16", "--out", f"{R}/o"], "--train-draws"),
    ("recon-data-natural-bomb", ["recon-data", "--train-draws", "1", "--val-draws", "2", "--size", "16",
                                 "--natural", "99999999999", "--out", f"{R}/o"], "--natural"),
    ("sim-duration-negative", [*SIM[:-5], "--duration", "-1", "--out", f"{R}/o"], "--duration"),
    ("import-keyframe-every-huge", [*IMP[:8], "--keyframe-every", "99999999999999999999", "--window", "3",
                                    "--out", f"{R}/o"], "--keyframe-every"),
    ("info-run-without-config", ["info", f"{R}/no_config_run"], "config.yaml"),
    ("render-spike-steps-alone", ["render", f"{R}/run", "--spike-steps", "5", "--out", f"{R}/o"],
     "--spike-steps"),
    ("sim-blend-not-blend", ["simulate", "--blend", f"{R}/afile", "--out", f"{R}/o"], "--blend"),
    ("sim-warmup-negative", [*SIM, "--warmup", "-1", "--out", f"{R}/o"], "Invalid value for '--warmup'"),
    ("recon-data-unknown-scene", ["recon-data", "--scene", "nope", "--out", f"{R}/o"],
     "`spikenerf simulate --list-scenes`"),
    # nothing created before the checks pass, not even a parent folder
    ("render-traj-garbage-deep", ["render", f"{R}/run", "--trajectory", f"{R}/garbage.json", "--device",
                                  "cpu", "--out", f"{R}/new/deeper/r"], "garbage.json"),
    ("import-one-pose-deep", ["import", f"{R}/ds/spikes_gray.dat", "--poses", f"{R}/seq/transforms.json",
                              "--fov", "40", "--out", f"{R}/new/deeper/o"], "transforms.json"),
    # a 16-bit PNG bomb: bounded by its header before inflating
    ("sim-seq-png-bomb", ["simulate", "--sequence", f"{R}/seq_bomb/transforms.json", "--out", f"{R}/o"],
     "bomb.png"),
    ("train-png-bomb", ["train", f"{R}/bomb_ds", *TRAIN, "--out", f"{R}/o"], "limit"),
    ("sim-seq-png-liar", ["simulate", "--sequence", f"{R}/seq_liar/transforms.json", "--no-progress",
                          "--out", f"{R}/o"],
     "more data"),
    # damaged records: render.json (read by info and by a render into its folder), a one-line curves.csv
    ("info-render-record-types", ["info", f"{R}/bad_render"],
     "render.json: malformed render record (files.spikes: expected a list of file names, found 5)"),
    ("info-render-record-size", ["info", f"{R}/size_render"], "(size 7×5 from render.json)"),
    ("render-into-bad-record", ["render", f"{R}/run", "--device", "cpu", "--quiet",
                                "--out", f"{R}/bad_render"], "render.json: malformed render record"),
    ("train-resume-curves-one-line", [*T, "--resume", "--out", f"{R}/line_curves_run"],
     "curves.csv: not a training curve table: no column 'iteration'"),
    ("info-curves-one-line", ["info", f"{R}/line_curves_run"], "curves.csv: not a training curve table"),
    # the hostile-input audit: a folder where a file goes (named before any work, not its write's
    # temporary after it), warnings that came before a refusal (two lines), a dataset's layout
    ("eval-metrics-folder", ["eval", f"{R}/dir_metrics_run", "--device", "cpu", "--quiet"],
     "metrics.json: RUN: is a folder, not a file"),
    ("train-resume-curves-folder", [*T, "--iters", "3", "--resume", "--out", f"{R}/dir_curves_run"],
     "curves.csv: is a folder, not a training curve table"),
    ("info-curves-folder", ["info", f"{R}/dir_curves_run"], "curves.csv: is a folder"),
    ("recon-threshold-nan-recorded", [*DAT, "--threshold", "nan", "--frame", "3", "--out", f"{R}/o.npy"],
     "--threshold φ must be a positive number"),
    ("recon-threshold-differs-frame-outside", [*DAT, "--threshold", "2", "--frame", "1000",
                                               "--out", f"{R}/o.png"], "--frame: frame 1000 is outside"),
    ("recon-layout-differs-frame-outside", [*DAT, "--layout", "topdown", "--frame", "1000",
                                            "--out", f"{R}/o.png"], "--frame: frame 1000 is outside"),
    ("info-fps-differs-raw-width-small", ["info", f"{R}/ds/spikes_gray.dat", "--fps", "1000", "--raw-width",
                                          "8"], "--raw-width 8 is smaller"),
    ("train-dataset-layout-topdown", ["train", f"{R}/topdown_ds", *TRAIN, "--out", f"{R}/o"],
     "config.yaml: field 'layout': a dataset's spike files are stored in the spikecv layout"),
    ("info-dataset-layout-topdown", ["info", f"{R}/topdown_ds"], "config.yaml: field 'layout'"),
    # the input-handling audit: a window longer than the stream, an eval-views file's broken camera
    ("recon-eval-window-longer", ["recon-eval", f"{R}/ds", "--window", "999999", "--methods", "tfp",
                                  "--out", f"{R}/o"],
     "spikes_gray.dat: --window 999999 is longer than the 40-frame stream"),
    *[(f"sim-eval-views-{name}", [*SIM[:-3], "--no-progress", "--eval-views", f"{R}/{name}.json", "--out",
                                   f"{R}/o"], f"{name}.json: field '{key}': expected a positive number")
      for name, key in (("nan_fov", "camera_angle_x"), ("text_fov", "camera_angle_x"),
                        ("zero_fov", "camera_angle_x"), ("neg_fl", "fl_x"))],
    ("render-traj-nan-fov", ["render", f"{R}/run", "--trajectory", f"{R}/nan_fov.json", "--device", "cpu",
                             "--out", f"{R}/o"], "nan_fov.json: field 'camera_angle_x': expected a positive"),
    # ... a run's garbled summary.json or marker (reported as a garbled curves.csv is), an empty --resume
    ("info-summary-garbage", ["info", f"{R}/garbage_summary_run"], "summary.json: malformed JSON"),
    ("info-marker-garbage", ["info", f"{R}/garbage_marker_run"], ".spikenerf: a damaged folder marker"),
    ("train-resume-empty-folder", [*T, "--resume", "--out", f"{R}/empty_dir"],
     "empty_dir: --resume: no run in this empty folder to resume"),
]
#: cases run while this process holds the writer lock of the sandbox folder named here
LOCKED = {"locked-eval-link": "run", "locked-render": "run",
          "locked-train-link": "run", "locked-recon-train": "run_recon"}
# fmt: on


@pytest.fixture(scope="module")
def seq_npy(sandbox: Path) -> Path:
    """A sequence whose only frame is an object (pickle) .npy: it must be refused, never unpickled."""
    seq = sandbox / "seq_npy"
    if not seq.exists():
        seq.mkdir()
        text = (sandbox / "seq" / "transforms.json").read_text().replace("a.png", "obj.npy")
        (seq / "transforms.json").write_text(text)
        shutil.copy(sandbox / "obj.npy", seq / "obj.npy")
    return seq


@pytest.mark.parametrize(("case", "argv", "needle"), CASES, ids=[c[0] for c in CASES])
def test_bad_input_is_one_line_exit_2_and_harmless(
    sandbox: Path, seq_npy: Path, case: str, argv: list[str], needle: str, capsys: pytest.CaptureFixture[str]
) -> None:
    before = _tree(sandbox)
    args = [a.replace(R, str(sandbox)) for a in argv]
    capsys.readouterr()
    t0 = time.perf_counter()
    held = output_lock(sandbox / LOCKED[case]) if case in LOCKED else contextlib.nullcontext()
    with pytest.raises(SystemExit) as exit_, held:
        _cli(*args)
    TIMES[" ".join(argv[:1])] = max(TIMES.get(argv[0], 0.0), time.perf_counter() - t0)
    err = capsys.readouterr().err
    assert exit_.value.code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("spikenerf: error: "), err
    assert "Traceback" not in err and needle in lines[0], err
    assert _tree(sandbox) == before, "the sandbox changed (partial output, or a file was touched)"
    assert not Path(PWNED[0]).exists(), "a pickle payload ran"


def test_case_table_is_large_and_distinct() -> None:
    assert len({c[0] for c in CASES}) == len(CASES) >= 50
    assert len({tuple(c[1]) for c in CASES}) == len(CASES)


# ------------------------------------------------------------------------------- round two, beyond the table
def test_a_users_old_folder_is_never_moved_and_our_own_dataset_is_replaced(tmp_path: Path) -> None:
    """A user's ``.NAME.old`` beside a new output stays where it is, untouched; a dataset spikenerf wrote is
    replaced by ``--overwrite`` with nothing left beside it."""
    out, old = tmp_path / "ds", tmp_path / ".ds.old"
    old.mkdir()
    (old / "mine.txt").write_text("mine\n")
    _cli(*SIM, "--out", out)
    assert (old / "mine.txt").read_text() == "mine\n" and not (out / "mine.txt").exists()
    mine = tmp_path / "mine"
    _cli(*SIM, "--out", mine)
    before = (mine / "spikes_gray.dat").read_bytes()
    _cli(*SIM, "--overwrite", "--threshold", "2", "--out", mine)
    assert (mine / "spikes_gray.dat").read_bytes() != before
    assert sorted(p.name for p in tmp_path.iterdir()) == [".ds.old", "ds", "mine"]


def test_render_into_a_used_folder_keeps_only_the_new_views(sandbox: Path, tmp_path: Path) -> None:
    out = tmp_path / "r"
    _cli("render", sandbox / "run", "--trajectory", "orbit", "--orbit-frames", "3", "--device", "cpu",
         "--quiet", "--out", out)  # fmt: skip
    assert len(list((out / "images").glob("*.png"))) == 3
    (out / ".render.json.abc1_xyz.tmp").write_text("a killed render's temporary")
    _cli("render", sandbox / "run", "--device", "cpu", "--quiet", "--out", out)  # the 1 test view
    assert sorted(p.name for p in (out / "images").iterdir()) == ["00000.png"]
    assert sorted(p.name for p in (out / "depth").iterdir()) == ["00000.npy", "00000.png"]
    assert not list(out.glob("*.tmp")) and not (out / "orbit.mp4").exists()


def test_a_render_into_its_folder_keeps_the_users_files_and_drops_its_old_spikes(
    sandbox: Path, tmp_path: Path
) -> None:
    out = tmp_path / "r"
    args = ["render", sandbox / "run", "--device", "cpu", "--quiet", "--out", out]
    _cli(*args[:2], "--trajectory", "orbit", "--orbit-frames", "3", "--spikes", *args[2:])
    assert (out / "spikes_gray.dat").is_file() and (out / "spikes_tfp.png").is_file()
    mine = [out / "images" / "2023_holiday.png", out / "depth" / "1notes.txt", out / "mine.mp4"]
    for path in mine:
        path.write_text("the user's")
    _cli(*args)  # the test views, no spikes
    assert all(path.read_text() == "the user's" for path in mine)
    assert not (out / "spikes_gray.dat").exists() and not (out / "spikes_tfp.png").exists()
    assert sorted(p.name for p in (out / "images").iterdir()) == ["00000.png", "2023_holiday.png"]


def test_a_render_with_spikes_keeps_a_config_yaml_it_did_not_write(sandbox: Path, tmp_path: Path) -> None:
    out = tmp_path / "r"
    args = ["render", sandbox / "run", "--device", "cpu", "--quiet", "--out", out]
    _cli(*args)  # a render folder (marked), then the user's own config.yaml in it
    (out / "config.yaml").write_text("mine: true\n")
    _cli(*args[:2], "--trajectory", "orbit", "--orbit-frames", "2", "--spikes", *args[2:])
    assert (out / "config.yaml").read_text() == "mine: true\n" and (out / "spikes_gray.dat").is_file()
    assert "config.yaml" not in json.loads((out / "render.json").read_text())["files"]["spikes"]
    _cli(*args)  # its spike files go, the user's file stays
    assert (out / "config.yaml").read_text() == "mine: true\n" and not (out / "spikes_gray.dat").exists()


def test_eval_removes_a_killed_writers_temporaries(sandbox: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    shutil.copytree(sandbox / "run", run)
    (run / ".metrics.json.k2m9q0zz.tmp").write_text("{")
    (run / ".checkpoint.pt.def45678.tmp").write_bytes(b"\0")
    _cli("eval", run, "--device", "cpu", "--quiet")
    assert not list(run.glob(".*.tmp")) and (run / "metrics.json").is_file()


def test_a_full_disk_while_checkpointing_is_one_line(
    sandbox: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """torch.save on a full disk (here: a file-size limit, EFBIG) gives one line naming the checkpoint."""
    import resource

    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    capsys.readouterr()
    resource.setrlimit(resource.RLIMIT_FSIZE, (100_000, hard))  # the checkpoint is about 300 kB
    try:
        with pytest.raises(SystemExit) as exit_:
            _cli("train", sandbox / "ds", *TRAIN, "--out", tmp_path / "run")
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
    err = capsys.readouterr().err.strip()
    assert exit_.value.code == 2 and err.count("\n") == 0 and "Traceback" not in err, err
    assert "checkpoint.pt" in err and "disk full" in err, err
    assert not list((tmp_path / "run").glob(".*.tmp")) and not (tmp_path / ".run.lock").exists()


def test_simulate_jobs_are_capped_by_cores_and_work() -> None:
    from spikenerf.capture.render_workers import usable_jobs

    assert usable_jobs(100000, 10**6) <= (os.cpu_count() or 1)
    assert usable_jobs(100000, 1) == 1 and usable_jobs(1, 50) == 1


def test_info_lists_its_preview_so_overwrite_still_replaces_the_dataset(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    _cli(*SIM, "--out", out)
    _cli("info", out)
    assert (out / "preview.png").is_file()
    _cli(*SIM, "--overwrite", "--threshold", "2", "--out", out)  # refused before: preview.png a stranger
    assert not (out / "preview.png").exists() and (out / "transforms.json").is_file()


def test_a_single_output_file_may_go_into_an_unmarked_look_alike(tmp_path: Path) -> None:
    """Only a real marker protects a folder from a single file: a user's folder with a ``manifest.json`` is
    not a pair folder."""
    from spikenerf.core.errors import InputError
    from spikenerf.core.marker import check_file_output, mark

    mine = tmp_path / "project"
    mine.mkdir()
    (mine / "manifest.json").write_text("{}")
    check_file_output(mine / "frame.png")
    mark(mine, "pairs")
    with pytest.raises(InputError, match="inside a pairs folder"):
        check_file_output(mine / "frame.png")


# --------------------------------------------------------------- records, and runs that do not fit their data
def test_info_says_when_the_runs_dataset_is_not_the_one_it_trained_on(
    sandbox: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """What eval, render and train --resume refuse, info tells in a warning line and still describes the
    run; a dataset that is gone is no warning (eval names it)."""

    def info(run: Path) -> list[str]:
        capsys.readouterr()
        _cli("info", run)
        out = capsys.readouterr().out
        assert "iterations: 2 of 2" in out and "last evaluation: iteration 2" in out, out
        return [line for line in out.splitlines() if line.startswith("warning: ")]

    resimulated = info(sandbox / "run_resim")
    assert len(resimulated) == 1 and "its files differ from those the run trained on" in resimulated[0]
    assert info(sandbox / "run") == []
    run = tmp_path / "run"
    shutil.copytree(sandbox / "run", run)
    config = (run / "config.yaml").read_text()
    (run / "config.yaml").write_text(re.sub(r"(?m)^dataset: .*$", f"dataset: {sandbox / 'other_ds'}", config))
    other = info(run)
    assert len(other) == 1 and "size [12, 12] (run: [16, 16])" in other[0], other
    (run / "config.yaml").write_text(re.sub(r"(?m)^dataset: .*$", f"dataset: {tmp_path / 'gone'}", config))
    assert info(run) == []
    (run / "config.yaml").write_text(config)  # a dataset it cannot read (as root, a permission would not do)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(
            "spikenerf.train.run.content_digest", lambda *_: (_ for _ in ()).throw(PermissionError())
        )
        assert info(run) == []


@pytest.mark.parametrize("content", ["", "iteration,seconds,train_psnr,test_psnr\n"], ids=["empty", "header"])
def test_a_resume_writes_an_empty_curves_csv_again(sandbox: Path, tmp_path: Path, content: str) -> None:
    """A zero-byte curves.csv (a write a crash cut short) or a header alone holds no rows to keep: resume
    writes it again from its next evaluation (one line of anything else is refused, in CASES)."""
    from spikenerf.train.evaluate import read_curves

    run = tmp_path / "run"
    shutil.copytree(sandbox / "run", run)
    (run / "curves.csv").write_text(content)
    _cli("train", sandbox / "ds", *TRAIN, "--iters", "3", "--resume", "--out", run)
    assert [row["iteration"] for row in read_curves(run / "curves.csv")] == [3]


def test_a_trajectory_files_views_are_weighed_with_their_files(
    sandbox: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """4000 poses of a 16×16 camera write four files a view (a 4 KiB block each at least: 91 MB in all,
    not the 26 MB of their pixels): with 60 MB free, render refuses them up front in one line (not with
    ``spikenerf --no-limits``)."""
    from spikenerf.core import limits
    from spikenerf.eval.video import check_render_resources
    from spikenerf.scenes.trajectory import Intrinsics

    monkeypatch.setattr(limits, "available_memory", lambda: 64 * limits.GIB)
    monkeypatch.setattr(limits, "free_disk", lambda path: 60 * 1024**2)
    pose = [[1, 0, 0, 0], [0, 0, -1, -4], [0, 1, 0, 0], [0, 0, 0, 1]]
    (tmp_path / "long.json").write_text(json.dumps({"frames": [{"transform_matrix": pose}] * 4000}))
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit_:
        _cli("render", sandbox / "run", "--trajectory", tmp_path / "long.json", "--device", "cpu", "--quiet",
             "--out", tmp_path / "r")  # fmt: skip
    err = capsys.readouterr().err.strip()
    assert exit_.value.code == 2 and err.count("\n") == 0 and "Traceback" not in err, err
    assert "--trajectory" in err and "disk space" in err and not (tmp_path / "r").exists(), err
    monkeypatch.setenv(limits.NO_LIMITS_ENV, "1")  # spikenerf --no-limits: not weighed
    check_render_resources(Intrinsics(16, 16, 20.0, 20.0, 8.0, 8.0), 4000, 0, tmp_path / "r")
