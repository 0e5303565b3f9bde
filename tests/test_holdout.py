"""The hold-out of the no-reference check steps (data/holdout.py): the samplers never draw a held-out step or
a window overlapping a guard band, the defaults (imported → on, simulated → off), the run's record, the
radius, and a band that leaves nothing to train on."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from helpers import run_cli
from spikenerf.capture.options import SimulateOptions
from spikenerf.capture.simulate import simulate_dataset
from spikenerf.core.errors import InputError
from spikenerf.data.dataset import load_dataset
from spikenerf.data.holdout import HOLDOUT_FILE, Holdout, guard_radius, read_record
from spikenerf.data.samplers import RaySampler, WindowSampler
from spikenerf.data.targets import stream_targets
from spikenerf.scenes.analytic import AnalyticSource
from spikenerf.scenes.trajectory import novel_views, orbit
from spikenerf.train.config import TrainConfig
from spikenerf.train.methods import make_method

STEPS = 60
TRAIN = ["--iters", 2, "--batch", 32, "--eval-every", 0, "--eval-views", 1, "--spike-warmup", 0,
         "--spike-window", 4, "--spike-pixels", 4, "--device", "cpu", "--quiet",
         "--field-option", "n_voxels_init=512", "--field-option", "n_voxels_final=512"]  # fmt: skip


@pytest.fixture(scope="module")
def dataset_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    traj = orbit(4.0, 30.0, duration=STEPS / 40000)
    source = AnalyticSource("analytic-orbs", 8, 8, traj, novel_views(4.0, 1), supersample=1)
    out = tmp_path_factory.mktemp("holdout") / "orbs8"
    return simulate_dataset(source, out, SimulateOptions(blur_fps=0.0), progress=False)


def _imported(dataset, keys: list[int]):  # type: ignore[no-untyped-def]
    """The dataset as if `spikenerf import` had written it, with these test keyframes."""
    return dataclasses.replace(dataset, config={**dataset.config, "imported": {"test_keyframes": keys}})


def test_samplers_never_draw_a_held_out_step_or_an_overlapping_window() -> None:
    hold = Holdout(np.array([10, 31]), radius=3, total=50, source="test")
    band = set(np.flatnonzero(hold.band()).tolist())
    assert band == set(range(7, 14)) | set(range(28, 35))
    images = hold.image_indices(torch.arange(100, 150), np.arange(100, 150))  # step numbers ≠ indices
    assert set(images.tolist()) == set(range(50)) - band
    rays = RaySampler(50, 4, 4, seed=0, images=images)
    drawn = torch.cat([rays.sample(256)[0] for _ in range(40)])
    assert not set(drawn.tolist()) & band and len(set(drawn.tolist())) == 50 - len(band)
    length = 5
    starts = hold.window_starts(length)
    for order in ("random", "sequential"):
        windows = WindowSampler(50, 4, 4, length, seed=1, order=order, starts=starts)
        firsts = {windows.sample(2)[0] for _ in range(400)}
        assert firsts <= set(starts.tolist()), order
        if order == "random":
            assert firsts == set(starts.tolist())  # every allowed window, and only those
        else:  # walks on by L, skipping to the next allowed start, and wraps
            assert firsts == {0, 14, 19, 35, 40, 45}
        for s in firsts:
            assert not set(range(s, s + length)) & band, (order, s)
    # the allowed windows are exactly those that miss the bands (the edges touch them)
    assert {6 - length + 1, 2, 14, 23, 35, 45} <= set(starts.tolist())
    assert not {3, 9, 24, 34, 46} & set(starts.tolist())


def test_unrestricted_samplers_draw_as_before() -> None:
    """``images``/``starts`` covering everything give the same draws as the unrestricted samplers."""
    a, b = RaySampler(6, 3, 5, seed=2), RaySampler(6, 3, 5, seed=2, images=torch.arange(6))
    for _ in range(5):
        for x, y in zip(a.sample(64), b.sample(64), strict=True):
            assert torch.equal(x, y)
    for order in ("random", "sequential"):
        c = WindowSampler(30, 3, 3, 4, seed=3, order=order, stride=3)
        d = WindowSampler(30, 3, 3, 4, seed=3, order=order, stride=3, starts=torch.arange(27))
        for _ in range(25):
            (s, p), (t, q) = c.sample(3), d.sample(3)
            assert s == t and torch.equal(p, q)
        assert c.state_dict()["next_start"] == d.state_dict()["next_start"]


def test_guard_radius_keeps_trained_and_checked_spikes_apart() -> None:
    # TFP 41 (a = 20), mask n 5, spike window 16 (centred: ±8): r = 20 + 20
    assert guard_radius(41, 5, 16) == 40
    assert guard_radius(5, 5, 40) == 5 + 20  # a wide check window
    assert guard_radius(3, 5, 2) == 10  # the mask reaches further than a short TFP


def test_hold_out_is_on_for_imported_datasets_only(dataset_dir: Path) -> None:
    dataset = load_dataset(dataset_dir)
    cfg = TrainConfig(dataset=str(dataset_dir), holdout_radius=2, holdout_steps=3)
    assert make_method(cfg).hold_out(dataset) is None  # simulated: off by default
    hold = make_method(cfg).hold_out(_imported(dataset, [20, 40]))
    assert (
        hold is not None and hold.steps.tolist() == [20, 40] and hold.source == "the imported test keyframes"
    )
    on = make_method(dataclasses.replace(cfg, holdout=True)).hold_out(dataset)
    assert on is not None and on.steps.tolist() == [15, 30, 44] and on.source == "evenly spaced steps"
    assert make_method(dataclasses.replace(cfg, holdout=False)).hold_out(_imported(dataset, [20])) is None
    # the default band: a + e = 40 for image targets (TFP window 41, mask n 5, spike window 16); e = 20 for
    # spike-integral, whose count windows never overlap a band (its learned prior's images need a + e)
    radii = {}
    for method, prior in (("spike-integral", "none"), ("spike-integral", "learned"), ("spike-nerf", "none")):
        cfg = TrainConfig(dataset=str(dataset_dir), method=method)
        cfg.integral.prior = prior
        default = make_method(cfg).hold_out(_imported(dataset, [20]))
        radii[method, prior] = default.radius if default is not None else None
    assert radii == {
        ("spike-integral", "none"): 20,
        ("spike-integral", "learned"): 40,
        ("spike-nerf", "none"): 40,
    }
    began = make_method(TrainConfig(dataset=str(dataset_dir))).hold_out(_imported(dataset, [20]), began=40)
    assert began is not None and began.radius == 40  # a resumed run keeps the band it recorded


def test_train_records_the_held_out_steps_and_eval_reads_them(
    dataset_dir: Path, tmp_path: Path, capsys
) -> None:
    run = tmp_path / "run"
    args = ["--holdout", "--holdout-steps", 2, "--holdout-radius", 3]
    code, _, err = run_cli(capsys, "train", dataset_dir, *TRAIN, *args, "--out", run)
    assert code == 0, err
    record = read_record(run)
    assert record is not None and record["check_steps"] == [20, 39] and record["radius"] == 3
    assert record["excluded_steps"] == 14 and record["source"] == "evenly spaced steps"
    code, out, err = run_cli(capsys, "eval", run, "--lpips", "none", "--spike-pixels", 8, "--quiet")
    assert code == 0, err
    assert "no-reference at 2 check steps (held out)" in out  # auto: on for a run that held steps out
    nr = json.loads((run / "metrics.json").read_text())["no_reference"]
    assert nr["steps_trained_on"] is False and nr["guard_radius"] == 3
    assert [r["step"] for r in nr["per_step"]] == record["step_numbers"]
    code, out, _ = run_cli(capsys, "info", run)
    assert code == 0 and "held out: steps 20, 39 ± 3 (14 steps not trained on)" in out
    # the same run without the hold-out trains on every step, writes no record and says so
    (run / HOLDOUT_FILE).unlink()
    code, out, err = run_cli(capsys, "eval", run, "--lpips", "none", "--spike-pixels", 8, "--noref", "on",
                             "--noref-steps", 2, "--quiet")  # fmt: skip
    assert code == 0 and "(trained on: they measure fit, not generalisation)" in out, err
    assert json.loads((run / "metrics.json").read_text())["no_reference"]["steps_trained_on"] is True


def test_default_simulated_run_writes_no_record(dataset_dir: Path, tmp_path: Path, capsys) -> None:
    code, _, err = run_cli(capsys, "train", dataset_dir, *TRAIN, "--out", tmp_path / "run")
    assert code == 0, err
    assert not (tmp_path / "run" / HOLDOUT_FILE).exists()


@pytest.mark.parametrize(
    ("args", "what"),
    [
        (["--holdout-radius", 30, "--method", "spike-nerf"], "image target"),
        (["--holdout-radius", 30], "5-step window"),  # spike-integral, train's default
        (["--holdout-radius", 12, "--holdout-steps", 2, "--method", "spike-nerf", "--spike-window", 30],
         "30-step spike window"),
    ],
)  # fmt: skip
def test_a_band_that_leaves_nothing_to_train_on_exits_2(
    dataset_dir: Path, tmp_path: Path, capsys, args: list, what: str
) -> None:
    out = tmp_path / "run"
    code, _, err = run_cli(capsys, "train", dataset_dir, *TRAIN, "--holdout", *args, "--out", out)
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "--holdout-radius" in err and f"leaves no {what}" in err, err
    assert not (out / "config.yaml").exists() and not (out / "checkpoint.pt").exists()


def test_a_negative_radius_exits_2(dataset_dir: Path, tmp_path: Path, capsys) -> None:
    code, _, err = run_cli(
        capsys, "train", dataset_dir, *TRAIN, "--holdout-radius", -1, "--out", tmp_path / "r"
    )
    assert code == 2 and "--holdout-radius must be ≥ 0" in err, err


def test_the_trainer_samples_only_outside_the_bands(dataset_dir: Path, tmp_path: Path) -> None:
    from spikenerf.train.trainer import Trainer

    cfg = TrainConfig(dataset=str(dataset_dir), device="cpu", holdout=True, holdout_steps=2, holdout_radius=3,
                      method="spike-nerf")  # fmt: skip
    cfg.spike.window = 4
    trainer = Trainer(cfg, tmp_path / "run", progress=False)
    band = set(range(17, 24)) | set(range(36, 43))
    rays, windows = trainer.samplers["rays"], trainer.samplers["windows"]
    drawn = set(torch.cat([rays.sample(512)[0] for _ in range(20)]).tolist())
    assert not drawn & band and len(drawn) == STEPS - len(band)
    for _ in range(100):
        start = windows.sample(1)[0]
        assert not set(range(start, start + 4)) & band, start
    # spike-integral: no window of counts, and no step it renders, reaches into a band
    cfg = dataclasses.replace(cfg, method="spike-integral")
    cfg.integral.lengths = [3, 5]
    integral = Trainer(cfg, tmp_path / "integral", progress=False).samplers["windows"]
    start, end, _, steps = integral.sample(4096)
    for a, b in zip(start.tolist(), end.tolist(), strict=True):
        assert not set(range(a, b)) & band, (a, b)
    assert not set(steps.reshape(-1).tolist()) & band


def test_a_run_from_before_the_hold_out_resumes_without_one(dataset_dir: Path, tmp_path: Path) -> None:
    """Its config.yaml has no ``holdout`` key: it trained on every step and must go on doing so, even on an
    imported dataset (where the default would turn the hold-out on halfway and eval would mislabel it)."""
    from spikenerf.train.trainer import Trainer

    imported = _imported(load_dataset(dataset_dir), [30])
    cfg = TrainConfig(dataset=str(dataset_dir), device="cpu", iters=4, holdout=False, holdout_radius=3)
    cfg.spike.window = 4
    cfg.poses.refine = False  # the stand-in import has no keyframe section for the (default) refinement
    first = Trainer(cfg, tmp_path / "run", imported, progress=False)
    first.train(stop_after=2)
    path = tmp_path / "run" / "config.yaml"
    path.write_text("".join(li for li in path.read_text().splitlines(True) if not li.startswith("holdout:")))
    resumed = Trainer(dataclasses.replace(cfg, holdout=None), tmp_path / "run", imported, resume=True,
                      progress=False)  # fmt: skip
    assert resumed.holdout is None and resumed.config.holdout is False
    assert not (tmp_path / "run" / HOLDOUT_FILE).exists()


def test_a_resumed_run_keeps_the_band_it_recorded(dataset_dir: Path, tmp_path: Path) -> None:
    """A spike-integral run begun when its default band was a + e resumes with that band, not with today's
    default e: a band that narrowed halfway would train on steps its record and eval call held out."""
    from spikenerf.train.trainer import Trainer

    run = tmp_path / "run"
    cfg = TrainConfig(dataset=str(dataset_dir), device="cpu", iters=4, holdout=True, holdout_steps=1,
                      batch=32, eval_every=0, eval_views=1)  # fmt: skip
    cfg.integral.lengths = [4]
    cfg.targets.window, cfg.targets.mask_n, cfg.spike.window = 9, 2, 4  # a = e = 4
    cfg.field_config = {"n_voxels_init": 512, "n_voxels_final": 512}
    dataset = load_dataset(dataset_dir)
    Trainer(cfg, run, dataset, progress=False).train(stop_after=2)
    record = read_record(run)
    assert record is not None and record["radius"] == record["check_reach"] == 4
    (run / HOLDOUT_FILE).write_text(json.dumps({**record, "radius": 8}))  # an older run's default band
    resumed = Trainer(cfg, run, dataset, resume=True, progress=False)
    assert resumed.holdout is not None and resumed.holdout["radius"] == 8
    assert resumed.method.holdout is not None and resumed.method.holdout.radius == 8


def test_a_hand_edited_imported_section_is_one_input_error(dataset_dir: Path) -> None:
    from spikenerf.data.holdout import check_steps
    from spikenerf.train.pose_refine import keyframes_of

    dataset = load_dataset(dataset_dir)
    with pytest.raises(InputError, match="test_keyframes must be a list of step indices"):
        check_steps(_imported(dataset, ["a", 3]), 4)
    with pytest.raises(InputError, match=r"imported section is incomplete or malformed \(KeyError"):
        keyframes_of(_imported(dataset, [20]), 20)  # no keyframe_every / window


def test_info_numbers_held_steps_of_a_ranged_import_as_info_of_the_dataset_does() -> None:
    """After ``import --range 100:``, ``info DATASET`` said "recording steps 130" and ``info RUN``
    "held out: steps 30": the run now gives both numberings."""
    from spikenerf.train.run import held_line

    held = {"check_steps": [30], "step_numbers": [30], "radius": 40, "excluded_steps": 81}
    assert held_line(held, {"range": [100, 200]}) == (
        "held out: recording steps 130 (dataset steps 30) ± 40 (81 steps not trained on)"
    )
    for imported in ({}, {"range": [0, 200]}):  # a simulated dataset, or an import from step 0
        assert held_line(held, imported) == "held out: steps 30 ± 40 (81 steps not trained on)"


def _recon_method(dataset_dir: Path, recon: str, method: str = "spike-nerf"):  # type: ignore[no-untyped-def]
    """A method held out at steps [20, 39] of the 60 with TFP window 5, mask n 2 and spike window 4:
    a = 2, e = 2, r = 4 (bands 16..24 and 35..43; the checks read 18..22 and 37..41)."""
    cfg = TrainConfig(dataset=str(dataset_dir), method=method, holdout=True, holdout_steps=2)
    cfg.targets.recon, cfg.targets.window, cfg.targets.mask_n, cfg.spike.window = recon, 5, 2, 4
    return make_method(cfg)


def test_tfi_and_tfstp_targets_read_no_spike_a_check_reads(dataset_dir: Path) -> None:
    """A TFI target outside the TFP-sized band read back or forward to the nearest spike, however far: at
    step 6 of a pixel firing at 5 and 21 its interval reached the spike at 21, inside the check span of
    step 20 (18..22), so moving that spike changed a trained target. With the hold-out the stream is cut
    at the bands' edges before TFI or TFSTP reconstructs it: no trained target changes with any spike a
    check reads (their masks read k±n, into the band but not to the check span), and the targets trained
    on are the same steps as with TFP."""
    dataset = load_dataset(dataset_dir)
    stream = np.zeros((STEPS, 8, 8), np.uint8)
    stream[[5, 21, 50], 0, 0] = 1
    moved = stream.copy()
    moved[[21, 19], 0, 0] = 0, 1  # the spike inside the check span moves
    rng = np.random.default_rng(3)
    stream[:, 1:] = moved[:, 1:] = rng.random((STEPS, 7, 8)) < 0.08  # other pixels, some dark
    moved[18:23, 1:] = rng.random((5, 7, 8)) < 0.5  # and every spike the checks read changes
    moved[37:42, 1:] = rng.random((5, 7, 8)) < 0.5
    for recon in ("tfi", "tfstp"):
        method = _recon_method(dataset_dir, recon)
        hold = method.hold_out(dataset)
        assert hold is not None and hold.steps.tolist() == [20, 39] and hold.radius == 4 and hold.reach == 2
        assert hold.cut and hold.cuts().tolist() == [16, 25, 35, 44]
        kept = hold.image_indices(torch.arange(STEPS), np.arange(STEPS))
        assert set(kept.tolist()) == set(range(STEPS)) - set(range(16, 25)) - set(range(35, 44))
        a, b = (method.image_targets(dataset, s).images[kept] for s in (stream, moved))
        assert torch.equal(a, b), recon
        # uncut (the reconstruction before the hold-out cut it): the target at step 6 read the spike at 21
        whole = [stream_targets(dataset, "gray", recon, 5, True, 2, s).images[kept] for s in (stream, moved)]
        assert not torch.equal(whole[0], whole[1]), recon
        if recon == "tfi":
            six = [
                stream_targets(dataset, "gray", "tfi", 5, True, 2, s).images[6, 0, 0, 0]
                for s in (stream, moved)
            ]
            assert float(six[0]) != float(six[1]) and float(a[6, 0, 0, 0]) == float(b[6, 0, 0, 0]) > 0
        record = hold.record(np.arange(STEPS))
        assert record["recon"] == recon and record["recon_cut"] is True and record["check_reach"] == 2


def test_tfp_targets_and_kept_steps_are_unchanged_by_the_cut(dataset_dir: Path) -> None:
    """TFP (and learned) read their window, which the band is sized for: their targets are not cut and the
    steps trained on are the band's complement, as before."""
    dataset = load_dataset(dataset_dir)
    stream = (np.random.default_rng(5).random((STEPS, 8, 8)) < 0.1).astype(np.uint8)
    method = _recon_method(dataset_dir, "tfp")
    hold = method.hold_out(dataset)
    assert hold is not None and not hold.cut and hold.record(np.arange(STEPS))["recon_cut"] is False
    assert torch.equal(method.image_targets(dataset, stream).images,
                       stream_targets(dataset, "gray", "tfp", 5, True, 2, stream).images)  # fmt: skip
    kept = hold.image_indices(torch.arange(STEPS), np.arange(STEPS))
    assert kept.tolist() == np.flatnonzero(~hold.band()).tolist()


