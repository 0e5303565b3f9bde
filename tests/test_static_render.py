"""The grid's static-shape render path (``static_samples``, issue 27): the packed path's result when every
sample fits, a counted truncation when not, no graph break under ``torch.compile(fullgraph=True)`` (the CPU
proxy for "no host sync"), and ``train --field-option static_samples=N`` end to end."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

import test_train
from spikenerf.data.rays import image_rays
from spikenerf.fields import GridFieldConfig
from spikenerf.fields import grid as grid_module
from spikenerf.render import build_model
from spikenerf.render.grid_model import MARCH_SLOTS, compact_slots
from spikenerf.render.model import ray_bounds
from spikenerf.scenes.poses import look_at
from spikenerf.scenes.trajectory import Intrinsics

dataset_dir = test_train.dataset_dir  # the module's fixture: a 16×16 simulated dataset
BOX = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
#: R = 16, so a step of 0.75 · 2 / 15 = 0.1 and at most 35 samples along the box's diagonal; a coarse colour
#: threshold so that decoding colour in every slot without the threshold mask would show
GRID = GridFieldConfig(n_voxels_init=16**3, n_voxels_final=16**3, init_scale=0.5, density_shift=-1.0,
                       distance_scale=5.0, decoder_bf16=False, weight_threshold=1e-2)  # fmt: skip
ALL_FIT = 40


def _model(occupancy: bool):  # type: ignore[no-untyped-def]
    """A random grid; with ``occupancy`` about half of the cells culled in a pattern (and a shortened box)."""
    torch.manual_seed(0)
    model = build_model("grid", 3, BOX, GRID)
    model.use_occupancy = occupancy
    if occupancy:
        pattern = lambda x: 10.0 * ((torch.sin(5 * x).sum(-1) > 0) & (x[:, 0] < 0.6)).float()  # noqa: E731
        model.field.occupancy.update(pattern, model.field.step_size, dilation=0)
        assert 0.2 < model.field.occupancy.occupied_fraction() < 0.8
    return model


def _rays(model, size: tuple[int, int] = (12, 10)) -> tuple[torch.Tensor, ...]:  # type: ignore[no-untyped-def]
    pose = torch.as_tensor(look_at(np.array([0.3, 2.5, 1.2]), np.zeros(3)), dtype=torch.float32)
    origins, dirs = image_rays(pose, Intrinsics.from_fov(*size, 0.8))
    return (origins, dirs, *ray_bounds(model, origins, dirs))


def _static(model, samples: int) -> None:  # type: ignore[no-untyped-def]
    model.field.config = dataclasses.replace(model.field.config, static_samples=samples)


def _render(model, rays) -> tuple[object, list[torch.Tensor]]:  # type: ignore[no-untyped-def]
    """The output and the gradients of colour + depth + opacity w.r.t. every parameter."""
    model.zero_grad(set_to_none=True)
    out = model.render_rays(*rays)
    (out.color.sum() + out.depth.sum() + out.opacity.sum()).backward()
    return out, [p.grad.clone() for p in model.parameters()]


def assert_renders_as(model, rays, expected, expected_grads) -> None:  # type: ignore[no-untyped-def]
    """:func:`_render` of ``model`` gives ``expected``'s colour, depth and opacity (1e-5) and gradients."""
    got, grads = _render(model, rays)
    assert got.num_samples == expected.num_samples
    for name in ("color", "depth", "opacity"):
        torch.testing.assert_close(getattr(got, name), getattr(expected, name), atol=1e-5, rtol=1e-5)
    for g, e in zip(grads, expected_grads, strict=True):
        torch.testing.assert_close(g, e, atol=1e-5, rtol=1e-4)


def short_runs_differ(dataset_dir: Path, tmp_path: Path, option: str, device: str) -> float:
    """The train PSNR difference of two 6-iteration nerf-gt runs (same seed, static budget 48) with the
    field option ``option`` "torch" and "triton"."""
    from spikenerf.train.trainer import train

    runs = {}
    for how in ("torch", "triton"):
        cfg = test_train._config(dataset_dir, method="nerf-gt")
        cfg.iters, cfg.eval_every, cfg.device = 6, 0, device
        cfg.field_config = {**cfg.field_config, "static_samples": 48, option: how}
        runs[how] = train(cfg, tmp_path / how, progress=False)
    return abs(runs["triton"].train_psnr - runs["torch"].train_psnr)


