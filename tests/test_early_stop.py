"""Early ray termination in training renders (``GridFieldConfig.early_stop``, issue 27): which samples it
leaves out, that a render changes by less than the threshold and its gradients by an error that shrinks
with it, that renders without gradients keep every sample, and that a bad value is one line; and the
second, visible budget of the static path (``static_visible``): equal to one budget where it holds the
slots, one graph, the compiled step's losses, its prerequisites and its warning."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pytest
import torch

import test_static_render as static
import test_train
from spikenerf.core.errors import InputError
from spikenerf.fields import grid as grid_module
from spikenerf.render.volume import early_stop_mask, packed_depth_before, packed_weights

dataset_dir = test_train.dataset_dir  # the module's fixture: a 16×16 simulated dataset


def test_the_mask_keeps_each_ray_until_its_transmittance_falls_below_the_threshold() -> None:
    # three rays: 10 samples of optical depth 1 each, 4 of depth 0.5, none; then one of 3 samples
    ray = torch.tensor([0] * 10 + [1] * 4 + [3] * 3)
    tau = torch.tensor([1.0] * 10 + [0.5] * 4 + [2.0, 3.0, 1.0], dtype=torch.float64)
    deltas = torch.full_like(tau, 0.5)
    sigma = tau / deltas
    mask = early_stop_mask(sigma, deltas, ray, 4, 1e-2)  # kept while the depth before is ≤ ln 100 = 4.61
    want = [True] * 5 + [False] * 5 + [True] * 4 + [True, True, False]
    assert mask.tolist() == want
    depth = packed_depth_before(sigma * deltas, ray, 4)
    assert torch.equal(mask, depth <= math.log(100.0))
    assert early_stop_mask(sigma, deltas, ray, 4, 0.0).all()  # 0: every sample
    # what is left out weighs less than the threshold, ray by ray
    weights = packed_weights(sigma, deltas, ray, 4)
    lost = torch.zeros(4, dtype=weights.dtype).index_add(0, ray, weights * ~mask)
    assert 0 < lost.max() < 1e-2


@pytest.mark.parametrize("bad", [-0.1, 1.0, 2.0])
def test_a_threshold_outside_0_1_is_refused_naming_it(bad: float) -> None:
    with pytest.raises(InputError, match="min_transmittance") as err:
        early_stop_mask(torch.ones(3), torch.ones(3), torch.zeros(3, dtype=torch.long), 1, bad)
    assert err.value.params == ("min_transmittance",)


def _with(model, **changes):  # type: ignore[no-untyped-def]
    model.field.config = dataclasses.replace(model.field.config, **changes)
    return model


@pytest.mark.parametrize("occupancy", [False, True])
@pytest.mark.parametrize("budget", [0, static.ALL_FIT])
def test_a_training_render_changes_by_less_than_the_threshold_and_its_gradients_little(
    occupancy: bool, budget: int
) -> None:
    """Packed (budget 0) and static paths: colour and opacity within ``early_stop`` of the full render,
    samples really left out, and the density factors' gradients off by an error that shrinks with the
    threshold (about 50 × it here, in norm; the other parameters' gradients unchanged)."""
    model = _with(static._model(occupancy), static_samples=budget, early_stop=0.0, distance_scale=40.0)
    rays = static._rays(model)
    full, full_grads = static._render(model, rays)
    assert full.opacity.max() > 1 - 1e-4  # rays that become opaque
    errors = []
    for eps in (1e-3, 1e-4):
        stopped, stopped_grads = static._render(_with(model, early_stop=eps), rays)
        torch.testing.assert_close(stopped.color, full.color, atol=eps, rtol=0)
        torch.testing.assert_close(stopped.opacity, full.opacity, atol=eps, rtol=0)
        assert (stopped.opacity < full.opacity - eps / 100).any()  # something was left out
        density = [(a - b).norm() / b.norm() for a, b in zip(stopped_grads[:2], full_grads[:2], strict=True)]
        assert max(density) < 100 * eps
        errors.append(max(density))
        for got, want in zip(stopped_grads[2:], full_grads[2:], strict=True):
            torch.testing.assert_close(got, want)
    assert errors[1] < errors[0] / 5


def test_the_left_out_samples_get_no_density_gradient(monkeypatch: pytest.MonkeyPatch) -> None:
    """The density's gradient is exactly 0 behind the early stop (what lets the CPU kernel skip them): far
    more zeros than without it (where only transmittance underflow makes some)."""
    seen: list[torch.Tensor] = []

    def spy(density):  # type: ignore[no-untyped-def]
        def spying(field, xyz, *args):  # type: ignore[no-untyped-def]
            sigma = density(field, xyz, *args)
            sigma.register_hook(lambda g: seen.append(g.clone()))
            return sigma

        return spying

    for name in ("density_norm", "density_until"):  # (density_until: the lookup up to the stop, on a CPU)
        monkeypatch.setattr(grid_module.GridField, name, spy(getattr(grid_module.GridField, name)))
    zeros = {}
    for eps in (0.0, 1e-2):
        model = _with(static._model(occupancy=False), early_stop=eps, distance_scale=40.0)
        out = model.render_rays(*static._rays(model))
        (out.color.sum() + out.opacity.sum()).backward()
        zeros[eps] = (seen[-1] == 0).float().mean().item()
    assert zeros[1e-2] > zeros[0.0] + 0.3 and zeros[1e-2] < 0.95, zeros  # some left out, not all


def test_a_render_without_gradients_keeps_every_sample() -> None:
    model = _with(static._model(occupancy=True), early_stop=0.1)
    rays = static._rays(model)
    with torch.no_grad():
        kept = model.render_rays(*rays)
        every = _with(model, early_stop=0.0).render_rays(*rays)
    assert torch.equal(kept.color, every.color) and torch.equal(kept.opacity, every.opacity)


def test_train_with_early_stop_off_runs_and_a_bad_value_is_one_line(
    dataset_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    saved = static.train_option_then_refuse(
        dataset_dir, tmp_path, capsys, "early_stop", "0", ("-1e-4", "0.9", "often")
    )
    assert saved["early_stop"] == 0


@pytest.mark.parametrize("occupancy", [False, True])
def test_a_visible_budget_that_holds_every_visible_slot_changes_nothing(occupancy: bool) -> None:
    """``static_visible``: the slots before each ray's early stop, found without gradient and moved into
    V × N slots, give the one-budget render's colour, depth, opacity and gradients."""
    model = _with(
        static._model(occupancy), static_samples=static.ALL_FIT, early_stop=1e-3, distance_scale=40.0
    )
    rays = static._rays(model)
    one, one_grads = static._render(model, rays)
    visible = 12  # the opaque rays stop after a few samples: 12 × N slots hold every visible one (checked)
    two, two_grads = static._render(_with(model, static_visible=visible), rays)
    assert int(two.dropped_samples) == 0 and two.num_samples == visible * len(rays[0]) < one.num_samples
    for name in ("color", "depth", "opacity"):
        torch.testing.assert_close(getattr(two, name), getattr(one, name), atol=1e-6, rtol=1e-5)
    for got, want in zip(two_grads, one_grads, strict=True):
        torch.testing.assert_close(got, want, atol=1e-6, rtol=1e-4)
    small = static._render(_with(model, static_visible=2), rays)[0]  # too small: counted, finite
    assert int(small.dropped_samples) > 0 and torch.isfinite(small.color).all()


@pytest.mark.parametrize("occupancy", [False, True])
def test_a_visible_budget_renders_the_points_its_stop_was_found_at(occupancy: bool) -> None:
    """Training renders draw random points in each slot: the visible budget keeps the first pass's draw, so
    with the same seed it renders what the one-budget path renders (a second draw would cut rays where the
    first draw stopped them, not where the rendered points do)."""
    model = _with(
        static._model(occupancy), static_samples=static.ALL_FIT, early_stop=1e-3, distance_scale=40.0
    )
    rays = static._rays(model)
    torch.manual_seed(3)
    one = model.render_rays(*rays, perturb=True)
    torch.manual_seed(3)
    two = _with(model, static_visible=12).render_rays(*rays, perturb=True)
    assert int(two.dropped_samples) == 0
    for name in ("color", "depth", "opacity"):
        torch.testing.assert_close(getattr(two, name), getattr(one, name), atol=1e-6, rtol=1e-5)


def test_a_visible_budget_traces_as_one_graph(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(grid_module, "usable", lambda *_: False)
    model = _with(static._model(occupancy=True), static_samples=static.ALL_FIT, static_visible=8,
                  static_colors=4)  # fmt: skip
    explained = torch._dynamo.explain(model.render_rays)(*static._rays(model, (6, 5)), True)
    assert (explained.graph_count, explained.graph_break_count) == (1, 0), explained.break_reasons


@pytest.mark.parametrize(
    ("options", "named"),
    [({"static_visible": 8}, "static sample budget"), ({"static_visible": 8, "static_samples": 64,
      "early_stop": 0.0}, "early_stop > 0")],
)  # fmt: skip
def test_a_visible_budget_without_its_prerequisites_is_refused(options: dict, named: str) -> None:
    from spikenerf.fields import field_config

    with pytest.raises(InputError, match=rf"field_config\.static_visible 8 needs .*{named}"):
        field_config("grid", options)
    assert field_config("grid", {"static_visible": 8, "static_samples": 64}).static_visible == 8


def test_training_with_a_small_visible_budget_warns_naming_both_budgets(
    dataset_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from spikenerf.cli import main

    args = ["train", str(dataset_dir), "--method", "nerf-gt", "--iters", "3", "--batch", "32", "--quiet"]
    args += ["--eval-every", "0", "--device", "cpu", "--set", "log_every=1"]
    args += [f"--field-option={k}={v}" for k, v in test_train.TINY_GRID.items()]
    args += ["--field-option", "static_samples=64", "--field-option", "static_visible=1"]
    main([*args, "--out", str(tmp_path / "run")])
    told = [line for line in capsys.readouterr().err.splitlines() if " cut " in line]
    assert len(told) == 1 and "static_samples=64 static_visible=1 cut" in told[0], told
    assert "--field-option static_visible=" in told[0] and "--field-option static_samples=" in told[0]


def test_the_compiled_step_with_a_visible_budget_gives_the_eager_losses(
    dataset_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The closeness check of the compiled step (``aot_eager`` on the CPU; CUDA graphs in
    ``tests/test_compiled_step.py``): the no-grad pass and the second compaction trace into its graph."""
    import test_compiled_step as cs
    from spikenerf.train import compiled_step

    monkeypatch.setattr(compiled_step, "BACKEND", "aot_eager")
    torch._dynamo.reset()
    dataset = test_train.load_dataset(dataset_dir)
    try:
        _, eager = cs._run(
            cs._config(dataset_dir, "nerf-gt", False, static_visible=12), tmp_path / "e", dataset
        )
        config = cs._config(dataset_dir, "nerf-gt", True, static_visible=12)
        trainer, compiled = cs._run(config, tmp_path / "c", dataset)
    finally:
        torch._dynamo.reset()
    step = vars(trainer.method)["step_losses"]
    assert isinstance(step, compiled_step.CompiledStep) and step.failed is None
    assert len(compiled) == len(eager) and compiled == pytest.approx(eager, rel=1e-3)
