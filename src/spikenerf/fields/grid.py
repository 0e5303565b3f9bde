"""TensoRF-VM factorised radiance grid with a small MLP decoder, coarse-to-fine upsampling and occupancy.

Density and appearance are sums of vector–matrix (VM) products: for the three axis pairs
``(x,y)·z, (x,z)·y, (y,z)·x`` a plane ``P_m`` (C, R, R) times a line ``L_m`` (C, R). Each factor set is
stored as one tensor so that all three planes are read by ONE batched 2-D ``grid_sample`` call (on the CPU
that kernel is vectorised and threads over the batch; the 3-D one is scalar) and the three lines by another
(as width-1 images).

Layout: ``planes[m, c, h, w]`` is the value at ``(coord[MAT[m][0]] ↔ w, coord[MAT[m][1]] ↔ h)``,
``lines[m, c, h, 0]`` at ``coord[VEC[m]] ↔ h``, with coordinates normalised to [−1, 1] over the scene box and
``align_corners=True`` (−1 and 1 are the first and last texel centres). The resolution R is the same on all
axes (cells are anisotropic in a non-cubic box).
"""

from __future__ import annotations

import contextlib

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from spikenerf.core.errors import InputError
from spikenerf.core.tracing import constant_result
from spikenerf.fields.base import Field
from spikenerf.fields.encoding import encoded_size, positional_encoding
from spikenerf.fields.grid_config import GridFieldConfig
from spikenerf.fields.occupancy import OccupancyGrid
from spikenerf.fields.row_buckets import bucket_rows, bucketing, pad_rows
from spikenerf.fields.vm_build import cpu_has
from spikenerf.fields.vm_gather import gather_vm
from spikenerf.fields.vm_kernel import available, usable, vm_lookup, vm_rows, vm_sum_until
from spikenerf.fields.vm_lattice import vm_lattice_sum
from spikenerf.fields.vm_sample import sample_vm, vm_splits
from spikenerf.fields.vm_triton import applies, triton_vm

FACTORS = ("density_planes", "density_lines", "app_planes", "app_lines")


@constant_result  # a host query: fixed per device, traced as a constant
def native_bf16(device: torch.device) -> bool:
    """Whether ``device`` multiplies bfloat16 matrices natively (else bf16 would be emulated, slower)."""
    if device.type == "cuda":  # emulated bf16 (V100, T4) would count by default: ask for the real thing
        return torch.cuda.is_bf16_supported(including_emulation=False) and torch.cuda.get_device_capability(
            device
        ) >= (8, 0)
    return device.type == "cpu" and cpu_has("avx512_bf16", "amx_bf16")


def _low_precision(device: torch.device, on: bool) -> contextlib.AbstractContextManager:
    """bfloat16 autocast on ``device`` if ``on`` and it is native there, else no change (an outer
    ``--amp`` context stays active)."""
    if on and native_bf16(device):
        return torch.autocast(device.type, torch.bfloat16)
    return contextlib.nullcontext()


def _factor(values: Tensor) -> nn.Parameter:
    """A factor (3, C, R, R) or (3, C, R, 1) as a parameter stored channels-last (memory order 3, R, R, C).

    The fused kernel reads and writes that order: no transposed copy of the factors per lookup, and its
    gradients have the parameter's own strides (autograd keeps them without a copy). Values and
    ``state_dict`` keys are those of a contiguous tensor; only the strides differ.
    """
    return nn.Parameter(values.contiguous(memory_format=torch.channels_last))


def total_variation(factor: Tensor) -> Tensor:
    """Scalar (): mean squared difference of neighbouring texels of a factor (3, C, H, W) along H and W
    (a line, W = 1, along H only)."""
    tv = (factor[..., 1:, :] - factor[..., :-1, :]).pow(2).mean()
    if factor.shape[-1] > 1:
        tv = tv + (factor[..., :, 1:] - factor[..., :, :-1]).pow(2).mean()
    return tv


