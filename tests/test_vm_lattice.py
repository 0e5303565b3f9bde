"""The occupancy grid's density pass on a lattice (``fields/vm_lattice.py``) and its dilation
(``fields/occupancy.py: dilate``): the same values as the point-by-point lookups and ``F.max_pool3d``."""

from __future__ import annotations

import contextlib

import pytest
import torch
import torch.nn.functional as F

from spikenerf.fields.grid import GridField
from spikenerf.fields.grid_config import GridFieldConfig
from spikenerf.fields.occupancy import OccupancyGrid, dilate
from spikenerf.fields.vm_gather import gather_vm
from spikenerf.fields.vm_kernel import suspended
from spikenerf.fields.vm_lattice import lattice_weights, vm_lattice_sum


def _factors(c: int = 4, r: int = 9, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return torch.randn(3, c, r, r, generator=g), torch.randn(3, c, r, 1, generator=g)


@pytest.mark.parametrize("cells", [1, 5, 9, 16])
def test_lattice_sums_equal_the_point_lookups(cells: int) -> None:
    planes, lines = _factors()
    coords = (torch.arange(cells, dtype=torch.float32) + 0.5) * (2.0 / cells) - 1.0
    xyz = torch.stack(torch.meshgrid(coords, coords, coords, indexing="ij"), dim=-1).reshape(-1, 3)
    want = gather_vm(planes, lines, xyz).sum(dim=(1, 2)).reshape(cells, cells, cells)
    torch.testing.assert_close(vm_lattice_sum(planes, lines, coords), want, rtol=1e-5, atol=1e-5)


def test_lattice_sums_keep_zeros_padding_outside_the_grid() -> None:
    planes, lines = _factors(r=5)
    coords = torch.tensor([-1.3, -1.0, -0.2, 0.7, 1.0, 1.6])  # the ends, and points outside [−1, 1]
    xyz = torch.stack(torch.meshgrid(coords, coords, coords, indexing="ij"), dim=-1).reshape(-1, 3)
    want = gather_vm(planes, lines, xyz).sum(dim=(1, 2)).reshape(6, 6, 6)
    torch.testing.assert_close(vm_lattice_sum(planes, lines, coords), want, rtol=1e-5, atol=1e-5)


def test_lattice_weights_interpolate_linearly() -> None:
    w = lattice_weights(torch.tensor([-1.0, 0.0, 0.5, 1.0]), 5)  # texels at −1, −0.5, 0, 0.5, 1
    values = torch.tensor([0.0, 10.0, 20.0, 30.0, 40.0])
    torch.testing.assert_close(w @ values, torch.tensor([0.0, 20.0, 30.0, 40.0]))
    torch.testing.assert_close(w.sum(1), torch.ones(4))


def test_lattice_sums_reject_factors_of_the_wrong_shape() -> None:
    planes, lines = _factors()
    with pytest.raises(ValueError, match="planes/lines"):
        vm_lattice_sum(planes[:, :2], lines, torch.zeros(3))


@pytest.mark.parametrize("kernel", [True, False])
def test_grid_density_on_the_lattice_equals_density_norm(kernel: bool) -> None:
    torch.manual_seed(0)
    field = GridField(
        1, torch.tensor([[-1.0] * 3, [1.0] * 3]), GridFieldConfig(n_voxels_init=12**3, n_voxels_final=12**3)
    )
    coords = field.occupancy.axis_centres()
    g = coords.shape[0]
    with torch.no_grad(), contextlib.nullcontext() if kernel else suspended():  # kernel, grid_sample
        want = field.density_norm(field.occupancy.cell_centres()).reshape(g, g, g)
        got = field.density_lattice(coords)
    torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-4)


def test_the_lattice_density_has_gradients_like_the_lookups() -> None:
    planes, lines = _factors(c=2, r=4)
    planes, lines = planes.double().requires_grad_(), lines.double().requires_grad_()
    coords = torch.tensor([-0.6, 0.1, 0.8], dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda p, ln: vm_lattice_sum(p, ln, coords), (planes, lines))


def test_a_field_update_builds_the_grid_the_point_update_builds() -> None:
    torch.manual_seed(1)
    field = GridField(
        1, torch.tensor([[-1.0] * 3, [1.0] * 3]), GridFieldConfig(n_voxels_init=16**3, n_voxels_final=16**3)
    )
    with torch.no_grad():  # dense where a coordinate is in one band, empty where none is
        field.density_planes.fill_(1.0)
        field.density_lines.fill_(-1.0)
        field.density_lines[:, :, 6:9] = 4.0
    reference = OccupancyGrid(field.occupancy.resolution)
    reference.update(field.density_norm, field.step_size, field.config.occupancy_threshold)
    field.update_occupancy()
    assert 0.0 < reference.occupied_fraction() < 1.0
    assert torch.equal(field.occupancy.grid, reference.grid)
    torch.testing.assert_close(field.occupancy.bounds, reference.bounds)


@pytest.mark.parametrize("radius", [0, 1, 2, 3])
def test_dilation_equals_a_max_pool(radius: int) -> None:
    occupied = torch.rand(7, 9, 6, generator=torch.Generator().manual_seed(radius)) > 0.93
    pooled = F.max_pool3d(occupied[None, None].float(), 2 * radius + 1, stride=1, padding=radius)[0, 0] > 0.5
    assert torch.equal(dilate(occupied, radius), pooled)
    assert not torch.equal(dilate(occupied, 1), occupied)  # it does grow


def test_dilation_of_a_grid_smaller_than_its_radius_fills_it() -> None:
    occupied = torch.zeros(2, 2, 2, dtype=torch.bool)
    occupied[0, 0, 0] = True
    assert bool(dilate(occupied, 5).all())
    with pytest.raises(ValueError, match="radius"):
        dilate(occupied, -1)


def test_update_from_rejects_a_density_of_another_shape() -> None:
    grid = OccupancyGrid(4)
    with pytest.raises(ValueError, match="sigma"):
        grid.update_from(torch.ones(4, 4, 5), step_size=0.1)


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_a_cuda_update_builds_the_grid_the_cpu_update_builds() -> None:
    torch.manual_seed(2)
    field = GridField(
        1, torch.tensor([[-1.0] * 3, [1.0] * 3]), GridFieldConfig(n_voxels_init=24**3, n_voxels_final=24**3)
    )
    with torch.no_grad():
        field.density_planes.mul_(20.0)
        want = field.density_norm(field.occupancy.cell_centres())
        field.update_occupancy()
        on_gpu = field.to("cuda")
        got = on_gpu.density_lattice(on_gpu.occupancy.axis_centres())
        cpu_grid = field.occupancy.grid.clone()
        on_gpu.update_occupancy()
    torch.testing.assert_close(got.cpu().reshape(-1), want, rtol=1e-4, atol=1e-4)
    assert torch.equal(on_gpu.occupancy.grid.cpu(), cpu_grid)
