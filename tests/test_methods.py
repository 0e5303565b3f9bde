"""The training methods (train/methods.py) and the benchmark variants (pipelines/variants.py)."""

from __future__ import annotations

import typing
from pathlib import Path

import pytest
import torch

from spikenerf.cli import main
from spikenerf.core.errors import InputError
from spikenerf.data.targets import METHODS, Method
from spikenerf.pipelines.cells import BenchmarkConfig, cell_commands
from spikenerf.pipelines.stats import COMPARISONS
from spikenerf.pipelines.variants import ABLATION_VARIANTS, TABLE1_VARIANTS, VARIANTS
from spikenerf.train.config import TrainConfig
from spikenerf.train.losses import spike_weight
from spikenerf.train.methods import METHOD_CLASSES, StepLosses, make_method
from spikenerf.train.trainer import TrainSummary


def test_one_class_per_method_literal() -> None:
    assert tuple(METHOD_CLASSES) == METHODS == typing.get_args(Method)
    for name, cls in METHOD_CLASSES.items():
        assert cls.name == name and cls.views in ("steps", "gt", "blur")
        assert type(make_method(TrainConfig(method=name))) is cls  # type: ignore[arg-type]
    with pytest.raises(InputError, match="method must be one of"):
        make_method(TrainConfig(method="nerf-foo"))  # type: ignore[arg-type]


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

    spike = method("spike-nerf")
    assert spike.uses_mask and spike.uses_spike_loss and spike.describe() == "spike-nerf"
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
    from spikenerf.pipelines import variants
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
    monkeypatch.setattr("spikenerf.cli.train.train", lambda config, *a, **k: seen.append(config) or summary)
    cfg = BenchmarkConfig(["analytic-orbs"], [name], ["gray"], tmp_path, device="cpu")
    (tmp_path / "datasets" / "analytic-orbs").mkdir(parents=True)
    command = cell_commands(cfg, "analytic-orbs", "gray", name)[0]
    main(command[command.index("train") :])
    assert len(seen) == 1
    fields = {k: getattr(seen[0], k) for k in ("dataset", "color", "field", "seed", "device")}
    want = VARIANTS[name].config(**fields)
    assert seen[0] == want and make_method(want).describe().startswith(VARIANTS[name].method)
    if name.endswith("learned"):
        assert want.targets.recon == "learned"
    assert make_method(want).uses_mask == (name != "spike-nerf-no-mask" and want.method == "spike-nerf")


def test_trained_on_follows_each_variants_method(tmp_path: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    from spikenerf.pipelines import results
    from spikenerf.pipelines.cells import run_dir
    from spikenerf.train.config import save_config

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
