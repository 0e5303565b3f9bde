"""The training methods (train/methods/) and the benchmark variants (pipelines/variants.py)."""

from __future__ import annotations

import typing
from pathlib import Path

import pytest
import torch

from spikenerf.cli import main
from spikenerf.core.errors import InputError
from spikenerf.data.choices import METHODS, Method
from spikenerf.pipelines.benchmark.cells import BenchmarkConfig, cell_commands
from spikenerf.pipelines.benchmark.stats import COMPARISONS
from spikenerf.pipelines.benchmark.variants import ABLATION_VARIANTS, TABLE1_VARIANTS, VARIANTS
from spikenerf.train.config import TrainConfig
from spikenerf.train.losses import spike_weight
from spikenerf.train.methods import METHOD_CLASSES, StepLosses, make_method
from spikenerf.train.settings import METHOD_SUMMARIES
from spikenerf.train.trainer import TrainSummary


def test_one_class_per_method_literal() -> None:
    assert tuple(METHOD_CLASSES) == METHODS == typing.get_args(Method)
    for name, cls in METHOD_CLASSES.items():
        assert cls.name == name and cls.views in ("steps", "gt", "blur")
        assert type(make_method(TrainConfig(method=name))) is cls  # type: ignore[arg-type]
    with pytest.raises(InputError, match="method must be one of"):
        make_method(TrainConfig(method="nerf-foo"))  # type: ignore[arg-type]


def test_every_literal_name_has_exactly_one_registry_entry() -> None:
    """The ``Method`` Literal names the methods; METHOD_CLASSES holds one class per name, and every place
    that lists or dispatches on methods reads that table (no name list elsewhere in train/ or the CLI)."""
    names = typing.get_args(Method)
    assert len(set(names)) == len(names) and tuple(METHOD_CLASSES) == names
    assert len({cls for cls in METHOD_CLASSES.values()}) == len(names)
    from spikenerf.cli.train import command

    option = next(p for p in command.params if p.name == "method")
    assert tuple(option.type.choices) == tuple(METHOD_CLASSES)  # type: ignore[attr-defined]
    assert tuple(METHOD_SUMMARIES) == names  # the help's one line per method (torch-free)
    assert all(f"{name} ({text})" in (command.help or "") for name, text in METHOD_SUMMARIES.items())


def test_a_new_method_is_one_registry_entry(monkeypatch: pytest.MonkeyPatch) -> None:
    """Registering a class is all it takes: TrainConfig accepts the name, its defaults and rules apply, and
    make_method builds it."""
    from spikenerf.train.methods import NerfGT

    class Dummy(NerfGT):
        name, uses_stream, default_batch, learns_poses = "dummy", True, 96, True

        @classmethod
        def check(cls, config: TrainConfig) -> None:
            if config.iters > 100:
                raise InputError("iters: dummy trains ≤ 100 iterations", param="iters")

    with pytest.raises(InputError, match="method must be one of"):
        TrainConfig(method="dummy").validate()  # type: ignore[arg-type]
    monkeypatch.setitem(METHOD_CLASSES, "dummy", Dummy)
    config = TrainConfig(dataset="d", method="dummy", iters=50).validate()  # type: ignore[arg-type]
    assert type(make_method(config)) is Dummy and config.method_class() is Dummy
    assert config.rays_per_step() == 96 and config.window_poses() == config.targets.poses_per_target()
    with pytest.raises(InputError, match="dummy trains") as err:
        TrainConfig(dataset="d", method="dummy", iters=500).validate()  # type: ignore[arg-type]
    assert err.value.params == ("iters",)
    loaded = TrainConfig.from_dict({**config.to_dict(), "iters": 60})
    assert loaded.method == "dummy" and loaded.validate().iters == 60


def test_method_rules_live_with_the_method() -> None:
    """spike-integral's and nerf-bad's config rules are their classes' ``check``, called by validate."""
    from spikenerf.train.methods import NerfBAD, SpikeIntegral

    bad = TrainConfig(dataset="d", method="nerf-bad")
    bad.targets.blur_samples = 1
    with pytest.raises(InputError, match="nerf-bad") as err:
        NerfBAD.check(bad)
    assert err.value.params == ("targets.blur_samples",)
    with pytest.raises(InputError, match="nerf-bad"):
        bad.validate()
    TrainConfig(dataset="d", method="nerf-gt", targets=bad.targets).validate()  # the rule is nerf-bad's
    tfi = TrainConfig(dataset="d", method="spike-integral")
    tfi.targets.recon, tfi.targets.window_poses = "tfi", 1
    with pytest.raises(InputError, match="spike-integral reads spike counts"):
        SpikeIntegral.check(tfi)
    assert TrainConfig(method="spike-integral").rays_per_step() == SpikeIntegral.default_batch == 4096


