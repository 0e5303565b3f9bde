"""``render/march_triton.py``: the Triton march kernels (``march="triton"``) keep exactly the torch march's
steps, in its order, on the packed path and in a static budget (rays longer than a block, rays that miss,
with and without the occupancy grid), count the steps past a budget exactly, give the grid renderer's
colour, depth, opacity and gradients, stay one graph under ``torch.compile`` and are left aside where they
cannot run (``train`` refusing them there in one line).

Without a GPU the kernels run in Triton's CPU interpreter (``TRITON_INTERPRET=1``, set by ``conftest.py``):
it checks the indexing, masks, scans and custom ops, not GPU speed. On a CUDA host the same tests run the
compiled kernels (where float contraction may move a step that lies on a cell's edge: the tests compare
exactly, so a rare failure there means that, not a wrong kernel)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import torch

import test_static_render
import test_train
from helpers import counts_graphs, triton_device
from spikenerf.core.errors import InputError
from spikenerf.fields import field_config
from spikenerf.render import march_triton
from spikenerf.render.grid_model import MARCH_SLOTS, compact_slots

DEVICE = triton_device()
dataset_dir = test_train.dataset_dir  # the module's fixture


def _march_how(model, how: str, **options: int) -> None:  # type: ignore[no-untyped-def]
    model.field.config = dataclasses.replace(model.field.config, march=how, **options)


def _marching(occupancy: bool, size: tuple[int, int] = (12, 10)):  # type: ignore[no-untyped-def]
    """A model of ``test_static_render`` on DEVICE and the march's inputs for its rays (normalised origins
    and directions, near and far shortened as ``render_rays`` does, the step), every 7th ray empty and
    every 5th ending where a step starts."""
    model = test_static_render._model(occupancy).to(DEVICE)
    origins, dirs, near, far = (r.to(DEVICE) for r in test_static_render._rays(model, size))
    field, step = model.field, model.field.step_size
    if occupancy:
        near, far = model._shorten(origins, dirs, near, far, step)
    d_n = dirs * (2.0 / (field.scene_box[1] - field.scene_box[0]))
    i = torch.arange(len(far), device=DEVICE)
    on_lattice = near + step * torch.floor((far - near) / step)  # the last step starts exactly at far
    far = torch.where(i % 5 == 1, on_lattice, torch.where(i % 7 == 3, near, far))  # and rays with no step
    return model, (field.normalize(origins), d_n, near, far, step)


@pytest.mark.parametrize("block", [8, 128])
@pytest.mark.parametrize("occupancy", [False, True])
def test_the_packed_march_keeps_the_torch_marchs_steps_in_order(
    occupancy: bool, block: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(march_triton.LAUNCH, "BLOCK", block)  # 8: rays of up to 35 steps over 5 blocks
    model, inputs = _marching(occupancy)
    ray, k = model._march(*inputs)
    _march_how(model, "triton")
    assert model.marched(inputs[0])
    got_ray, got_k = model._march(*inputs)
    assert len(ray) > 100 and torch.equal(got_ray, ray) and torch.equal(got_k, k)
    counts = model._counts(*inputs[2:])
    kept = march_triton.kept_counts(*inputs[:4], counts, model._grid(), inputs[4])
    assert torch.equal(kept, torch.bincount(ray, minlength=len(counts)))
    if occupancy:
        assert (kept < counts).any()  # the occupancy test culled steps


@pytest.mark.parametrize("occupancy", [False, True])
def test_a_static_budget_gets_the_torch_layout_and_counts_the_steps_past_it_exactly(occupancy: bool) -> None:
    model, inputs = _marching(occupancy)
    total = len(model._march(*inputs)[0])
    n = len(inputs[0])
    _march_how(model, "triton")
    for budget in (total + 37, total, total // 3):  # spare slots, none, a cut
        expected = compact_slots(*model._march_static(*inputs, MARCH_SLOTS * budget), n, budget)
        got = model._march_fused(*inputs, budget)
        for name, a, b in zip(("ray", "ray_at", "k", "keep"), got[:4], expected[:4], strict=True):
            assert torch.equal(a, b), (budget, name)
        assert int(got[4]) == max(0, total - budget) <= int(expected[4])  # the torch count: an upper bound


def test_a_ray_of_nan_direction_is_counted_and_written_consistently() -> None:
    """A ray of NaN direction (the torch march cannot index a cell for it): the kernels finish, count at
    most the ray's steps and write what they counted (whether a stray cell is read, the interpreter does
    not show: the kernel clamps the cell index for that)."""
    model, (o_n, d_n, near, far, step) = _marching(occupancy=True)
    d_n = d_n.clone()
    d_n[0] = float("nan")
    counts = model._counts(near, far, step)
    kept = march_triton.kept_counts(o_n, d_n, near, far, counts, model._grid(), step)
    assert bool(((kept >= 0) & (kept <= counts)).all())
    ray, _, total = march_triton.write(
        o_n, d_n, near, far, counts, model._grid(), step, kept, int(kept.sum())
    )
    assert int(total) == len(ray) and torch.equal(torch.bincount(ray, minlength=len(counts)), kept)


def test_a_sparse_grid_fills_the_budget_where_the_torch_layout_cannot() -> None:
    """Where fewer than one candidate step in ``MARCH_SLOTS`` is kept, the torch layout (``MARCH_SLOTS`` × the
    budget candidates) leaves slots empty and over-counts the dropped ones; the kernels test every step, so
    they fill the budget with the packed march's first steps and count the rest exactly."""
    model, inputs = _marching(occupancy=True)
    grid = model.field.occupancy.grid
    grid.zero_()
    grid[::6] = True  # one slab of cells in six along x
    packed_ray, packed_k = model._march(*inputs)
    n, budget = len(inputs[0]), len(packed_ray) // 2
    torch_layout = compact_slots(*model._march_static(*inputs, MARCH_SLOTS * budget), n, budget)
    assert int(torch_layout[3].sum()) < budget and int(torch_layout[4]) > len(packed_ray) - budget
    _march_how(model, "triton")
    ray, _, k, keep, dropped = model._march_fused(*inputs, budget)
    assert bool(keep.all()) and int(dropped) == len(packed_ray) - budget
    assert torch.equal(ray, packed_ray[:budget]) and torch.equal(k, packed_k[:budget])