def assert_one_graph(model, rays) -> None:  # type: ignore[no-untyped-def]
    """A training render (perturbed) of ``model`` traces as one graph without a break, and compiled
    (``aot_eager``, ``fullgraph``) gives the eager colour and a gradient."""
    torch._dynamo.reset()
    explained = torch._dynamo.explain(model.render_rays)(*rays, True)
    assert (explained.graph_count, explained.graph_break_count) == (1, 0), explained.break_reasons
    torch._dynamo.reset()
    compiled = torch.compile(model.render_rays, backend="aot_eager", fullgraph=True)
    out, eager = compiled(*rays), model.render_rays(*rays)
    torch.testing.assert_close(out.color, eager.color)
    out.color.sum().backward()
    assert model.field.density_planes.grad.abs().sum() > 0


@pytest.mark.parametrize("occupancy", [False, True])
def test_static_path_equals_the_packed_path_when_every_sample_fits(occupancy: bool) -> None:
    model = _model(occupancy)
    rays = _rays(model)
    packed, packed_grads = _render(model, rays)
    assert packed.dropped_samples is None and 0 < packed.opacity.mean() < 0.95  # rays hit and miss
    _static(model, ALL_FIT)
    static, static_grads = _render(model, rays)
    assert int(static.dropped_samples) == 0 and static.num_samples == ALL_FIT * len(rays[0])
    assert static.num_samples > packed.num_samples
    for name in ("color", "depth", "opacity"):
        torch.testing.assert_close(getattr(static, name), getattr(packed, name), atol=1e-5, rtol=1e-5)
    for g, e in zip(static_grads, packed_grads, strict=True):
        torch.testing.assert_close(g, e, atol=1e-5, rtol=1e-4)


def test_a_small_budget_cuts_the_march_at_its_end_and_counts_the_dropped_slots() -> None:
    model = _model(occupancy=False)
    step = model.field.step_size
    origins = torch.tensor([[x, 0.1, -1.0] for x in (-0.5, -0.2, 0.2, 0.5)])
    dirs = torch.tensor([[0.0, 0.0, 1.0]]).repeat(4, 1)
    near = torch.full((4,), 0.5)
    rays = (origins, dirs, near, near + 2.5 * step)  # 3 slots a ray: 12 in all
    packed = model.render_rays(*rays)
    assert packed.num_samples == 12
    _static(model, 2)  # 8 slots: rays 0 and 1 whole, ray 2 two of its three, ray 3 none
    static = model.render_rays(*rays)
    assert static.dropped_samples.dtype == torch.int64 and int(static.dropped_samples) == 4
    assert torch.isfinite(static.color).all() and torch.isfinite(static.depth).all()
    torch.testing.assert_close(static.color[:2], packed.color[:2], atol=1e-6, rtol=1e-6)
    assert 0 < static.opacity[2] < packed.opacity[2] - 1e-3
    assert static.opacity[3] == 0 and torch.equal(static.color[3], torch.ones(3))