def test_step_losses_sum_the_weighted_terms_in_order() -> None:
    terms = {"recon": torch.tensor(1.0), "reg": torch.tensor(2.0), "spike": torch.tensor(3.0)}
    step = StepLosses(dict(terms), torch.tensor(0.0), rays=4, weights={"spike": 0.5})
    assert step.total().item() == 1.0 + 2.0 + 0.5 * 3.0
    a, b = torch.tensor(0.1), torch.tensor(1e8)  # the trainer's order: (recon + reg) + λ·spike, bit for bit
    assert torch.equal(StepLosses({"r": a, "g": b, "s": a}, a, 0, {"s": 0.3}).total(), (a + b) + 0.3 * a)


def test_each_method_owns_its_parts() -> None:
    def method(name: str, **kw: object):  # type: ignore[no-untyped-def]
        cfg = TrainConfig(method=name, iters=100)  # type: ignore[arg-type]
        for key, value in kw.items():
            section, field = key.split("__")
            setattr(getattr(cfg, section), field, value)
        return make_method(cfg)

    spike = method("spike-nerf", targets__window_poses=1)  # the paper's targets: masked by default
    assert spike.uses_mask and spike.uses_spike_loss and spike.describe() == "spike-nerf"
    window = method("spike-nerf")  # window-aware targets (train's default): no masks unless asked
    assert not window.uses_mask and window.describe() == "spike-nerf (no mask)"
    assert method("spike-nerf", targets__mask=True).uses_mask
    assert not method("spike-nerf", targets__window_poses=1, targets__mask=False).uses_mask
    its = (0, 19, 20, 29, 39, 99)
    assert [spike.lam(it) for it in its] == [spike_weight(it, 1.0, 20, 20) for it in its]
    assert spike.lam(19) == 0 and spike.lam(39) == 1.0
    off = method("spike-nerf", targets__mask=False, spike__enabled=False)
    assert not off.uses_mask and not off.uses_spike_loss and off.lam(99) == 0.0
    assert off.describe() == "spike-nerf (no mask, no spike loss)"
    recon = method("nerf-recon", targets__mask=True)  # the mask and the spike loss are spike-nerf's only
    assert recon.uses_stream and not recon.uses_mask and not recon.uses_spike_loss and recon.lam(99) == 0.0
    assert method("nerf-blur-aware", targets__blur_samples=5).poses_per_view() == 5
    assert method("nerf-blur", targets__blur_samples=5).poses_per_view() == 1
    bad = method("nerf-bad", targets__blur_samples=5)
    assert bad.poses_per_view() == 5 and bad.views == "blur" and not bad.uses_stream
    assert not method("nerf-gt").uses_stream and method("nerf-gt").views == "gt"


def test_paper_rows_train_the_papers_targets_and_window_rows_window_aware() -> None:
    from spikenerf.pipelines.benchmark import variants
    from spikenerf.train import config

    assert variants.WINDOW_POSES == config.WINDOW_POSES  # the rows show train's default
    for name in ("nerf-recon", "spike-nerf", "spike-nerf-no-mask", "spike-nerf-no-spike-loss"):
        assert VARIANTS[name].config().targets.poses_per_target() == 1, name
    for name in ("nerf-recon-window", "spike-nerf-window"):
        assert VARIANTS[name].config().targets.poses_per_target() == config.WINDOW_POSES > 1, name
    assert VARIANTS["spike-nerf-learned"].config().targets.poses_per_target() == 1


def test_variant_table_is_complete() -> None:
    assert set(TABLE1_VARIANTS) | set(ABLATION_VARIANTS) == set(VARIANTS)
    assert {v for pair in COMPARISONS for v in pair} <= set(VARIANTS)
    assert {v.method for v in VARIANTS.values()} == set(METHODS)
    assert len({v.label for v in VARIANTS.values()}) == len(VARIANTS)


