"""``spikenerf info`` on what recon-data, recon-train and reconstruct write: a summary, not an error line that
only named the kind of folder (exit 2)."""

from __future__ import annotations

from pathlib import Path

from helpers import run_cli, write_recording
from spikenerf.recon.generate import write_pairs
from spikenerf.recon.pairs import PairConfig

TRAIN = ["--iters", 4, "--batch", 2, "--crop", 16, "--width", 4, "--eval-every", 2, "--ckpt-every", 2]


def test_info_summarises_pair_recon_and_frame_folders(capsys, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    pairs, run = tmp_path / "pairs", tmp_path / "run"
    write_pairs(pairs, PairConfig(size=16, window=5, supersample=1), 2, 2, seed=0, progress=False)
    code, out, err = run_cli(capsys, "info", pairs)
    assert code == 0, err
    assert "recon-data pair folder: 16×16 pairs of a 5-step window" in out
    assert "draws: 2 training (1 shard file), 2 held-out" in out and f"recon-train {pairs} --out RUN" in out
    assert run_cli(capsys, "--quiet", "recon-train", pairs, "--out", run, *TRAIN)[0] == 0
    code, out, err = run_cli(capsys, "info", run)
    assert code == 0, err
    assert "recon-train folder: 4 iterations of 2 crops of 16 px, width 4" in out
    assert "curves: iteration 4" in out and "finished in" in out
    assert f"--method learned --weights {run / 'weights.pt'}" in out
    (run / "weights.pt").unlink()  # as if interrupted before the end
    assert "unfinished: run its command again" in run_cli(capsys, "info", run)[1]
    (run / "config.json").write_text("[1")
    code, _, err = run_cli(capsys, "info", run)
    assert code == 2 and err.strip().endswith("config.json: malformed JSON (JSONDecodeError)"), err
    dat = write_recording(tmp_path / "rec" / "r.dat", 20, 8, 12)
    frames = tmp_path / "frames"
    assert run_cli(capsys, "reconstruct", dat, "--method", "tfp", "--frames", "3:6", "--out", frames)[0] == 0
    code, out, err = run_cli(capsys, "info", frames)
    assert code == 0 and out.strip() == "reconstruct frame folder: 3 frames (00003 to 00005), 12×8 gray", err
