"""``fields/vm_gather.py``: the VM lookup by index gathers equals ``grid_sample``'s (values, gradients,
zeros outside the grid), passes gradcheck, serves the grid field with ``lookup="gather"`` and traces as one
graph."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from spikenerf.core.errors import InputError
from spikenerf.fields import field_config
from spikenerf.fields.grid import GridField, _factor
from spikenerf.fields.grid_config import GridFieldConfig
from spikenerf.fields.vm_gather import corners, gather_vm
from spikenerf.fields.vm_sample import sample_vm
from spikenerf.render.model import model_from_hparams

BOX = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])


def _factors(c: int = 5, r: int = 7, dtype: torch.dtype = torch.float32) -> tuple[torch.Tensor, torch.Tensor]:
    torch.manual_seed(0)
    planes = _factor(torch.randn(3, c, r, r, dtype=dtype))
    lines = _factor(torch.randn(3, c, r, 1, dtype=dtype))
    return planes, lines


def _points(m: int = 300, spread: float = 1.8) -> torch.Tensor:
    """Points in [−spread, spread]³ (some outside the grid), the box's corners and texel centres."""
    torch.manual_seed(1)
    edge = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], [-1.0, 1.0, 0.0], [1 / 3, -2 / 3, 0.0]])
    return torch.cat([(torch.rand(m, 3) * 2 - 1) * spread, edge])


def test_values_and_gradients_equal_grid_sample_inside_and_outside_the_grid() -> None:
    planes, lines = _factors()
    xyz = _points().requires_grad_(True)
    expected = sample_vm(planes, lines, xyz).permute(2, 0, 1)
    got = gather_vm(planes, lines, xyz)
    assert got.shape == (len(xyz), 3, 5)
    torch.testing.assert_close(got, expected, atol=1e-5, rtol=1e-5)
    outside = (xyz.detach().abs() > 1 + 2 / 6).all(dim=1)  # more than a texel (2 / (R − 1)) outside
    assert outside.any() and got[outside].abs().max() == 0  # zeros padding
    weights = torch.randn_like(got)
    inputs = [planes, lines, xyz]
    for g, e in zip(torch.autograd.grad((got * weights).sum(), inputs),
                    torch.autograd.grad((expected * weights).sum(), inputs), strict=True):  # fmt: skip
        torch.testing.assert_close(g, e, atol=1e-4, rtol=1e-4)


def test_gradcheck() -> None:
    planes, lines = _factors(c=2, r=4, dtype=torch.float64)
    torch.manual_seed(2)
    xyz = ((torch.rand(9, 3, dtype=torch.float64) * 2 - 1) * 0.9).requires_grad_(True)  # off texel edges
    assert torch.autograd.gradcheck(gather_vm, (planes, lines, xyz))


def test_corners_weights_sum_to_one_inside_and_vanish_outside() -> None:
    coord = torch.tensor([-1.0, -0.5, 0.0, 0.99, 1.0, 1.5, -3.0])
    lo, hi, w_lo, w_hi = corners(coord, 5)
    torch.testing.assert_close((w_lo + w_hi)[:5], torch.ones(5))
    assert torch.equal(w_lo[5:] + w_hi[5:], torch.zeros(2)) and lo.min() >= 0 and hi.max() <= 4
    assert lo.tolist()[:5] == [0, 1, 2, 3, 4] and w_lo[4] == 1  # 1.0 is the last texel's centre


def test_the_grid_field_with_lookup_gather_gives_its_default_lookups_values() -> None:
    config = GridFieldConfig(n_voxels_init=9**3, n_voxels_final=9**3, decoder_bf16=False)
    field = GridField(3, BOX, config)
    xyz, dirs = _points(100, 1.0), torch.nn.functional.normalize(torch.randn(104, 3), dim=-1)
    sigma, rgb = field.density_norm(xyz), field.color_norm(xyz, dirs)
    field.config = dataclasses.replace(config, lookup="gather")
    torch.testing.assert_close(field.density_norm(xyz), sigma, atol=1e-4, rtol=1e-5)
    torch.testing.assert_close(field.color_norm(xyz, dirs), rgb, atol=1e-5, rtol=1e-5)
    explained = torch._dynamo.explain(field.density_norm)(xyz)
    assert (explained.graph_count, explained.graph_break_count) == (1, 0), explained.break_reasons


def test_a_bad_lookup_value_names_the_key_and_the_choices() -> None:
    assert field_config("grid", {"lookup": "gather"}).lookup == "gather"
    with pytest.raises(InputError, match=r"lookup.*one of auto, gather, triton"):
        field_config("grid", {"lookup": "sometimes"})


def test_the_old_gather_lookup_key_still_loads_as_lookup() -> None:
    """Checkpoints and config.yaml files written before the rename hold ``gather_lookup``."""
    assert field_config("grid", {"gather_lookup": True}).lookup == "gather"
    assert field_config("grid", {"gather_lookup": False}).lookup == "auto"
    assert field_config("grid", {"gather_lookup": True, "lookup": "triton"}).lookup == "triton"
    with pytest.raises(InputError, match=r"field_config.gather_lookup must be true or false, got 'yes'"):
        field_config("grid", {"gather_lookup": "yes"})
    hparams = model_from_hparams(
        {"kind": "grid", "channels": 1, "scene_box": BOX.tolist(), "config": {}}
    ).hparams()
    hparams["config"] = {**hparams["config"], "gather_lookup": True}
    hparams["config"].pop("lookup")
    assert model_from_hparams(hparams).field.config.lookup == "gather"


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_gathers_equal_grid_sample_on_cuda() -> None:
    planes, lines = (f.cuda() for f in _factors(c=16, r=33))
    planes, lines = _factor(planes.detach()), _factor(lines.detach())
    xyz = _points(4096).cuda().requires_grad_(True)
    expected = sample_vm(planes, lines, xyz).permute(2, 0, 1)
    got = gather_vm(planes, lines, xyz)
    torch.testing.assert_close(got, expected, atol=1e-5, rtol=1e-5)
    weights = torch.randn_like(got)
    inputs = [planes, lines, xyz]
    for g, e in zip(torch.autograd.grad((got * weights).sum(), inputs),
                    torch.autograd.grad((expected * weights).sum(), inputs), strict=True):  # fmt: skip
        torch.testing.assert_close(g, e, atol=1e-3, rtol=1e-4)
