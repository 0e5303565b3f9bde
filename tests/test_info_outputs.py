"""What recon-data, recon-train and reconstruct write and read: ``info`` summarises their folders (it gave an
error line naming only the kind of folder), and reconstruct says when its φ differs from the recording's."""

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
    (frames / "00005.png").rename(frames / "100000.png")  # past 99999 the names grow: ordered as numbers
    assert "(00003 to 100000)" in run_cli(capsys, "info", frames)[1]


def test_info_counts_the_photograph_and_source_draws_of_a_pair_folder(capsys, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """``recon-data --natural 600 --train-draws 800`` was summarised as "800 training" draws."""
    import json

    pairs = tmp_path / "pairs"
    write_pairs(pairs, PairConfig(size=16, window=5, supersample=1), 2, 2, seed=0, progress=False)
    manifest = json.loads((pairs / "manifest.json").read_text())
    assert "draws: 2 training (1 shard file)" in run_cli(capsys, "info", pairs)[1]  # extra_draws 0 sources
    manifest.update(natural_draws=3, extra_sources=["bricks", "shots.json"], extra_draws=5)
    (pairs / "manifest.json").write_text(json.dumps(manifest))
    code, out, err = run_cli(capsys, "info", pairs)
    assert code == 0, err
    assert "draws: 2 training + 3 from photographs + 5 from each of bricks, shots.json (1 shard file)" in out


def test_reconstruct_warns_when_its_threshold_differs_from_the_recordings(capsys, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """``--threshold 2`` against a recorded φ of 1 was taken without a word (``info`` warns on ``--fps``)."""
    dat = write_recording(tmp_path / "rec" / "r.dat", 20, 8, 12)
    with (dat.parent / "config.yaml").open("a") as f:
        f.write("threshold: 1.0\n")
    for threshold, said in ((2, "--threshold 2 differs from threshold 1 in"), (1, "")):
        args = [
            "--method",
            "tfp",
            "--threshold",
            threshold,
            "--frame",
            0,
            "--out",
            tmp_path / f"{threshold}.png",
        ]
        code, _, err = run_cli(capsys, "reconstruct", dat, *args)
        assert code == 0 and (said in err if said else "differs" not in err), err


def test_reconstruct_messages_say_what_is_missing(capsys, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    dat = write_recording(tmp_path / "rec" / "r.dat", 20, 8, 12)
    (dat.parent / "config.yaml").unlink()
    tfp = ["--method", "tfp", "--frame", 0, "--out", tmp_path / "a.png"]
    code, _, err = run_cli(
        capsys, "reconstruct", dat, "--height", 8, *tfp
    )  # read "pass --height and --width"
    assert code == 2 and err.strip().endswith("pass --width too"), err
    code, _, err = run_cli(capsys, "reconstruct", dat.parent, *tfp)  # a folder: which file in it
    assert code == 2 and err.strip().endswith("give a recording file in it (r.dat)"), err
    code, _, err = run_cli(capsys, "reconstruct", tmp_path / "rec" / "..", *tfp)
    assert code == 2 and err.strip().endswith("it holds no .dat file"), err
    code, _, err = run_cli(  # negative indices are taken: the message said "need 0 <= start"
        capsys, "reconstruct", dat, "--height", 8, "--width", 12, "--method", "tfp", "--frames", "-40:-30",
        "--out", tmp_path / "b.npy",
    )  # fmt: skip
    assert code == 2 and "a negative index counting from the end: -20 is 0" in err, err


def test_the_recorded_layout_is_read_and_a_differing_one_warned(capsys, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """``--layout topdown`` against a dataset's ``layout: spikecv`` gave an upside-down image silently."""
    import numpy as np

    dat = write_recording(tmp_path / "rec" / "r.dat", 20, 8, 12)
    config = dat.parent / "config.yaml"
    base = config.read_text()
    args = ["--method", "tfp", "--frame", 5]

    def frame(name: str, *extra: object) -> tuple[np.ndarray, str]:
        code, _, err = run_cli(capsys, "reconstruct", dat, *args, *extra, "--out", tmp_path / name)
        assert code == 0, err
        return np.load(tmp_path / name), err

    plain, _ = frame("plain.npy")
    config.write_text(base + "layout: topdown\n")
    recorded, err = frame("recorded.npy")  # the config's layout, unasked
    assert "warning" not in err and np.array_equal(recorded, plain[::-1])
    given, err = frame("given.npy", "--layout", "spikecv")
    assert np.array_equal(given, plain) and "--layout spikecv differs from layout topdown in" in err
    code, out, err = run_cli(capsys, "info", dat)
    assert code == 0 and "layout topdown" in out, err
    config.write_text(base + "layout: sideways\n")
    code, _, err = run_cli(capsys, "reconstruct", dat, *args, "--out", tmp_path / "x.npy")
    assert code == 2 and "field 'layout': expected one of spikecv, topdown, found 'sideways'" in err, err
