"""``spikenerf recon-eval``: every method and step scored, TFP's error on a static scene within its bound,
bad input refused in one line with nothing written."""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from helpers import edit_json, run_cli
from spikenerf.capture.options import SimulateOptions
from spikenerf.capture.simulate import simulate_dataset
from spikenerf.core.errors import InputError
from spikenerf.eval.recon_scores import score_reconstructions
from spikenerf.scenes.analytic import AnalyticSource
from spikenerf.scenes.trajectory import novel_views, orbit

STEPS, GT_EVERY, WINDOW = 240, 40, 41


def _orbs(tmp_path_factory: pytest.TempPathFactory, name: str, turns: float) -> Path:
    """analytic-orbs at 24×24 on an orbit of ``turns`` turns over STEPS steps, gray + rgb."""
    traj = orbit(4.0, 30.0, turns=turns, duration=STEPS / 40000)
    source = AnalyticSource("analytic-orbs", 24, 24, traj, novel_views(4.0, 1), supersample=1)
    options = SimulateOptions(colors=("gray", "rgb"), gt_every=GT_EVERY, blur_fps=0.0)
    return simulate_dataset(source, tmp_path_factory.mktemp("recon-eval") / name, options, progress=False)


@pytest.fixture(scope="module")
def static(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A camera that stands still (an orbit of 0 turns)."""
    return _orbs(tmp_path_factory, "static", 0.0)


def test_scores_every_method_and_step(
    static: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "scores"
    code, stdout, err = run_cli(capsys, "recon-eval", static, "--lpips", "none", "--quiet", "--out", out)
    assert code == 0, err
    result = json.loads((out / "scores.json").read_text())
    steps = list(range(0, STEPS, GT_EVERY))
    assert result["steps"] == steps and result["color"] == "gray" and list(result["methods"]) == [
        "tfp", "tfi", "tfstp", "learned"
    ]  # fmt: skip
    assert [(r["method"], r["step"]) for r in result["rows"]] == [
        (m, s) for m in ("tfp", "tfi", "tfstp", "learned") for s in steps
    ]
    assert result["methods"]["tfp"]["window"] == WINDOW and result["methods"]["tfi"]["window"] is None
    assert result["methods"]["tfstp"]["window"] is None
    for name, summary in result["methods"].items():  # the means are the plain means of the rows
        own = [r for r in result["rows"] if r["method"] == name]
        assert summary["mean"]["psnr"] == pytest.approx(np.mean([r["psnr"] for r in own]))
        assert summary["mean"]["lpips"] is None and all(r["lpips"] is None for r in own)
    with open(out / "scores.csv", newline="") as fh:
        table = list(csv.DictReader(fh))
    assert len(table) == 4 * len(steps) and table[0]["lpips"] == ""
    assert float(table[0]["psnr"]) == pytest.approx(result["rows"][0]["psnr"], rel=1e-5)
    assert json.loads((out / ".spikenerf").read_text())["kind"] == "scores"
    assert "tfp" in stdout and "learned" in stdout and "PSNR (dB)" in stdout
    # once written, the same --out is refused without --overwrite, then replaced with it
    code, _, err = run_cli(capsys, "recon-eval", static, "--methods", "tfp", "--lpips", "none", "--out", out)
    assert code == 2 and "--overwrite" in err and len(err.strip().splitlines()) == 1
    code, _, err = run_cli(capsys, "recon-eval", static, "--methods", "tfp", "--count", "2",
                           "--lpips", "none", "--quiet", "--overwrite", "--out", out)  # fmt: skip
    assert code == 0, err
    again = json.loads((out / "scores.json").read_text())
    assert list(again["methods"]) == ["tfp"] and again["steps"] == [steps[0], steps[-1]]


@pytest.mark.parametrize("color", ["gray", "rgb"])
def test_tfp_on_a_static_scene_is_within_its_error_bound(static: Path, color: str) -> None:
    """An ideal pixel fires ⌊mI⌋ or ⌈mI⌉ times in any m steps, so |TFP − I| < 1/|W_k| (test_reconstruct.py's
    bound) against the sharp GT, here in linear units after the GT's 16-bit sRGB round trip (≤ 2e-5)."""
    result = score_reconstructions(static, "tfp", color=color, lpips_backbone=None, progress=False)
    half = WINDOW // 2
    for row in result["rows"]:
        k = row["step"]
        used = min(k + half + 1, STEPS) - max(k - half, 0)
        assert row["max_error"] <= 1.0 / used + 1e-4, (k, row["max_error"])
    middle = [r["max_error"] for r in result["rows"] if half <= r["step"] < STEPS - half]
    assert max(middle) > 0.25 / WINDOW  # the bound is tight, not vacuous
    assert result["methods"]["tfp"]["mean"]["psnr"] > 35  # and the comparison is in one colour space


def test_the_learned_weights_are_read_once(static: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """recon-eval's learned method loads its weights file once: the same network reconstructs every step
    and gives the trained window (it was read twice, once for each)."""
    from spikenerf.recon import net

    loads: list[object] = []
    real = net.load_weights

    def counted(*args: object, **kwargs: object) -> object:
        loads.append(args[0] if args else kwargs.get("path"))
        return real(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(net, "load_weights", counted)
    result = score_reconstructions(static, "learned", count=2, lpips_backbone=None, progress=False)
    assert loads == [None] and len(result["rows"]) == 2
    assert result["methods"]["learned"]["window"] == real()[0].config.window


def test_an_interrupted_write_never_leaves_a_mismatched_pair(
    static: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """scores.csv and scores.json are one commit: cut between the CSV's rename and the JSON's, the old JSON
    is already gone (no stale pair), the reader and info refuse the lone CSV, and recon-eval writes the pair
    again without --overwrite; a CSV that is not the JSON's rows is caught."""
    from spikenerf.core import atomic
    from spikenerf.eval.recon_scores import pair_problem, read_scores, write_scores

    first = score_reconstructions(static, "tfp", count=2, lpips_backbone=None, progress=False)
    second = score_reconstructions(static, "tfi", count=3, lpips_backbone=None, progress=False)
    out = tmp_path / "pair"
    write_scores(out, first)
    assert read_scores(out) == first and pair_problem(out) == ""

    def cut(name: str) -> None:
        if name == "write:scores.json":
            raise KeyboardInterrupt

    with monkeypatch.context() as patch:
        patch.setattr(atomic, "failpoint", cut)
        with pytest.raises(KeyboardInterrupt):
            write_scores(out, second)
    assert not (out / "scores.json").exists()  # (it was the first pair's: never beside the second CSV)
    assert "interrupted" in pair_problem(out) and sorted(p.name for p in out.iterdir()) == ["scores.csv"]
    with pytest.raises(InputError, match="run recon-eval into it again"):
        read_scores(out)
    write_scores(out, second)
    (out / "scores.csv").write_text((out / "scores.csv").read_text().replace("tfi", "tfp"))
    assert "mismatched" in pair_problem(out)
    # the command: a first write cut short is still recon-eval's folder, refused by info, rewritten by a rerun
    cli_out = tmp_path / "cli"
    with monkeypatch.context() as patch:
        patch.setattr(atomic, "failpoint", cut)
        code, _, _ = run_cli(capsys, "recon-eval", static, "--methods", "tfp", "--count", "2", "--lpips",
                             "none", "--quiet", "--out", cli_out)  # fmt: skip
        assert code != 0 and not (cli_out / "scores.json").exists()
    assert json.loads((cli_out / ".spikenerf").read_text())["kind"] == "scores"
    code, _, err = run_cli(capsys, "info", cli_out)
    assert code == 2 and "unfinished scores" in err and "interrupted" in err
    code, _, err = run_cli(capsys, "recon-eval", static, "--methods", "tfp", "--count", "2", "--lpips",
                           "none", "--quiet", "--out", cli_out)  # fmt: skip
    assert code == 0 and "replacing the unfinished scores" in err, err
    assert read_scores(cli_out)["rows"] == first["rows"]


def _refused(capsys: pytest.CaptureFixture[str], out: Path, *args: object) -> str:
    code, _, err = run_cli(capsys, "recon-eval", *args, "--lpips", "none", "--out", out)
    assert code == 2, (args, err)
    assert len(err.strip().splitlines()) == 1 and err.startswith("spikenerf: error: "), err
    assert not out.exists() and not any(out.parent.glob(f".{out.name}*")), "partial output"
    return err


def test_bad_input_exits_2_in_one_line_and_writes_nothing(
    static: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "scores"
    assert "--methods" in _refused(capsys, out, static, "--methods", "tfp,bogus")
    assert "--methods" in _refused(capsys, out, static, "--methods", "tfp,tfp")
    assert "--steps" in _refused(capsys, out, static, "--steps", "5:3")
    assert "--steps" in _refused(capsys, out, static, "--steps", "1:30")  # holds no gt frame
    assert "--steps" in _refused(capsys, out, static, "--steps", "0:9999")
    assert "--window" in _refused(capsys, out, static, "--methods", "tfi", "--window", "21")
    even = _refused(capsys, out, static, "--methods", "tfp", "--window", "20")
    assert "--window" in even and "spikes_gray.dat" not in even  # the flag's fault, not the stream's
    assert "--color" in _refused(capsys, out, static, "--color", "bayer")  # not recorded
    assert "--out" in _refused(capsys, static / "inside", static)  # inside the dataset
    # an imported recording has no sharp gt/ frames: scoring needs them
    bare = tmp_path / "bare"
    shutil.copytree(static, bare)
    edit_json(bare / "transforms.json", lambda meta: [f.pop("file_path", None) for f in meta["frames"]])
    assert "needs ground truth" in _refused(capsys, out, bare)


@pytest.fixture(scope="module")
def moving(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One orbit turn."""
    return _orbs(tmp_path_factory, "moving", 1.0)


def test_each_step_is_reconstructed_at_its_own_frame(moving: Path) -> None:
    """On a moving camera the scores are those of TFP and TFI taken at each GT step's own stream frame
    (computed here directly from the stream), not at a neighbour's: an off-by-one would change the error."""
    from spikenerf.camera.io import read_dat
    from spikenerf.camera.reconstruct import tfi, tfp
    from spikenerf.core.color import rgb_to_gray
    from spikenerf.data.dataset import load_dataset

    root = moving
    result = score_reconstructions(root, "tfp,tfi", lpips_backbone=None, progress=False)
    dataset = load_dataset(root)
    spikes = read_dat(root / "spikes_gray.dat", 24, 24)
    gray = np.asarray(rgb_to_gray(dataset.gt.images.astype(np.float32), channel_axis=-1))
    for row in result["rows"]:
        frame = int(np.searchsorted(dataset.trajectory.steps, row["step"]))
        estimate = {"tfp": lambda f: tfp(spikes, WINDOW, frames=f), "tfi": lambda f: tfi(spikes, frames=f)}
        errors = [
            float(np.abs(np.clip(estimate[row["method"]](f), 0, 1) - gray[frame // GT_EVERY]).mean())
            for f in (frame, min(frame + 3, STEPS - 1))
        ]
        assert row["mae"] == pytest.approx(errors[0], rel=1e-4, abs=1e-6)
        assert abs(row["mae"] - errors[1]) > 1e-4  # the neighbour frame differs: the check can fail


@pytest.mark.parametrize(("color", "count"), [("gray", None), ("gray", 4), ("rgb", 3)])
def test_all_frames_at_once_equal_the_per_frame_path(
    moving: Path, monkeypatch: pytest.MonkeyPatch, color: str, count: int | None
) -> None:
    """Each method reconstructs its GT frames in one call (TFSTP: one scan of each stream from frame 0, not
    one per frame), and every score equals the one-call-per-frame path's, bit for bit (evenly spaced GT
    frames and, with --count 4 of 6, uneven ones)."""
    from spikenerf.camera import reconstruct
    from spikenerf.data.reconstruction import reconstructor
    from spikenerf.eval import recon_scores

    scans: list[int] = []
    real = reconstruct.tfstp
    monkeypatch.setattr(reconstruct, "tfstp", lambda *a, **k: scans.append(1) or real(*a, **k))
    kwargs = {"color": color, "count": count, "lpips_backbone": None, "progress": False}
    batched = score_reconstructions(moving, "tfp,tfi,tfstp", **kwargs)
    assert len(scans) == (3 if color == "rgb" else 1)  # one per stream file
    frames = len(batched["steps"])
    assert frames == (count or STEPS // GT_EVERY)

    def per_frame(name: str, window: int | None = None, threshold: float = 1.0, **kw: object) -> object:
        one = reconstructor(name, window, threshold, **kw)
        return lambda read, total, idx: np.stack([one(read, total, int(k), int(k) + 1)[0] for k in idx])

    monkeypatch.setattr(recon_scores, "frames_reconstructor", per_frame)
    scans.clear()
    single = score_reconstructions(moving, "tfp,tfi,tfstp", **kwargs)
    assert len(scans) == frames * (3 if color == "rgb" else 1)  # (the path compared against)
    assert batched["rows"] == single["rows"] and batched["steps"] == single["steps"]
    for name in ("tfp", "tfi", "tfstp"):
        assert batched["methods"][name]["mean"] == single["methods"][name]["mean"]