@pytest.mark.parametrize(
    ("samples", "occupancy"), [(0, True), (test_static_render.ALL_FIT, True), (16, False)]
)
def test_the_grid_renders_as_with_the_torch_march(samples: int, occupancy: bool) -> None:
    model = test_static_render._model(occupancy).to(DEVICE)
    model.field.config = dataclasses.replace(model.field.config, static_samples=samples)
    rays = tuple(r.to(DEVICE) for r in test_static_render._rays(model))
    expected, expected_grads = test_static_render._render(model, rays)
    _march_how(model, "triton", composite="triton")  # both kernel sets at once, as on a GPU
    assert model.marched(rays[0])
    test_static_render.assert_renders_as(model, rays, expected, expected_grads)


@counts_graphs
def test_the_custom_ops_pass_opcheck_and_a_static_render_compiles_as_one_graph(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    model, (o_n, d_n, near, far, step) = _marching(occupancy=True, size=(6, 5))
    counts, grid = model._counts(near, far, step), model.field.occupancy.grid
    torch.library.opcheck(
        torch.ops.spikenerf.march_count.default, (o_n, d_n, near, far, counts, grid, step, True)
    )
    kept = march_triton.kept_counts(o_n, d_n, near, far, counts, grid, step)
    first = torch.cumsum(kept, 0) - kept
    args = (o_n, d_n, near, far, counts, grid, first, 40, step, True)
    torch.library.opcheck(torch.ops.spikenerf.march_write.default, args)
    monkeypatch.setattr(
        test_static_render.grid_module, "usable", lambda *_: False
    )  # the CPU kernel: no trace
    _march_how(model, "triton", static_samples=test_static_render.ALL_FIT)
    rays = tuple(r.to(DEVICE) for r in test_static_render._rays(model, (6, 5)))
    test_static_render.assert_one_graph(model, rays)


def test_where_the_kernels_cannot_run_they_are_refused_or_left_aside(monkeypatch: pytest.MonkeyPatch) -> None:
    model = test_static_render._model(occupancy=True)
    _march_how(model, "triton")
    rays = test_static_render._rays(model, (4, 3))
    with torch.no_grad():
        kernels = model.render_rays(*rays)
    monkeypatch.setenv("TRITON_INTERPRET", "0")  # a CPU without the interpreter: the torch march
    assert not model.marched(rays[0])
    with torch.no_grad():
        torch.testing.assert_close(model.render_rays(*rays).color, kernels.color)
    with pytest.raises(InputError, match=r"field_config\.march=triton: Triton kernels need a CUDA device"):
        field_config("grid", {"march": "triton"}).check_device(torch.device("cpu"))
    with pytest.raises(InputError, match="march"):
        field_config("grid", {"march": "cuda"})


def test_train_names_the_field_option_it_refuses(
    dataset_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """In ``train``, an error about ``field_config.KEY`` names ``--field-option KEY``: one line, exit 2."""
    from spikenerf.cli import main

    monkeypatch.setenv("TRITON_INTERPRET", "0")  # a CPU without the interpreter
    base = ["train", str(dataset_dir), "--device", "cpu", "--iters", "2", "--out", str(tmp_path / "run")]
    cases = {
        "march=triton": "--field-option march=triton: Triton kernels need a CUDA device",
        "early_stop=0.7": "--field-option early_stop must be a finite number in [0, 0.5]",
    }
    for option, words in cases.items():
        with pytest.raises(SystemExit) as exit_:
            main([*base, "--field-option", option])
        err = capsys.readouterr().err
        assert exit_.value.code == 2 and words in err and err.count("\n") == 1, err
    assert not (tmp_path / "run").exists()


def test_a_short_training_run_with_the_triton_march_is_the_torch_one(
    dataset_dir: Path, tmp_path: Path
) -> None:
    """The same seed, 6 iterations with the static budget: the same samples, so the same run."""
    assert test_static_render.short_runs_differ(dataset_dir, tmp_path, "march", DEVICE.type) < 1e-4