def test_the_check_of_a_cut_run_reconstructs_from_its_own_steps(dataset_dir: Path) -> None:
    """eval's TFI or TFSTP image of a check step c of a run held out with the cut comes from steps
    c−e..c+e alone (``check_reach``), not from the whole stream, whose dark pixels read trained steps."""
    from spikenerf.camera.reconstruct import tfi
    from spikenerf.eval.noref import step_reconstructions

    dataset = load_dataset(dataset_dir)
    cfg = TrainConfig(dataset=str(dataset_dir), method="spike-nerf")
    cfg.targets.recon = "tfi"
    spikes = np.asarray(dataset.spikes("gray"))
    steps = np.array([20, 58])
    cut = step_reconstructions(cfg, dataset, steps, reach=3)
    assert cut is not None
    np.testing.assert_array_equal(cut[0], tfi(spikes[17:24], dataset.threshold)[3])
    np.testing.assert_array_equal(cut[1], tfi(spikes[55:60], dataset.threshold)[3])  # (clipped at the end)
    whole = step_reconstructions(cfg, dataset, steps)
    assert whole is not None
    np.testing.assert_array_equal(whole[0], tfi(spikes, dataset.threshold)[20])


def test_a_tfi_run_records_its_cut_and_eval_follows_it(dataset_dir: Path, tmp_path: Path, capsys) -> None:
    run = tmp_path / "run"
    args = ["--method", "spike-nerf", "--recon", "tfi", "--set", "targets.mask_n=2", "--window", 5,
            "--holdout", "--holdout-steps", 2]  # fmt: skip
    code, _, err = run_cli(capsys, "train", dataset_dir, *TRAIN, *args, "--out", run)
    assert code == 0, err
    record = read_record(run)
    assert record is not None and record["radius"] == 4 and record["check_reach"] == 2
    assert record["recon"] == "tfi" and record["recon_cut"] is True
    code, _, err = run_cli(capsys, "eval", run, "--lpips", "none", "--spike-pixels", 8, "--quiet")
    assert code == 0, err
    nr = json.loads((run / "metrics.json").read_text())["no_reference"]
    assert nr["target"] == "tfi (steps k±2 alone)" and nr["steps_trained_on"] is False
    # a cut record without its check_reach: refused in one line naming the file (it was scored as an uncut
    # run, the check images made from the whole stream, which training read), metrics.json left as it was
    metrics = (run / "metrics.json").read_bytes()
    (run / HOLDOUT_FILE).write_text(json.dumps({k: v for k, v in record.items() if k != "check_reach"}))
    code, out, err = run_cli(capsys, "eval", run, "--lpips", "none", "--spike-pixels", 8, "--quiet")
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1, err
    assert str(run / HOLDOUT_FILE) in err and "recon_cut is true but check_reach is missing" in err
    assert (run / "metrics.json").read_bytes() == metrics


