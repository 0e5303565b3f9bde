"""The learned reconstructor: pairs, network, tiling, training/resume, shipped weights and bad input."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from helpers import run_cli
from spikenerf.camera.io import write_dat
from spikenerf.core.errors import InputError
from spikenerf.recon.config import ReconTrainConfig
from spikenerf.recon.generate import write_pairs
from spikenerf.recon.infer import predict_plane, reconstruct_learned
from spikenerf.recon.net import NetConfig, ReconNet, load_weights, save_weights
from spikenerf.recon.pairs import PairConfig, analytic_pairs, simulate_samples
from spikenerf.recon.store import load_split
from spikenerf.recon.training import rate_psnr, train_memory, train_recon

TINY = PairConfig(size=16, window=7, supersample=1)


def test_pairs_have_the_window_and_target_shapes_of_each_colour_mode() -> None:
    samples = list(analytic_pairs(None, range(6), TINY, seed=3))
    counts = {"gray": 1, "rgb": 3, "bayer": 4}
    per_draw: dict[str, list[str]] = {}
    for s in samples:
        per_draw.setdefault(s.info["scene"], []).append(s.info["mode"])
    assert len(per_draw) == 6
    assert all(len(m) == counts[m[0]] and len(set(m)) == 1 for m in per_draw.values())
    for s in samples:
        assert s.window.shape == (7, 16, 16) and s.window.dtype == bool
        assert s.target.shape == (16, 16) and s.target.dtype == np.float32
        assert s.target.min() >= 0 and s.target.max() <= 1.0 + 1e-6


def test_the_target_is_the_middle_step_and_the_window_is_in_time_order() -> None:
    k, c = 9, 4
    # dark before the middle step, white from it on: an ideal pixel cannot fire before step c, fires at every
    # step from c + 1 on, and the target is the frame of step c
    frames = np.zeros((k, 3, 8, 8), np.float32)
    frames[c:] = 1.0
    frames[c] = 0.5
    (s,) = simulate_samples(frames, "gray", "ideal", PairConfig(window=k), seed=1, info={})
    assert not s.window[:c].any()
    assert s.window[c + 1 :].all()
    np.testing.assert_allclose(s.target, 0.5, atol=1e-6)
    rgb = simulate_samples(
        frames * np.array([0.2, 0.4, 0.6], np.float32)[:, None, None],
        "rgb",
        "ideal",
        PairConfig(window=k),
        seed=1,
        info={},
    )
    assert [round(float(r.target.mean()), 3) for r in rgb] == [0.1, 0.2, 0.3]


@pytest.mark.parametrize("max_speed", [0.0, 0.03, 1.5])  # below 0.06 a pan's range started above its end
def test_motions_stay_under_any_max_speed(max_speed: float) -> None:
    from spikenerf.recon.pairs import motion_poses

    rng = np.random.default_rng(0)
    speeds = [motion_poses(rng, 5, max_speed)[1]["speed"] for _ in range(60)]
    assert all(0 <= v <= max_speed for v in speeds) and (max(speeds) > 0) == (max_speed > 0)
    from spikenerf.recon.natural import motion_grids

    speeds = [motion_grids(rng, (64, 64), 16, 5, max_speed, 1)[1]["speed"] for _ in range(60)]  # --natural
    assert all(0 <= v <= max_speed for v in speeds) and (max(speeds) > 0) == (max_speed > 0)


def test_network_shapes_and_tiled_inference_matches_untiled() -> None:
    torch.manual_seed(0)
    net = ReconNet(NetConfig(window=7, width=8)).eval()
    with torch.no_grad():
        out = net(torch.rand(2, 7, 13, 18).round(), torch.tensor([0.5, 0.3]))
    assert out.shape == (2, 13, 18) and (out >= 0).all()
    window = (np.random.default_rng(0).random((7, 100, 130)) < 0.4).astype(np.uint8)
    whole, tiled = predict_plane(net, window, tile=512), predict_plane(net, window, tile=32)
    assert np.abs(whole - tiled).max() < 2e-3 * max(float(np.abs(whole).max()), 1e-3)


@pytest.fixture(scope="module")
def pairs(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("pairs")
    write_pairs(root, PairConfig(size=20, window=7, supersample=1), 6, 2, seed=0, progress=False)
    return root


def _cfg(**kw) -> ReconTrainConfig:
    return ReconTrainConfig(
        **{
            "iters": 6,
            "batch": 4,
            "crop": 16,
            "width": 8,
            "eval_every": 3,
            "ckpt_every": 2,
            "val_samples": 4,
            **kw,
        }
    )


def test_training_reduces_the_loss_and_resumes_bit_identically(pairs: Path, tmp_path: Path) -> None:
    torch.set_num_threads(1)
    train_set = load_split(pairs, "train")
    index = torch.arange(min(8, len(train_set)))
    win, tgt = train_set.windows(index), train_set.targets[index]
    scale = win.mean(dim=(1, 2, 3)).clamp_min(1e-2)
    torch.manual_seed(0)
    with torch.no_grad():
        before = float((ReconNet(NetConfig(window=7, width=8)).eval()(win, scale) - tgt).abs().mean())
    torch.manual_seed(0)
    train_recon(pairs, tmp_path / "a", _cfg(iters=30, lr=5e-3, eval_every=30, ckpt_every=30), progress=False)
    net, meta = load_weights(tmp_path / "a" / "weights.pt")
    with torch.no_grad():
        after = float((net(win, scale) - tgt).abs().mean())
    assert after < 0.9 * before
    assert meta["modes"] == ["gray", "rgb", "bayer"] and meta["record"]["train_samples"] == len(train_set)
    torch.manual_seed(0)
    train_recon(pairs, tmp_path / "b", _cfg(), progress=False)
    torch.manual_seed(0)
    assert train_recon(pairs, tmp_path / "c", _cfg(), progress=False, stop_at=3) == {"iteration": 3}
    train_recon(pairs, tmp_path / "c", _cfg(), progress=False)
    a = torch.load(tmp_path / "b" / "checkpoint.pt", weights_only=True)
    b = torch.load(tmp_path / "c" / "checkpoint.pt", weights_only=True)
    assert a["iteration"] == b["iteration"] == 6
    for key, value in a["model"].items():
        assert torch.equal(value, b["model"][key]), key
    assert (tmp_path / "c" / "curves.csv").read_text().count("\n") == 3  # header + iterations 3 and 6
    # the running L1 (column 2) continues across the resume; the time (last column) differs
    rows = [[r.split(",")[:4] for r in (tmp_path / d / "curves.csv").read_text().splitlines()] for d in "bc"]
    assert rows[0] == rows[1]
    other = tmp_path / "other_pairs"  # same samples, another manifest: refused
    shutil.copytree(pairs, other)
    manifest = json.loads((other / "manifest.json").read_text())
    (other / "manifest.json").write_text(json.dumps({**manifest, "seed": -1}))
    with pytest.raises(InputError, match="another pair folder"):
        train_recon(other, tmp_path / "c", _cfg(iters=9), progress=False)


def test_shipped_weights_beat_tfp_on_a_held_out_analytic_scene() -> None:
    net, meta = load_weights(None, "gray")
    k = net.config.window
    cfg = PairConfig(size=32, window=k, modes=("gray",), noises=("ideal", "realistic"), brightness=(0.1, 0.6))
    samples = list(analytic_pairs(["analytic-orbs"], range(4), cfg, seed=12345))
    win = torch.from_numpy(np.stack([s.window for s in samples])).float()
    tgt = torch.from_numpy(np.stack([s.target for s in samples]))
    with torch.no_grad():
        learned = rate_psnr(net(win, win.mean(dim=(1, 2, 3)).clamp_min(1e-2)), tgt).mean()
    tfp = rate_psnr(win.mean(1), tgt).mean()
    assert learned > tfp + 1.0, (float(learned), float(tfp))
    assert set(meta["modes"]) == {"gray", "rgb", "bayer"} and "command" in meta["record"]


def test_in_memory_learned_reconstruction_of_a_stream_uses_mirrored_edges() -> None:
    net, _ = load_weights(None)
    k = net.config.window
    spikes = np.ones((k + 2, 3, 8, 8), np.uint8)
    out = reconstruct_learned(spikes, "rgb", threshold=2.0, frames=slice(0, 2))
    assert out.shape == (2, 3, 8, 8)
    np.testing.assert_allclose(out, 2.0, rtol=0.15)  # a white stream reconstructs as φ


def test_in_memory_learned_reconstruction_honours_the_slice_step(tmp_path: Path) -> None:
    from spikenerf.core.errors import InputError

    weights = _weights(tmp_path / "w.pt", ["gray"])
    spikes = (np.random.default_rng(2).random((12, 8, 8)) < 0.5).astype(np.uint8)
    every = reconstruct_learned(spikes, "gray", weights=weights)
    for sel in (slice(1, 9, 3), slice(None, None, -5)):
        got = reconstruct_learned(spikes, "gray", weights=weights, frames=sel)
        np.testing.assert_array_equal(got, every[sel])
    with pytest.raises(InputError, match="frames"):
        reconstruct_learned(spikes, "gray", weights=weights, frames=slice(5, 5))


def _weights(path: Path, modes: list[str]) -> Path:
    save_weights(path, ReconNet(NetConfig(window=7, width=8)), modes, {"command": "test"})
    return path


@pytest.mark.parametrize("case", ["corrupt", "foreign", "arch", "mode", "short", "window", "inner", "modes"])
def test_bad_learned_input_exits_2_with_one_line(capsys, tmp_path: Path, case: str) -> None:
    dat = tmp_path / "s.dat"
    write_dat(dat, np.random.default_rng(0).random((5 if case == "short" else 12, 8, 8)) < 0.5)
    weights = _weights(tmp_path / "w.pt", ["gray"])
    args = ["reconstruct", dat, "--height", 8, "--width", 8, "--method", "learned", "--frame", 0]
    if case == "corrupt":
        weights.write_bytes(weights.read_bytes()[:300])
    elif case == "foreign":
        torch.save({"format": "something-else"}, weights)
    elif case == "arch":
        data = torch.load(weights, weights_only=True)
        data["state"].pop(next(iter(data["state"])))
        torch.save(data, weights)
    elif case in ("inner", "modes"):  # right keys, wrong inner types
        data = torch.load(weights, weights_only=True)
        data.update({"state": [1, 2]} if case == "inner" else {"modes": 3})
        torch.save(data, weights)
    elif case == "mode":
        args += ["--color", "bayer"]
    elif case == "window":
        args += ["--window", 41]
    code, _, err = run_cli(capsys, *args, "--weights", weights, "--out", tmp_path / "o.npy")
    expected = {
        "corrupt": "unreadable weights",
        "foreign": "not a spikenerf reconstructor",
        "arch": "do not fit",
        "mode": "trained for colour modes gray, not 'bayer'",
        "short": "longer than the stream",
        "window": "trained window of 7",
        "inner": "do not fit",
        "modes": "malformed 'modes'",
    }[case]
    assert code == 2 and err.count("\n") == 1 and expected in err, err
    assert not (tmp_path / "o.npy").exists()


def test_training_targets_accept_the_learned_reconstruction() -> None:
    from spikenerf.core.errors import InputError
    from spikenerf.data.targets import masked_reconstruction

    net, _ = load_weights(None)
    spikes = (np.random.default_rng(1).random((net.config.window + 1, 6, 10)) < 0.5).astype(np.uint8)
    out = masked_reconstruction(spikes, "learned", window=net.config.window)
    assert out.shape == spikes.shape and out.dtype == np.float32
    with pytest.raises(InputError, match="trained window"):
        masked_reconstruction(spikes, "learned", window=net.config.window + 2)


def test_recon_commands_reject_bad_folders_with_one_line(capsys, tmp_path: Path) -> None:
    code, _, err = run_cli(capsys, "recon-train", tmp_path, "--out", tmp_path / "run")
    assert code == 2 and err.count("\n") == 1 and "manifest.json" in err
    code, _, err = run_cli(capsys, "recon-data", "--out", tmp_path / "p", "--window", 8)
    assert code == 2 and err.count("\n") == 1 and "--window" in err
    for flag, value in [("--brightness", "0.5:inf"), ("--max-speed", "inf"), ("--threshold", "inf"),
                        ("--extra-draws", 5)]:  # fmt: skip  # (the last: no --scene or --sequence)
        code, _, err = run_cli(capsys, "recon-data", "--out", tmp_path / "p", flag, value)
        assert code == 2 and err.count("\n") == 1 and flag in err, err
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "manifest.json").write_text("{not json")
    code, _, err = run_cli(capsys, "recon-train", tmp_path / "bad", "--out", tmp_path / "run")
    assert code == 2 and err.count("\n") == 1 and "corrupt manifest.json" in err, err
    assert not (tmp_path / "p").exists() and not (tmp_path / "run").exists()


def test_recon_resume_with_a_foreign_optimiser_state_is_an_input_error(pairs: Path, tmp_path: Path) -> None:
    train_recon(pairs, tmp_path / "r", _cfg(), progress=False, stop_at=2)
    data = torch.load(tmp_path / "r" / "checkpoint.pt", weights_only=True)
    data["optimizer"]["param_groups"].append(dict(data["optimizer"]["param_groups"][0]))  # → ValueError
    torch.save(data, tmp_path / "r" / "checkpoint.pt")
    with pytest.raises(InputError, match="does not fit"):
        train_recon(pairs, tmp_path / "r", _cfg(), progress=False)


@pytest.mark.parametrize("kw", [{"batch": 10**9}, {"width": 10**5}, {"crop": 16, "batch": 10**7}])
def test_recon_train_beyond_memory_is_refused_before_writing(pairs: Path, tmp_path: Path, kw: dict) -> None:
    with pytest.raises(InputError, match="batch/crop/width") as err:
        train_recon(pairs, tmp_path / "big", _cfg(**kw), progress=False)
    assert set(err.value.params) >= {"batch", "crop", "width"}
    assert not (tmp_path / "big").exists()
    assert train_memory(_cfg(), 7, 20) < 64 * 2**20  # the test's own runs stay far below any machine


def test_recon_train_refuses_a_learning_rate_that_is_not_finite() -> None:
    for lr in (float("inf"), float("nan"), 0.0, -1.0):
        with pytest.raises(InputError, match="lr"):
            _cfg(lr=lr).check()