class GridField(Field):
    """Radiance field on TensoRF-VM grids.

    Args:
        channels: 1 (gray) or 3 (rgb). scene_box: (2, 3) world bounds. config: :class:`GridFieldConfig`.
    Colour is linear radiance in [0, 1] (sigmoid): targets are clipped to [0, 1], so highlights brighter than
    white saturate.
    """

    def __init__(self, channels: int, scene_box: Tensor, config: GridFieldConfig | None = None) -> None:
        super().__init__(channels, scene_box, config or GridFieldConfig())
        self._box_size()  # read here, where the box is made: a trace before any eager render reads none
        cfg = self.config
        r, s = cfg.resolutions()[0], cfg.init_scale
        self.density_planes = _factor(s * torch.randn(3, cfg.density_components, r, r))
        self.density_lines = _factor(s * torch.randn(3, cfg.density_components, r, 1))
        self.app_planes = _factor(s * torch.randn(3, cfg.app_components, r, r))
        self.app_lines = _factor(s * torch.randn(3, cfg.app_components, r, 1))
        self.basis = nn.Linear(3 * cfg.app_components, cfg.app_dim, bias=False)
        self.decoder = nn.Sequential(
            nn.Linear(cfg.app_dim + encoded_size(3, cfg.view_freqs), cfg.hidden),
            nn.ReLU(inplace=True),
            nn.Linear(cfg.hidden, cfg.hidden),
            nn.ReLU(inplace=True),
            nn.Linear(cfg.hidden, channels),
        )
        self.occupancy = OccupancyGrid(min(r, cfg.occupancy_max_resolution))
        self.register_buffer("occupancy_step", torch.tensor(-1, dtype=torch.long))

    @property
    def resolution(self) -> int:
        return int(self.density_planes.shape[-1])

    @property
    def step_size(self) -> float:
        """Marching step in world units: ``step_ratio`` × the mean cell size."""
        return self.config.step_ratio * self._box_size() / (self.resolution - 1)

    def _box_size(self) -> float:
        """Mean box edge, read from the device once per box (no host sync per rendered batch). Traced by
        ``torch.compile``, the value an eager call read is a constant (the box's pointer cannot be traced):
        the constructor reads it first (on the box's device), an eager call on another device reads it again;
        recompile after changing the box."""
        if torch.compiler.is_compiling() and hasattr(self, "_box_mean"):
            return self._box_mean
        key = (self.scene_box.data_ptr(), self.scene_box._version)
        if getattr(self, "_box_key", None) != key:
            self._box_key, self._box_mean = key, (self.scene_box[1] - self.scene_box[0]).mean().item()
        return self._box_mean

    def density_norm(self, xyz_norm: Tensor) -> Tensor:
        """Density per world unit (M,) at normalised points (M, 3)."""
        return self._density_of(self._vm_sum(self.density_planes, self.density_lines, xyz_norm))

    def density_until(self, xyz_norm: Tensor, offsets: Tensor, deltas: Tensor, limit: float) -> Tensor:
        """:meth:`density_norm` (M,) of samples packed ray after ray (normalised points (M, 3), ray i's at
        ``offsets[i]:offsets[i + 1]`` of offsets (N + 1,), interval lengths ``deltas`` (M,)), where the fused
        CPU kernel applies only up to each ray's early stop: a sample behind an optical depth ``Σ σ δ`` of
        ``limit`` (and a margin, ``vm_kernel.UNTIL_MARGIN``) of the ray's earlier ones gets density 0, not
        looked up (``vm_kernel.vm_sum_until``; ``render.volume.early_stop_mask`` with ``exp(−limit)`` leaves
        such samples out). Elsewhere (another lookup, the kernel not built), and where ``train --compile``
        replaced :meth:`density_norm`, every sample's density."""
        cfg = self.config
        compiled = "density_norm" in vars(self)
        if compiled or cfg.lookup == "gather" or not usable(self.density_planes, xyz_norm):
            return self.density_norm(xyz_norm)
        raw = vm_sum_until(self.density_planes, self.density_lines, xyz_norm, offsets, deltas,
                           cfg.density_shift, cfg.distance_scale, limit)  # fmt: skip
        return self._density_of(raw)

    def _density_of(self, raw: Tensor) -> Tensor:
        """Density per world unit from the summed VM lookups (any shape)."""
        return self.config.distance_scale * F.softplus(raw + self.config.density_shift)

    def density_lattice(self, coords: Tensor) -> Tensor:
        """Density per world unit (G, G, G) at every point of the lattice ``coords``³ ((G,) normalised
        coordinates, index order x, y, z): :meth:`density_norm`'s values there, computed by separable
        interpolation (``fields/vm_lattice.py``) instead of G³ lookups."""
        return self._density_of(vm_lattice_sum(self.density_planes, self.density_lines, coords))

    def color_norm(self, xyz_norm: Tensor, dirs: Tensor, rays: Tensor | None = None) -> Tensor:
        """Linear colour (M, C) in [0, 1] at normalised points (M, 3) seen along unit ``dirs`` (M, 3); or,
        with ``rays`` (M,) int64, the ray of each point, along its ray's direction, of ``dirs`` (N, 3) one a
        ray (the view encoding made once a ray and gathered: the same values, a fraction of the work)."""
        view = positional_encoding(dirs, self.config.view_freqs)
        if rays is not None:
            view = view.index_select(0, rays)
        m = xyz_norm.shape[0]
        fused = self.config.lookup == "auto" and usable(self.app_planes, xyz_norm)  # the fused CPU kernel
        # (M, 3·C); flatten, not reshape(m, -1): 0 points give (0, 3·C), not an error
        feats = None if fused else self._vm(self.app_planes, self.app_lines, xyz_norm).flatten(1)
        with _low_precision(xyz_norm.device, self.config.decoder_bf16):
            if bucketing(xyz_norm.device):  # bf16 on a CPU: rows padded to a bucket (fields/row_buckets.py)
                rows = bucket_rows(m)  # the kernel writes its bf16 rows itself (vm_kernel.vm_rows)
                view = pad_rows(view, rows, torch.bfloat16)
                if feats is None:
                    feats = vm_rows(self.app_planes, self.app_lines, xyz_norm, rows)
                else:
                    feats = pad_rows(feats, rows, torch.bfloat16)
            elif feats is None:  # (a custom op: autocast leaves its products in float32)
                feats = vm_lookup(self.app_planes, self.app_lines, xyz_norm).flatten(1)
            feats = self.basis(feats)
            logit = self.decoder(torch.cat([feats, view.to(feats.dtype)], dim=-1))
        return torch.sigmoid(logit[:m].float())

    def _vm(self, planes: Tensor, lines: Tensor, xyz_norm: Tensor) -> Tensor:
        """VM products (M, 3, C) by ``lookup``: index gathers ("gather"), the Triton kernels ("triton", where
        they apply), else the fused CPU kernel where it applies, else ``grid_sample``."""
        lookup = self.config.lookup
        if lookup == "gather":
            return gather_vm(planes, lines, xyz_norm)
        if lookup == "triton" and applies(planes, xyz_norm):
            return triton_vm(planes, lines, xyz_norm)
        if usable(planes, xyz_norm):
            return vm_lookup(planes, lines, xyz_norm)
        return sample_vm(planes, lines, xyz_norm, vm_splits(xyz_norm.device)).permute(2, 0, 1)

    def _vm_sum(self, planes: Tensor, lines: Tensor, xyz_norm: Tensor) -> Tensor:
        """:meth:`_vm` summed over axis pairs and channels (M,): inside the Triton or fused CPU kernel where
        one applies (no (M, 3, C) tensor forward or backward)."""
        lookup = self.config.lookup
        if lookup == "triton" and applies(planes, xyz_norm):
            return triton_vm(planes, lines, xyz_norm, summed=True)
        if lookup != "gather" and usable(planes, xyz_norm):
            return vm_lookup(planes, lines, xyz_norm, summed=True)
        return self._vm(planes, lines, xyz_norm).sum(dim=(1, 2))

    def forward(self, xyz: Tensor, dirs: Tensor) -> tuple[Tensor, Tensor]:
        """World points (M, 3), unit dirs (M, 3) → density (M,) per world unit, colour (M, C)."""
        x = self.normalize(xyz)
        return self.density_norm(x), self.color_norm(x, dirs)

    def resized(self) -> list[tuple[Tensor, tuple[int, ...]]]:
        """The tensors that later upsamplings replace by others of a new size, with the dimensions that
        change: the factors' R while it is under the last resolution (planes (3, C, R, R): dims 2, 3; lines
        (3, C, R, 1): dim 2), the occupancy grid's (G, G, G) while G is under ``occupancy_max_resolution``
        (none once the grid is at its final size)."""
        cfg, found = self.config, []
        if cfg.resolutions()[-1] > self.resolution:
            found += [(getattr(self, n), (2, 3) if n.endswith("planes") else (2,)) for n in FACTORS]
        if min(cfg.resolutions()[-1], cfg.occupancy_max_resolution) > self.occupancy.grid.shape[0]:
            found.append((self.occupancy.grid, (0, 1, 2)))
        return found

    @torch.no_grad()
    def upsample(self, resolution: int) -> None:
        """Resample all factors to ``resolution`` (bilinear, so the function is kept approximately)."""
        for name in FACTORS:
            old = getattr(self, name)
            size = (resolution, resolution) if name.endswith("planes") else (resolution, 1)
            new = F.interpolate(old.data, size=size, mode="bilinear", align_corners=True)
            setattr(self, name, _factor(new))
        self.occupancy.resize(min(resolution, self.config.occupancy_max_resolution))

    @torch.no_grad()
    def update_occupancy(self) -> float:
        """Rebuild the occupancy grid from the current density at its cell centres; returns the occupied
        fraction."""
        sigma = self.density_lattice(self.occupancy.axis_centres())
        return self.occupancy.update_from(sigma, self.step_size, self.config.occupancy_threshold)

    def on_step(self, step: int) -> bool:
        """Run the schedules after ``step`` completed optimiser steps; True if parameter shapes changed.

        Idempotent: the target resolution is a function of ``step``; the last occupancy update is recorded.
        """
        cfg = self.config
        target = cfg.resolution_at(step)
        changed = target != self.resolution
        if changed:
            self.upsample(target)
        started = cfg.occupancy and step >= cfg.occupancy_start
        due = started and (step - cfg.occupancy_start) % cfg.occupancy_every == 0
        if (due or (changed and started)) and int(self.occupancy_step) != step:
            self.update_occupancy()
            self.occupancy_step.fill_(step)
        return changed

    def prepare(self) -> None:
        """On a CPU, build (or load) the fused lookup kernel now: the first build takes about a minute,
        which would otherwise count as the first training step's time."""
        if self.scene_box.device.type == "cpu" and self.config.lookup == "auto":  # (gather never uses it)
            available()

    def regularization(self, step: int | None = None) -> Tensor:
        """Scalar (): ``l1_weight`` × mean |density factor| (a sparsity prior against floaters) plus, at
        steps that are multiples of ``tv_every`` (every call when ``step`` is None), ``tv_every`` ×
        ``tv_density`` / ``tv_app`` × the total variation of the density / appearance factors
        (:func:`total_variation`); 0 by default."""
        cfg = self.config
        reg = self.density_planes.new_zeros(())
        if cfg.l1_weight:
            reg = reg + cfg.l1_weight * (self.density_planes.abs().mean() + self.density_lines.abs().mean())
        if not (cfg.tv_density or cfg.tv_app) or (step is not None and step % cfg.tv_every):
            return reg
        every = 1 if step is None else cfg.tv_every
        for weight, planes, lines in ((cfg.tv_density, self.density_planes, self.density_lines),
                                      (cfg.tv_app, self.app_planes, self.app_lines)):  # fmt: skip
            if weight:
                reg = reg + every * weight * (total_variation(planes) + total_variation(lines))
        return reg

    def param_groups(self, base_lr: float | None = None) -> list[dict]:
        """Adam groups: grids at ``lr_grid``, networks at ``lr`` (scaled by ``base_lr / lr``)."""
        scale = 1.0 if base_lr is None else base_lr / self.config.lr
        nets = list(self.basis.parameters()) + list(self.decoder.parameters())
        return [
            {
                "params": [getattr(self, n) for n in FACTORS],
                "lr": self.config.lr_grid * scale,
                "name": "grid",
            },
            {"params": nets, "lr": self.config.lr * scale, "name": "network"},
        ]

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs) -> None:  # type: ignore[no-untyped-def]
        self._check_saved_factors(state_dict, prefix)
        for name in FACTORS:  # a checkpoint of an upsampled grid: take its shapes first
            saved, param = state_dict.get(prefix + name), getattr(self, name)
            if saved is not None and saved.shape != param.shape:
                setattr(self, name, _factor(param.new_empty(saved.shape)))
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def _check_saved_factors(self, state_dict: dict[str, Tensor], prefix: str) -> None:
        """InputError unless the saved factors form one grid: planes (3, C, R, R) and lines (3, C, R, 1) of
        the config's component counts C and one resolution R >= 2 (an upsampled grid has another R than this
        one, which ``_load_from_state_dict`` adopts; factors of different sizes would render from mismatched
        lookups, and the fused kernel's gradient of them fails)."""
        cfg, sizes = self.config, set()
        for name in FACTORS:
            saved = state_dict.get(prefix + name)
            if saved is None or not torch.is_tensor(saved):
                continue  # (load_state_dict names a missing key)
            comps = cfg.density_components if name.startswith("density") else cfg.app_components
            shape = tuple(saved.shape)
            fits = len(shape) == 4 and shape[:2] == (3, comps) and shape[2] >= 2
            fits = fits and shape[3] == (shape[2] if name.endswith("planes") else 1)
            if not fits:
                kind = "(3, C, R, R)" if name.endswith("planes") else "(3, C, R, 1)"
                raise InputError(
                    f"grid factor {prefix + name} has shape {shape}, expected {kind} with C {comps}"
                )
            sizes.add(shape[2])
        if len(sizes) > 1:
            raise InputError(f"the grid factors have different resolutions {sorted(sizes)}")
