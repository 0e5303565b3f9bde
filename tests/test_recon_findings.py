"""recon-data / recon-train defects from a user walkthrough: each refusal is one line naming the file and
the flags, exit 2, nothing half-written; bars only on a terminal; the manifest lists what was drawn."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from helpers import run_cli
from spikenerf.core.errors import InputError
from spikenerf.recon.describe import describe_recon
from spikenerf.recon.generate import write_pairs
from spikenerf.recon.pairs import PairConfig, Sample
from spikenerf.recon.store import write_shard

CFG = PairConfig(size=16, window=5, supersample=1)
TRAIN = ["--batch", 2, "--crop", 16, "--width", 4]


@pytest.fixture(scope="module")
def pairs(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("pairs") / "p"
    write_pairs(root, CFG, 2, 2, seed=0, progress=False)
    return root


def _train(capsys, pairs: Path, out: Path, *args: object) -> tuple[int, str]:
    code, _, err = run_cli(capsys, "recon-train", pairs, "--out", out, *TRAIN, *args)
    return code, err


def test_recon_train_refuses_a_garbled_curves_file_in_one_line(capsys, pairs: Path, tmp_path: Path) -> None:
    """Finding 1: a resume reads curves.csv as `train --resume` does: a row that is no numbers is refused
    in one line naming the file, before anything is written (was a ValueError traceback)."""
    run = tmp_path / "run"
    code, err = _train(capsys, pairs, run, "--iters", 2, "--eval-every", 1)
    assert code == 0, err
    config = (run / "config.json").read_text()
    (run / "curves.csv").write_text("iteration,train_l1,val_psnr_learned,val_psnr_tfp,seconds\nabc,1,2,3,4\n")
    checkpoint = (run / "checkpoint.pt").read_bytes()
    code, err = _train(capsys, pairs, run, "--iters", 4, "--eval-every", 1)
    assert code == 2 and err.count("\n") == 1, err
    assert err.startswith(f"spikenerf: error: {run / 'curves.csv'}: not a curve table") and "line 2" in err
    assert (run / "checkpoint.pt").read_bytes() == checkpoint and (run / "config.json").read_text() == config
    for text in ("a,b\n1,2\n", "iteration,train_l1,val_psnr_learned,val_psnr_tfp,seconds\n2,1\n"):
        (run / "curves.csv").write_text(text)  # a foreign header; a row cut short
        code, err = _train(capsys, pairs, run, "--iters", 4, "--eval-every", 1)
        assert code == 2 and err.count("\n") == 1 and "curves.csv: not a curve table" in err, err
    (run / "curves.csv").write_text("")  # zero bytes (what a crash may leave): written again
    code, err = _train(capsys, pairs, run, "--iters", 4, "--eval-every", 1)
    assert code == 0, err
    assert [r.split(",")[0] for r in (run / "curves.csv").read_text().splitlines()[1:]] == ["3", "4"]


def test_recon_data_refuses_a_brightness_past_float32(capsys, tmp_path: Path) -> None:
    """Finding 3: --brightness is bounded up front, saying why; nothing is written."""
    for value in ("1e300:1e301", "1:1e7", "nan:1"):
        code, _, err = run_cli(capsys, "recon-data", "--out", tmp_path / "p", "--brightness", value)
        assert code == 2 and err.count("\n") == 1, err
        assert "--brightness must be LO:HI" in err and "float32" in err and "1e+06" in err, err
    assert not (tmp_path / "p").exists()
    with pytest.raises(InputError, match="brightness") as caught:
        write_pairs(tmp_path / "p", PairConfig(size=16, window=5, brightness=(1.0, 1e301)), 2, 2)
    assert caught.value.params == ("brightness",) and not (tmp_path / "p").exists()


def test_pairs_whose_targets_are_not_finite_are_never_written(tmp_path: Path) -> None:
    """Finding 3: what the bound leaves (a tiny threshold) is refused at the first draw, naming the flags,
    without a warning, and the folder it had begun goes; write_shard itself refuses such targets."""
    cfg = PairConfig(size=16, window=5, supersample=1, brightness=(1e6, 1e6), threshold=1e-38)
    with pytest.raises(InputError, match=r"targets that are not finite") as caught:
        write_pairs(tmp_path / "p", cfg, 2, 2, progress=False)
    assert caught.value.params == ("brightness", "threshold") and not (tmp_path / "p").exists()
    sample = Sample(np.zeros((5, 16, 16), bool), np.full((16, 16), np.inf, np.float32), {})
    with pytest.raises(ValueError, match="not finite"):
        write_shard(tmp_path / "s" / "shard-00000.npz", [sample])
    assert not (tmp_path / "s" / "shard-00000.npz").exists()


def test_a_diverged_recon_run_says_how_to_go_on(capsys, pairs: Path, tmp_path: Path) -> None:
    """Finding 4: a run that diverges before its first checkpoint leaves no folder (the same command with a
    lower --lr runs); one with a checkpoint says to use a new --out folder; finding 6: the resume refusal
    names the changed settings as flags."""
    run = tmp_path / "run"
    code, err = _train(capsys, pairs, run, "--iters", 10, "--lr", 1e30)
    assert code == 2 and err.count("\n") == 1, err
    assert "the run diverged; lower --lr and train again (it wrote no checkpoint: nothing is kept)" in err
    assert not run.exists() and not list(tmp_path.iterdir())
    code, err = _train(capsys, pairs, run, "--iters", 10, "--lr", 1e30, "--ckpt-every", 1)
    assert code == 2 and err.count("\n") == 1, err
    assert "diverged; lower --lr and train again into a new --out folder, or delete this one" in err
    assert "its checkpoint of iteration " in err and (run / "checkpoint.pt").is_file()
    code, err = _train(capsys, pairs, run, "--iters", 10, "--lr", 1e-3, "--ckpt-every", 2)
    assert code == 2 and err.count("\n") == 1, err
    assert f"{run}: --out holds a run with other settings (--lr 1e+30 → 0.001, --ckpt-every 1 → 2)" in err
    assert "(only --iters may change)" in err


def test_a_recon_resume_with_fewer_iters_names_the_out_flag(capsys, pairs: Path, tmp_path: Path) -> None:
    """Finding 7: "out" in the message is the flag --out."""
    run = tmp_path / "run"
    assert _train(capsys, pairs, run, "--iters", 3)[0] == 0
    code, err = _train(capsys, pairs, run, "--iters", 2)
    assert code == 2 and err.count("\n") == 1, err
    assert f"{run}: --out holds a run of 3 iterations, more than --iters 2" in err


def test_recon_bars_only_on_a_terminal(capsys, tmp_path: Path) -> None:
    """Finding 12: like reconstruct, recon-data and recon-train draw bars only on a terminal (here stderr
    is captured, so it stays empty)."""
    data = ["recon-data", "--train-draws", 2, "--val-draws", 2, "--size", 16, "--window", 5]
    code, _, err = run_cli(capsys, *data, "--out", tmp_path / "p")
    assert code == 0 and err == "", err
    code, err = _train(capsys, tmp_path / "p", tmp_path / "run", "--iters", 2)
    assert code == 0 and err == "", err


def test_the_manifest_lists_only_the_photographs_drawn(tmp_path: Path) -> None:
    """Finding 16: fewer than 4 val draws draw no held-out photograph, so val_scenes lists none; a folder
    written before, which listed them, still resumes (its manifest corrected)."""
    pytest.importorskip("skimage")
    manifest = write_pairs(tmp_path / "p", CFG, 1, 2, seed=0, natural_draws=1, progress=False)
    assert not [s for s in manifest["val_scenes"] if s.startswith("natural:")]
    assert manifest["val_scenes"][0] == "analytic-orbs" and "analytic-blocks" not in manifest["val_scenes"]
    drawn = {
        json.loads(i)["scene"] for f in (tmp_path / "p" / "val").glob("*.npz") for i in np.load(f)["info"]
    }
    assert drawn == {"analytic-orbs", "random-15838-0"}  # one named draw: blocks is never drawn
    path = tmp_path / "p" / "manifest.json"
    old = json.loads(path.read_text())
    old["val_scenes"] += ["natural:camera"]
    del old["complete"]
    path.write_text(json.dumps(old))
    shutil.rmtree(tmp_path / "p" / "val")
    again = write_pairs(tmp_path / "p", CFG, 1, 2, seed=0, natural_draws=1, progress=False)
    assert again["val_scenes"] == manifest["val_scenes"] == json.loads(path.read_text())["val_scenes"]
    with pytest.raises(InputError, match=r"other settings \(val_draws 2 → 3\)"):
        write_pairs(tmp_path / "p", CFG, 1, 3, seed=0, natural_draws=1, progress=False)


def test_recon_data_names_the_scene_flag(capsys, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """An unknown --scene was named ``scene:`` (its parameter is ``scenes``: no flag was found for it)."""
    code, _, err = run_cli(capsys, "recon-data", "--scene", "nosuch", "--out", tmp_path / "p")
    assert code == 2 and err.startswith("spikenerf: error: --scene: unknown scene 'nosuch'"), err
    assert not (tmp_path / "p").exists()


def _recon_folder(root: Path, iters: int, weights_iters: int) -> Path:
    """A recon-train folder as the trainer leaves it: config.json of the current call (``iters``), the
    curves of the last evaluation, and weights.pt/weights.json written at the end of a run of
    ``weights_iters`` iterations."""
    root.mkdir()
    cfg = {"iters": iters, "batch": 4, "crop": 16, "width": 8, "lr": 0.002}
    (root / "config.json").write_text(json.dumps({"config": cfg, "pairs": "pairs", "command": "cmd"}))
    (root / "curves.csv").write_text(
        "iteration,train_l1,val_psnr_learned,val_psnr_tfp,seconds\n350,0.25,33.0,27.6,4.7\n"
    )
    (root / "weights.pt").write_bytes(b"weights")
    summary = {"config": {**cfg, "iters": weights_iters}, "seconds": 7.5, "val_psnr_learned": 33.2,
               "val_psnr_tfp": 27.7}  # fmt: skip
    (root / "weights.json").write_text(json.dumps(summary))
    return root


def test_info_of_an_interrupted_longer_resume_is_not_described_as_finished(tmp_path: Path) -> None:
    """A finished 300-iteration run resumed with --iters 600 and killed at 350 still holds the weights.pt of
    the 300-iteration run; info must say the run is unfinished, not offer those weights as its result."""
    text = describe_recon(_recon_folder(tmp_path / "run", iters=600, weights_iters=300))
    assert "finished in" not in text and "use it:" not in text, text
    assert "unfinished" in text and "300 iterations" in text, text


def test_info_of_a_finished_recon_run_is_still_described_as_finished(tmp_path: Path) -> None:
    text = describe_recon(_recon_folder(tmp_path / "run", iters=600, weights_iters=600))
    assert "finished in 7.5 s" in text and "use it:" in text and "unfinished" not in text, text