@pytest.mark.parametrize(
    ("extra", "problem"),
    [
        ({"recon_cut": "yes"}, "recon_cut: expected true or false"),
        ({"check_reach": -1}, "check_reach: expected"),
        ({"recon": "tfi", "recon_cut": True}, "recon_cut is true but check_reach is missing"),
    ],
)
def test_a_damaged_cut_record_is_refused(tmp_path: Path, extra: dict, problem: str) -> None:
    (tmp_path / HOLDOUT_FILE).write_text(json.dumps({"check_steps": [3], "radius": 2, **extra}))
    with pytest.raises(InputError, match=problem) as refused:
        read_record(tmp_path)
    assert str(tmp_path / HOLDOUT_FILE) in str(refused.value)


def test_an_uncut_record_needs_no_check_reach(tmp_path: Path) -> None:
    """Records from before the cut (no ``recon_cut``) or of an uncut run (``recon_cut`` false) hold no
    check_reach, and are read as they are (eval scores them on the whole stream, as they trained)."""
    for extra in ({}, {"recon_cut": False}):
        (tmp_path / HOLDOUT_FILE).write_text(json.dumps({"check_steps": [3], "radius": 2, **extra}))
        assert read_record(tmp_path) == {"check_steps": [3], "radius": 2, **extra}


