"""Damaged or hand-edited pair folders: `recon-train` refuses them with one line naming the file before
writing anything, and a `recon-data` resume writes a damaged shard again."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from helpers import run_cli
from spikenerf.recon.generate import write_pairs
from spikenerf.recon.pairs import PairConfig
from spikenerf.recon.store import load_split

DATA = ["recon-data", "--train-draws", 2, "--val-draws", 2, "--size", 16, "--window", 5]
TRAIN = ["--iters", 4, "--batch", 2, "--crop", 16, "--width", 4, "--eval-every", 2, "--ckpt-every", 2]
SHARD = "train/shard-00000.npz"


@pytest.fixture(scope="module")
def pairs(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("pairs") / "p"
    write_pairs(root, PairConfig(size=16, window=5, supersample=1), 2, 2, seed=0, progress=False)
    return root


def _edit_shard(path: Path, **changes) -> None:
    with np.load(path) as z:
        data = dict(z)
    for key, change in changes.items():
        data[key] = change(data[key])
    np.savez(path, **data)


def _edit_manifest(root: Path, change) -> None:
    data = json.loads((root / "manifest.json").read_text())
    change(data)
    (root / "manifest.json").write_text(json.dumps(data))


def _nan(a: np.ndarray) -> np.ndarray:
    a[:] = np.nan
    return a


#: case → (how the folder is damaged, the file named, what the message says)
CASES = {
    "truncated": (
        lambda p: (p / SHARD).write_bytes((p / SHARD).read_bytes()[:100]),
        SHARD,
        "unreadable pair shard (BadZipFile)",
    ),
    "member-missing": (lambda p: np.savez(p / SHARD, spikes=np.zeros(3)), SHARD, "unreadable pair shard"),
    "nan-targets": (lambda p: _edit_shard(p / SHARD, targets=_nan), SHARD, "non-finite"),
    "inf-val-target": (
        lambda p: _edit_shard(p / "val/shard-00001.npz", targets=lambda a: a * np.float32(np.inf)),
        "val/shard-00001.npz",
        "non-finite",
    ),
    "float-spikes": (
        lambda p: _edit_shard(p / SHARD, spikes=lambda a: _nan(a.astype(np.float32))),
        SHARD,
        "spikes float32",
    ),
    "short-targets": (
        lambda p: _edit_shard(p / SHARD, targets=lambda a: a[:, :8]),
        SHARD,
        "targets float32({n}, 8, 16)",
    ),
    "short-window": (
        lambda p: _edit_shard(p / SHARD, spikes=lambda a: a[:, :3]),
        SHARD,
        "(window 5, size 16",
    ),
    "info-count": (lambda p: _edit_shard(p / SHARD, info=lambda a: a[:1]), SHARD, "and 1 info entries"),
    "manifest-window": (
        lambda p: _edit_manifest(p, lambda m: m["config"].update(window=7)),
        SHARD,
        "(window 7, size 16",
    ),
    "manifest-config": (
        lambda p: _edit_manifest(p, lambda m: m.update(config=5)),
        "manifest.json",
        "config must be an object, found 5",
    ),
    "manifest-size": (
        lambda p: _edit_manifest(p, lambda m: m["config"].update(size="16")),
        "manifest.json",
        'config.size must be an integer ≥ 1, found "16"',
    ),
    "manifest-modes": (
        lambda p: _edit_manifest(p, lambda m: m["config"].pop("modes")),
        "manifest.json",
        "config.modes must be a list of gray, rgb, bayer, found nothing",
    ),
}


@pytest.mark.parametrize("case", list(CASES))
def test_recon_train_refuses_a_damaged_pair_folder_with_one_line(
    capsys, pairs: Path, tmp_path: Path, case: str
) -> None:
    damage, name, expected = CASES[case]
    bad = tmp_path / "p"
    shutil.copytree(pairs, bad)
    with np.load(pairs / SHARD) as z:
        expected = expected.format(n=len(z["targets"]))
    damage(bad)
    code, _, err = run_cli(capsys, "recon-train", bad, *TRAIN, "--out", tmp_path / "run")
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err, err
    assert f"error: {bad / name}: " in err and expected in err, err
    assert not (tmp_path / "run").exists()


def test_recon_data_into_a_folder_of_other_settings_names_them(capsys, tmp_path: Path) -> None:
    other = tmp_path / "p"
    code, _, _ = run_cli(capsys, *DATA, "--out", other)
    assert code == 0
    args = [a if a != 16 else 24 for a in DATA]  # --size 16 → 24
    code, _, err = run_cli(capsys, *args, "--train-draws", 3, "--out", other)
    assert code == 2 and err.count("\n") == 1
    assert "other settings (--size 16 → 24, --train-draws 2 → 3): give the same ones" in err, err


def test_settings_changed_names_keys_either_side_lacks() -> None:
    from spikenerf.recon.generate import settings_changed

    old = {"config": {"size": 16, "gone": 1}, "seed": 0, "command": "a"}
    new = {"config": {"size": 24}, "seed": 0, "command": "b"}
    assert settings_changed(old, new) == [("size", 16, 24), ("gone", 1, None)]


def test_recon_train_names_a_missing_pair_folder_and_reconstruct_a_folder_given_as_weights(
    capsys, tmp_path: Path
) -> None:
    code, _, err = run_cli(capsys, "recon-train", tmp_path / "nope", *TRAIN, "--out", tmp_path / "run")
    assert code == 2 and f"{tmp_path / 'nope'}: pair folder not found (write one with" in err
    (tmp_path / "s.dat").write_bytes(bytes(50 * 2))  # 50 frames of 4×4
    args = ["--height", 4, "--width", 4, "--method", "learned", "--weights", tmp_path, "--frame", 0]
    code, _, err = run_cli(capsys, "reconstruct", tmp_path / "s.dat", *args, "--out", tmp_path / "o.npy")
    assert code == 2 and f"{tmp_path}: is a folder, not a weights file" in err


def test_weights_with_a_bad_hparams_value_name_the_file_and_the_value(capsys, tmp_path: Path) -> None:
    """The architecture's own check of a weights file's ``hparams`` (an even window) names the file,
    not a --window flag that was never given (it was one vague line before)."""
    import torch

    from spikenerf.recon.net import shipped_weights

    data = torch.load(shipped_weights(), weights_only=True)
    torch.save({**data, "hparams": {**data["hparams"], "window": 40}}, tmp_path / "even.pt")
    (tmp_path / "s.dat").write_bytes(bytes(50 * 2))  # 50 frames of 4×4
    args = ["--height", 4, "--width", 4, "--method", "learned", "--frame", 0, "--out", tmp_path / "o.npy"]
    weights = ["--weights", tmp_path / "even.pt"]
    code, _, err = run_cli(capsys, "reconstruct", tmp_path / "s.dat", *args, *weights)
    assert code == 2 and f"{tmp_path / 'even.pt'}: weights file hparams: window must be an odd" in err
    assert "found 40" in err and "--window" not in err and not (tmp_path / "o.npy").exists()


@pytest.mark.parametrize("case", ["truncated", "nan-targets", "short-targets"])
def test_a_recon_data_resume_writes_a_damaged_shard_again(capsys, tmp_path: Path, case: str) -> None:
    out = tmp_path / "p"
    assert run_cli(capsys, *DATA, "--out", out)[0] == 0
    before = load_split(out, "train")
    CASES[case][0](out)
    code, stdout, err = run_cli(capsys, *DATA, "--out", out)
    assert code == 0 and stdout.strip() == f"wrote {out}", err
    after = load_split(out, "train")
    assert after.info == before.info
    assert (after.spikes == before.spikes).all() and (after.targets == before.targets).all()
    code, stdout, err = run_cli(capsys, "recon-train", out, *TRAIN, "--out", tmp_path / "run")
    assert code == 0, err


def test_an_unfinished_pair_folder_is_refused_until_recon_data_finishes_it(
    capsys, pairs: Path, tmp_path: Path
) -> None:
    bad = tmp_path / "p"
    shutil.copytree(pairs, bad)
    _edit_manifest(bad, lambda m: m.pop("complete"))  # as a kill before the last shard leaves it
    code, _, err = run_cli(capsys, "recon-train", bad, *TRAIN, "--out", tmp_path / "run")
    assert code == 2 and "unfinished pair folder" in err and f"error: {bad}: " in err, err
    assert not (tmp_path / "run").exists()
    stale = bad / "train" / ".shard-00000.npz.x1b2c3d4.tmp"  # a killed writer's temporary, in a split folder
    stale.write_bytes(b"partial")
    write_pairs(bad, PairConfig(size=16, window=5, supersample=1), 2, 2, seed=0, progress=False)
    assert json.loads((bad / "manifest.json").read_text())["complete"] is True and not stale.exists()


def test_recon_train_is_reproducible_from_its_seed(capsys, pairs: Path, tmp_path: Path) -> None:
    import torch

    weights = []
    for name in ("a", "b"):
        torch.manual_seed(len(name) * 1000 + ord(name))  # the global RNG differs; --seed decides
        assert run_cli(capsys, "recon-train", pairs, *TRAIN, "--out", tmp_path / name)[0] == 0
        weights.append(torch.load(tmp_path / name / "weights.pt", weights_only=True)["state"])
    assert all(torch.equal(weights[0][k], weights[1][k]) for k in weights[0])


def test_a_diverged_recon_train_stops_with_one_line_naming_the_rate(
    capsys, pairs: Path, tmp_path: Path
) -> None:
    code, _, err = run_cli(capsys, "recon-train", pairs, *TRAIN, "--lr", "1e30", "--out", tmp_path / "run")
    last = err.strip().splitlines()[-1]  # after the progress bar's lines
    assert code == 2 and last.startswith("spikenerf: error: ") and "diverged; lower --lr" in last, err
    assert not (tmp_path / "run" / "weights.pt").exists()


def test_a_resume_with_fewer_iterations_is_refused_and_the_command_line_does_not_count(
    capsys, pairs: Path, tmp_path: Path
) -> None:
    run = tmp_path / "run"
    assert run_cli(capsys, "recon-train", pairs, *TRAIN, "--out", run)[0] == 0
    fewer = [*TRAIN[:1], 3, *TRAIN[2:]]
    code, _, err = run_cli(capsys, "recon-train", pairs, *fewer, "--out", run)
    assert code == 2 and "more than --iters 3" in err, err
    moved = tmp_path / "q"
    shutil.copytree(pairs, moved)
    _edit_manifest(moved, lambda m: m.update(command="spikenerf --threads 1 recon-data ..."))
    more = [*TRAIN[:1], 6, *TRAIN[2:]]
    code, _, err = run_cli(capsys, "recon-train", moved, *more, "--out", run)
    assert code == 0, err  # the same pairs, written by a command line that differs only in global flags