@pytest.mark.parametrize("name", list(VARIANTS))
def test_variant_command_trains_its_config(name: str, tmp_path: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """The benchmark cell's train command builds exactly the variant's config (its method + overrides)."""
    seen: list[TrainConfig] = []
    summary = TrainSummary(1, 1.0, 1.0, 1.0, 1.0, "cpu")
    monkeypatch.setattr(
        "spikenerf.train.trainer.train", lambda config, *a, **k: seen.append(config) or summary
    )
    cfg = BenchmarkConfig(["analytic-orbs"], [name], ["gray"], tmp_path, device="cpu")
    (tmp_path / "datasets" / "analytic-orbs").mkdir(parents=True)
    command = cell_commands(cfg, "analytic-orbs", "gray", name)[0]
    main(command[command.index("train") :])
    assert len(seen) == 1
    fields = {k: getattr(seen[0], k) for k in ("dataset", "color", "field", "seed", "device", "batch")}
    assert fields["batch"] == VARIANTS[name].config().rays_per_step()  # the CPU default on any device
    want = VARIANTS[name].config(**fields)
    assert seen[0] == want and make_method(want).describe().startswith(VARIANTS[name].method)
    if name.endswith("learned"):
        assert want.targets.recon == "learned"
    assert make_method(want).uses_mask == (name != "spike-nerf-no-mask" and want.method == "spike-nerf")


def test_trained_on_follows_each_variants_method(tmp_path: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    from spikenerf.pipelines.benchmark import results
    from spikenerf.pipelines.benchmark.cells import run_dir
    from spikenerf.train.config_file import save_config

    monkeypatch.setattr(results, "view_counts", lambda root: {"steps": 40, "gt": 4, "blur": 10})
    (tmp_path / "datasets" / "s").mkdir(parents=True)
    names = ["nerf-gt", "nerf-blur", "nerf-blur-aware", "spike-nerf-no-mask", "nerf-recon-learned"]
    cfg = BenchmarkConfig(["s"], names, ["gray"], tmp_path)
    aware = VARIANTS["nerf-blur-aware"].config()
    aware.targets.blur_samples = 3  # a finished cell's config.yaml is read; the others use the defaults
    run_dir(cfg, "s", "gray", "nerf-blur-aware").mkdir(parents=True)
    save_config(aware, run_dir(cfg, "s", "gray", "nerf-blur-aware") / "config.yaml")
    assert results.trained_on(cfg) == {
        "nerf-gt": "4 GT views",
        "nerf-blur": "10 blur views",
        "nerf-blur-aware": "10 blur views × 3 poses",
        "spike-nerf-no-mask": "40 poses",
        "nerf-recon-learned": "40 poses",
    }


def test_each_method_prints_its_key_settings() -> None:
    """``info RUN`` and ``train`` name what sets a method apart: spike-integral's windows and track (which
    ``for_dataset`` may pick from the dataset), the spike loss's kind and λ, the reconstruction targets."""

    def settings(method: str, *sets: str) -> list[str]:
        from spikenerf.train.config_file import apply_overrides

        config = TrainConfig.from_dict(apply_overrides(TrainConfig(method=method).to_dict(), list(sets)))
        return make_method(config).settings()

    assert settings("nerf-gt") == [] and settings("nerf-blur") == []
    assert settings("spike-integral") == ["windows from the dataset, 1 render each", "track from the dataset"]
    integral = settings("spike-integral", "integral.lengths=[4]", "integral.track=5", "iters=1000")
    assert integral == ["windows 4 steps, 1 render each", "track windows of 11 steps from iteration 400"]
    short = settings("spike-integral", "integral.lengths=[2,4]", "integral.samples=2", "integral.track=0")
    assert short == ["windows 2/4 steps, 2 renders each", "no track"]
    assert "(after the run's end)" in settings("spike-integral", "integral.track=5", "iters=300")[1]
    options = ("integral.groups=2", "integral.band=true", "integral.interpolate=true", "integral.track=0")
    assert settings("spike-integral", "integral.lengths=[4]", *options)[2:] == [
        "2 estimates a window (product form)", "noise band", "interpolated counts (span any)"
    ]  # fmt: skip
    assert settings("nerf-recon", "targets.recon=tfi") == ["targets tfi"]  # TFI has no window
    recon = settings("nerf-recon", "targets.window=21")
    assert recon == ["targets tfp, window 21, each the mean of 4 renders across its window"]
    paper = settings("spike-nerf", "spike.kind=paper", "spike.lam=0.5", "targets.window_poses=1")
    assert paper[0] == "targets tfp, window 41" and "the paper's (no gradient), λ 0.5" in paper[-1]
    assert not any("spike loss" in s for s in settings("spike-nerf", "spike.enabled=false"))
    assert settings("nerf-bad", "targets.blur_samples=4")[0].startswith("4 renders between")