def test_the_spare_slots_spread_over_spare_rays_at_distinct_points() -> None:
    """Budget left over goes to rays N … 2N − 1, evenly and at distinct points: no scatter index or grid
    texel is shared by the whole remainder (on a GPU that serialised a step's backward)."""
    model = _model(occupancy=True)
    origins, dirs, near, far = _rays(model)
    n, step = len(near), model.field.step_size
    o_n, d_n = (
        model.field.normalize(origins),
        dirs * (2.0 / (model.field.scene_box[1] - model.field.scene_box[0])),
    )
    budget = ALL_FIT * n
    marched = model._march_static(o_n, d_n, near, far, step, MARCH_SLOTS * budget)
    assert int(marched[4]) == 0  # the layout holds every step
    kept = torch.bincount(marched[0][marched[3]], minlength=n)
    ray, ray_at, k, keep, dropped = compact_slots(*marched, n, budget)
    spare = ray >= n
    used = int(kept.sum())
    assert int(dropped) == 0 and int(spare.sum()) == budget - used > n
    assert torch.all(ray[1:] >= ray[:-1]) and int(ray.max()) == 2 * n - 1 and not keep[spare].any()
    per_ray = torch.bincount(ray, minlength=2 * n)
    assert torch.equal(per_ray[:n], kept) and int(per_ray[n:].max()) <= -(-(budget - used) // n)
    points = ray_at[spare] * (budget + 1) + k[spare]
    assert len(torch.unique(points)) == len(points) and int(ray_at.max()) < n


def test_the_budget_holds_the_kept_samples_only_not_the_empty_space_between_them() -> None:
    """The march's empty slots (culled cells) are compacted away: a budget smaller than the march but as
    large as the packed path's samples renders the packed result and cuts nothing; its spare slots lie at
    distinct points of rays N … 2N − 1."""
    model = _model(occupancy=True)
    rays = _rays(model)
    n, step = len(rays[0]), model.field.step_size
    packed, packed_grads = _render(model, rays)
    near, far = model._shorten(rays[0], rays[1], rays[2], rays[3], step)
    slots = int(model._counts(near, far, step).sum())
    samples = -(-packed.num_samples // n) + 1
    assert samples * n < slots  # the march itself would not fit
    _static(model, samples)
    static, static_grads = _render(model, rays)
    assert int(static.dropped_samples) == 0
    torch.testing.assert_close(static.color, packed.color, atol=1e-5, rtol=1e-5)
    for g, e in zip(static_grads, packed_grads, strict=True):
        torch.testing.assert_close(g, e, atol=1e-5, rtol=1e-4)
    o_n = model.field.normalize(rays[0])
    d_n = rays[1] * (2.0 / (model.field.scene_box[1] - model.field.scene_box[0]))
    marched = model._march_static(o_n, d_n, near, far, step, 4 * samples * n)
    ray, ray_at, k, keep, dropped = compact_slots(*marched, n, samples * n)
    packed_ray, packed_k = model._march(o_n, d_n, near, far, step)
    used = int(keep.sum())
    assert used == len(packed_ray) and torch.equal(ray[:used], packed_ray) and torch.equal(k[:used], packed_k)
    assert torch.all(ray[1:] >= ray[:-1]) and int(ray.max()) == 2 * n - 1 and not keep[used:].any()
    points = ray_at[used:] * (samples * n + 1) + k[used:]
    assert len(torch.unique(points)) == len(points)
    ray, _, _, keep, dropped = compact_slots(*marched, n, used - 5)  # five kept slots too many
    assert int(dropped) == 5 and bool(keep.all()) and torch.equal(ray, packed_ray[: used - 5])


def test_a_tiny_budget_with_occupancy_stays_finite_and_an_empty_batch_renders() -> None:
    model = _model(occupancy=True)
    _static(model, 1)
    rays = _rays(model)
    out = model.render_rays(*rays)
    assert int(out.dropped_samples) > 0 and torch.isfinite(out.color).all()
    empty = model.render_rays(*(r[:0] for r in rays))
    assert empty.color.shape == (0, 3) and empty.num_samples == 0


def test_static_render_traces_as_one_graph_and_the_packed_one_does_not(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # the fused VM kernel (CPU only: a C++ extension that dynamo cannot trace) stays outside any graph
    monkeypatch.setattr(grid_module, "usable", lambda *_: False)
    model = _model(occupancy=True)
    rays = _rays(model, (6, 5))
    explained = torch._dynamo.explain(model.render_rays)(*rays)
    assert explained.graph_break_count > 0  # int(counts.sum()), masks, nonzero: data-dependent shapes
    _static(model, ALL_FIT)
    assert_one_graph(model, rays)


def _colours(model, count: int) -> None:  # type: ignore[no-untyped-def]
    model.field.config = dataclasses.replace(model.field.config, static_colors=count)


@pytest.mark.parametrize("occupancy", [False, True])
def test_a_colour_budget_that_holds_every_shown_slot_changes_nothing(occupancy: bool) -> None:
    """``static_colors``: colour decoded only in the C × N slots of largest weight; where they hold every
    slot above the threshold, colour, depth, opacity and gradients are those of every slot decoded."""
    model = _model(occupancy)
    rays = _rays(model)
    _static(model, ALL_FIT)
    full, full_grads = _render(model, rays)
    assert full.dropped_colors is None
    _colours(model, 20)  # 20 × N slots: more than this grid shows above its 1e-2 threshold (checked below)
    part, part_grads = _render(model, rays)
    assert part.dropped_colors is not None and int(part.dropped_colors) == 0
    for name in ("color", "depth", "opacity"):
        torch.testing.assert_close(getattr(part, name), getattr(full, name), atol=1e-6, rtol=1e-6)
    for g, e in zip(part_grads, full_grads, strict=True):
        torch.testing.assert_close(g, e, atol=1e-6, rtol=1e-5)


def test_a_small_colour_budget_keeps_the_heaviest_slots_and_counts_the_rest() -> None:
    from spikenerf.render.grid_model import colour_slots

    weights = torch.tensor([0.5, 0.0, 0.2, 0.05, 0.3, 0.001])
    shown = weights > 0.01
    slots, lost = colour_slots(weights, shown, 2)
    assert sorted(slots.tolist()) == [0, 4] and int(lost) == 2  # 0.2 and 0.05 left out
    slots, lost = colour_slots(weights, shown, 5)
    assert set(slots.tolist()) >= {0, 2, 3, 4} and int(lost) == 0
    model = _model(occupancy=False)
    rays = _rays(model)
    _static(model, ALL_FIT)
    full = model.render_rays(*rays)
    _colours(model, 1)
    one = model.render_rays(*rays)
    assert int(one.dropped_colors) > 0 and torch.isfinite(one.color).all()
    torch.testing.assert_close(one.opacity, full.opacity)  # density is every slot's still
    assert not torch.allclose(one.color, full.color)
    _colours(model, ALL_FIT)  # a budget as large as the slots': every slot decoded, as without one
    assert model.render_rays(*rays).dropped_colors is None


def test_a_colour_budget_without_a_sample_budget_is_refused() -> None:
    from spikenerf.core.errors import InputError
    from spikenerf.fields import field_config

    with pytest.raises(InputError, match=r"field_config\.static_colors 8 needs a static sample budget"):
        field_config("grid", {"static_colors": 8})
    assert field_config("grid", {"static_colors": 8, "static_samples": 64}).static_colors == 8


def test_a_colour_budget_traces_as_one_graph(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(grid_module, "usable", lambda *_: False)
    model = _model(occupancy=True)
    rays = _rays(model, (6, 5))
    _static(model, ALL_FIT)
    _colours(model, 4)
    explained = torch._dynamo.explain(model.render_rays)(*rays, True)
    assert (explained.graph_count, explained.graph_break_count) == (1, 0), explained.break_reasons


def train_option_then_refuse(dataset_dir: Path, tmp_path: Path, capsys, option: str, good: str,  # type: ignore[no-untyped-def]
                             bad: tuple[str, ...]) -> dict:  # fmt: skip
    """``train --field-option option=good`` runs (returns its saved field config); each ``option=bad``
    value is refused in one line naming the option, with exit 2 and no run folder."""
    from spikenerf.cli import main

    args = ["train", str(dataset_dir), "--method", "nerf-gt", "--iters", "3", "--batch", "32"]
    args += ["--eval-every", "0", "--device", "cpu", "--quiet"]
    args += [f"--field-option={k}={v}" for k, v in test_train.TINY_GRID.items()]
    main([*args, "--field-option", f"{option}={good}", "--out", str(tmp_path / "run")])
    assert "trained 3 iterations" in capsys.readouterr().out
    for value in bad:
        with pytest.raises(SystemExit) as exit_:
            main([*args, "--field-option", f"{option}={value}", "--out", str(tmp_path / "bad")])
        err = capsys.readouterr().err.strip()
        assert exit_.value.code == 2 and "\n" not in err and option in err, err
    assert not (tmp_path / "bad").exists()
    return yaml.safe_load((tmp_path / "run" / "config.yaml").read_text())["field_config"]


def test_train_with_static_samples_runs_and_a_bad_value_is_one_line(
    dataset_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    saved = train_option_then_refuse(
        dataset_dir, tmp_path, capsys, "static_samples", "24", ("-1", "1.5", "many")
    )
    assert saved["static_samples"] == 24


def test_a_render_without_gradients_takes_the_packed_path_and_cuts_nothing() -> None:
    model = _model(occupancy=True)
    rays = _rays(model)
    packed = model.render_rays(*rays)
    _static(model, 1)  # far too small for a training render
    assert int(model.render_rays(*rays).dropped_samples) > 0
    with torch.no_grad():
        exact = model.render_rays(*rays)
    assert exact.dropped_samples is None and exact.num_samples == packed.num_samples
    torch.testing.assert_close(exact.color, packed.color)


def test_training_with_a_small_budget_warns_once_with_a_budget_that_holds_the_samples(
    dataset_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from spikenerf.cli import main

    args = ["train", str(dataset_dir), "--method", "nerf-gt", "--iters", "4", "--batch", "32", "--quiet"]
    args += ["--eval-every", "0", "--device", "cpu", "--set", "log_every=1"]
    args += [f"--field-option={k}={v}" for k, v in test_train.TINY_GRID.items()]
    main([*args, "--field-option", "static_samples=1", "--out", str(tmp_path / "small")])
    err = capsys.readouterr().err
    told = [line for line in err.splitlines() if "static_samples=1 cut" in line]
    assert len(told) == 1, err  # once, though every step cut samples
    suggested = int(told[0].rsplit("static_samples=", 1)[1].split()[0])
    assert suggested > 1
    main([*args, "--field-option", f"static_samples={suggested}", "--out", str(tmp_path / "enough")])
    assert "cut" not in capsys.readouterr().err