def test_a_tfi_run_from_before_the_cut_resumes_uncut_and_says_so(
    dataset_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A TFI run held out before the cut (its holdout.json has no ``recon_cut``) trained on targets of the
    whole stream: a resume cut them halfway and rewrote the record as cut, so eval made the checks' images
    from k±e alone and called the run's spikes disjoint though half its steps read the bands. It resumes on
    the targets it began with, and its record says they were not cut (eval scores them as before)."""
    from spikenerf.train.trainer import Trainer

    run = tmp_path / "run"
    cfg = TrainConfig(dataset=str(dataset_dir), method="spike-nerf", device="cpu", iters=4, holdout=True,
                      holdout_steps=2, batch=32, eval_every=0, eval_views=1)  # fmt: skip
    cfg.targets.recon, cfg.targets.window, cfg.targets.mask_n, cfg.spike.window = "tfi", 5, 2, 4
    cfg.spike.warmup = 0
    cfg.field_config = {"n_voxels_init": 512, "n_voxels_final": 512}
    dataset = load_dataset(dataset_dir)
    Trainer(cfg, run, dataset, progress=False).train(stop_after=2)
    record = read_record(run)
    assert record is not None and record["recon_cut"] is True
    old = {k: v for k, v in record.items() if k not in ("recon", "recon_cut", "check_reach")}
    (run / HOLDOUT_FILE).write_text(json.dumps(old))  # the record a run from before the cut wrote
    capsys.readouterr()
    resumed = Trainer(cfg, run, dataset, resume=True, progress=False)
    assert "began with tfi targets of the whole stream" in capsys.readouterr().err
    whole = stream_targets(dataset, "gray", "tfi", 5, True, 2).images
    assert resumed.method.targets is not None and torch.equal(resumed.method.targets.images, whole)
    assert resumed.holdout is not None and resumed.holdout["recon_cut"] is False
    resumed.train()
    record = read_record(run)
    assert record is not None and record["recon_cut"] is False and record["check_steps"] == old["check_steps"]
    # resumed again (its record now says false): still the whole stream's targets
    later = Trainer(dataclasses.replace(cfg, iters=6), run, dataset, resume=True, progress=False)
    assert later.method.targets is not None and torch.equal(later.method.targets.images, whole)
    assert later.holdout is not None and later.holdout["recon_cut"] is False
    # a run begun with the cut resumes cut
    again = Trainer(dataclasses.replace(cfg, iters=6), run.parent / "new", dataset, progress=False)
    again.train(stop_after=2)
    capsys.readouterr()
    cut = Trainer(dataclasses.replace(cfg, iters=6), run.parent / "new", dataset, resume=True, progress=False)
    assert "whole stream" not in capsys.readouterr().err
    assert cut.holdout is not None and cut.holdout["recon_cut"] is True
    assert cut.method.targets is not None and again.method.targets is not None
    assert torch.equal(cut.method.targets.images, again.method.targets.images)
    assert not torch.equal(cut.method.targets.images, whole)
