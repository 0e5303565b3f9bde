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
import math
from dataclasses import dataclass, replace
from typing import ClassVar, Literal

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from spikenerf.core.config import Bound
from spikenerf.core.errors import InputError
from spikenerf.core.tracing import constant_result
from spikenerf.fields.base import Field
from spikenerf.fields.encoding import encoded_size, positional_encoding
from spikenerf.fields.occupancy import OccupancyGrid
from spikenerf.fields.row_buckets import bucketing, pad_to_bucket
from spikenerf.fields.vm_gather import MAT, VEC, gather_vm
from spikenerf.fields.vm_kernel import available, cpu_has, usable, vm_lookup
from spikenerf.fields.vm_lattice import vm_lattice_sum
from spikenerf.fields.vm_triton import applies, triton_vm, why_not

FACTORS = ("density_planes", "density_lines", "app_planes", "app_lines")

#: how the grid field reads its factors (``GridFieldConfig.lookup``)
Lookup = Literal["auto", "gather", "triton"]
#: how the grid's renderer sums along its rays (``GridFieldConfig.composite``)
Composite = Literal["torch", "triton"]
#: how the grid's renderer places its samples (``GridFieldConfig.march``)
March = Literal["torch", "triton"]


#: the options that choose how the same model is computed (which kernels), not the model
KERNEL_OPTIONS = ("lookup", "composite", "march")


@dataclass(frozen=True)
class GridFieldConfig:
    """Hyper-parameters of the grid field (defaults sized for minutes of CPU training).

    Attributes:
        n_voxels_init / n_voxels_final: grid size at the start and at the end, as a voxel count (R =
            round(n^(1/3)) cells a side).
        upsample_steps: the steps (completed optimiser steps) at which the grid grows, log-spaced in voxels
            from ``n_voxels_init`` to ``n_voxels_final``, written for ``iterations`` steps and scaled to the
            run's length (see ``iterations``).
        density_components / app_components: VM rank per axis pair of the density and appearance factors.
        app_dim: decoder input features.
        hidden: decoder width (two hidden layers).
        view_freqs: octaves of the view-direction encoding.
        init_scale: standard deviation of the factors' random initial values.
        density_shift / distance_scale: ``σ = distance_scale · softplus(raw + density_shift)`` per world unit.
        step_ratio: marching step in cells (TensoRF's is 0.5).
        max_samples: cap on samples per ray.
        weight_threshold: colour is decoded only where the compositing weight exceeds it.
        early_stop: early ray termination in training renders: the samples behind which a ray's
            transmittance has fallen below it count as empty (zero density and gradient; the gradients
            they would get scale with their transmittance), so the CPU kernel's backward skips them; 0 keeps
            every sample. Renders without gradients (``eval``, ``render``) keep every sample.
        static_samples: a fixed budget of N sample slots a ray in training renders, for CUDA graphs (0, the
            default: none, the renderer packs exactly the samples it keeps; shapes depend on the data, so
            the host reads sample counts back). N > 0: ``N × rays`` slots per render call, with no
            data-dependent shape and no host sync (for CUDA graphs / ``torch.compile(fullgraph=True)``):
            the march (4 × that many candidate steps in torch, every step with ``march`` "triton") moves
            the steps inside occupied cells, in order, into the budget, where density and colour are
            evaluated (unfilled slots get zero density). When a call's rays keep more samples than the
            budget the samples past it are dropped (the ray at the end of the budget loses its tail, later
            rays get none; the render output counts them). See ``GridModel``.
        static_colors: with ``static_samples``, colour is decoded in C slots a ray only (0, the default: in
            every slot). C > 0: the ``C × rays`` slots with the largest weights above ``weight_threshold``
            in the call (``torch.topk``: still no data-dependent shape); a weight beyond them keeps its
            place in the opacity but adds no colour (the render output counts them in ``dropped_colors``).
        static_visible: with ``static_samples`` and ``early_stop``, a second budget of V slots a ray for the
            samples before each ray's early stop (0, the default: none; density and its gradient are
            evaluated in every slot of the budget). V > 0: the density is first evaluated there without
            gradient, and the slots before each ray's early stop are moved, in order, into a second budget
            of ``V × rays`` slots, where it is evaluated again with its gradient (and colour decoded): the
            backward, which costs the most on a GPU, sees V slots a ray, not N. Samples past it are cut
            and counted like the first budget's.
        lookup: how the factors are read (:data:`Lookup`): the fused CPU kernel or ``grid_sample`` ("auto"),
            index gathers, or Triton kernels on CUDA. "auto" (the default): the fused CPU kernel
            where it applies, else ``grid_sample``. "gather": index gathers of channel rows
            (``fields/vm_gather.py``): the same values, as ops that ``torch.compile`` can fuse with its
            backward (slower on a CPU). "triton": the Triton kernels of ``fields/vm_triton.py`` on CUDA
            (training refuses a device they cannot run on; elsewhere, e.g. ``eval`` on a CPU, "auto").
            On an H200 a "triton" lookup ran 5–7× as fast as ``grid_sample`` and a "gather" one 3–6× as
            slow (docs/performance.md).
        composite: how the renderer sums along its rays (:data:`Composite`): torch ops, or Triton kernels on
            CUDA (experimental; the ``triton`` extra; ``train`` refuses them off CUDA, ``eval`` and ``render``
            fall back to torch). "torch" (the default): a float64
            running sum for the transmittance and per-ray sums of torch ops. "triton": the Triton kernels of
            ``render/volume_triton.py``, one program per ray, on CUDA (training refuses a device they
            cannot run on; elsewhere "torch"). Not yet timed on a GPU.
        march: how the renderer places its samples (:data:`March`): torch ops, or Triton kernels on CUDA
            (experimental; the ``triton`` extra; ``train`` refuses them off CUDA, ``eval`` and ``render``
            fall back to torch). "torch" (the default): every candidate
            step laid out, tested against the ray's end and the occupancy grid, and compacted, in torch
            ops. "triton": the Triton kernels of ``render/march_triton.py``, one program per ray, which
            store the kept steps only, on CUDA (training refuses a device they cannot run on; elsewhere
            "torch"). The same samples in tests (Triton's CPU interpreter); not yet run on a GPU.
        decoder_bf16: run the appearance basis and the decoder in bfloat16 (autocast: float32 accumulation,
            the logit rounded to bf16; the sigmoid, the grids and the compositing stay float32) where the
            device multiplies bfloat16 natively (:func:`native_bf16`: a CPU with AVX512-BF16 or AMX, a CUDA
            GPU with bf16); float32 elsewhere, and everywhere with ``False``.
            On a CPU its rows are padded to a bucket (``fields/row_buckets.py``): oneDNN builds a bf16
            kernel for each new row count, which cost more than the products themselves.
        occupancy / occupancy_*: empty-space skipping: a grid of at most ``occupancy_max_resolution`` cells
            a side, rebuilt at ``occupancy_start`` and every ``occupancy_every`` steps (scaled as
            ``upsample_steps`` are), marks the cells whose one-step opacity is below ``occupancy_threshold``
            empty. The occupancy grid is rebuilt at
            ``occupancy_start`` and every
            ``occupancy_every`` steps after (and after each upsampling once started); cells whose one-step
            opacity is below ``occupancy_threshold`` are skipped; its resolution is
            ``min(R, occupancy_max_resolution)``.
        lr_grid / lr / lr_final_ratio: Adam learning rates of the grids and of the networks; both decay
            exponentially to ``lr_final_ratio`` times their value over the run (trainer side).
        l1_weight: weight of the L1 sparsity prior on the density factors (see ``regularization``).
        tv_density / tv_app: weights of the total-variation prior on the density and appearance factors
            (TensoRF's smoothness prior; against fitting the noise of spike-count targets; see
            ``regularization``).
        tv_every: the prior is evaluated every this many steps, weighted by it (the same weight per step on
            average at a fraction of the cost).
        iterations: the run length the step values (``upsample_steps``, ``occupancy_start``,
            ``occupancy_every``) are written for: ``train`` scales them, the defaults and yours, by its
            iterations over this, unless this is set too (then they are taken as given). See
            :meth:`for_iterations`.
    """

    _ABOVE0, _LEAST0 = Bound(above=0), Bound(least=0)
    BOUNDS: ClassVar[dict[str, Bound]] = {  # ≥ 8 voxels: R ≥ 2 per axis
        "n_voxels_init": Bound(least=8), "n_voxels_final": Bound(least=8), "upsample_steps": _LEAST0,
        "density_components": _ABOVE0, "app_components": _ABOVE0, "app_dim": _ABOVE0, "hidden": _ABOVE0,
        "view_freqs": _LEAST0, "init_scale": _LEAST0, "distance_scale": _ABOVE0, "step_ratio": _ABOVE0,
        "max_samples": _ABOVE0, "weight_threshold": _LEAST0, "early_stop": Bound(least=0, most=0.5),
        "static_samples": _LEAST0,
        "static_colors": _LEAST0, "static_visible": _LEAST0,
        "occupancy_start": _LEAST0, "occupancy_every": Bound(least=1), "occupancy_threshold": _LEAST0,
        "occupancy_max_resolution": Bound(least=1),
        "lr_grid": _ABOVE0, "lr": _ABOVE0, "lr_final_ratio": Bound(above=0, most=1),
        "l1_weight": _LEAST0, "tv_density": _LEAST0, "tv_app": _LEAST0,
        "tv_every": Bound(least=1), "iterations": _ABOVE0,
    }  # fmt: skip

    n_voxels_init: int = 64**3
    n_voxels_final: int = 200**3
    upsample_steps: tuple[int, ...] = (500, 1000, 1500, 2000)
    density_components: int = 16
    app_components: int = 24
    app_dim: int = 27
    hidden: int = 64
    view_freqs: int = 2
    init_scale: float = 0.1
    density_shift: float = -10.0
    distance_scale: float = 25.0
    step_ratio: float = 0.75
    max_samples: int = 1024
    weight_threshold: float = 1e-4
    early_stop: float = 1e-4
    static_samples: int = 0
    static_colors: int = 0
    static_visible: int = 0
    lookup: Lookup = "auto"
    composite: Composite = "torch"
    march: March = "torch"
    decoder_bf16: bool = True
    occupancy: bool = True
    occupancy_start: int = 250
    occupancy_every: int = 500
    occupancy_threshold: float = 1e-4
    occupancy_max_resolution: int = 128
    lr_grid: float = 0.02
    lr: float = 1e-3
    lr_final_ratio: float = 0.1
    l1_weight: float = 0.0
    tv_density: float = 0.0
    tv_app: float = 0.0
    tv_every: int = 4
    iterations: int = 3000

    def for_iterations(self, iterations: int) -> GridFieldConfig:
        """The same config with its step schedules rescaled from ``self.iterations`` to ``iterations``."""
        s = iterations / self.iterations
        return replace(
            self,
            upsample_steps=tuple(max(1, round(k * s)) for k in self.upsample_steps),
            occupancy_start=max(1, round(self.occupancy_start * s)),
            occupancy_every=max(1, round(self.occupancy_every * s)),
            iterations=iterations,
        )

    def check(self) -> None:
        """InputError (naming the option) for a colour or visible budget without a sample budget, or a
        visible budget without ``early_stop``."""
        for name in ("static_colors", "static_visible"):
            if getattr(self, name) and not self.static_samples:
                raise InputError(
                    f"field_config.{name} {getattr(self, name)} needs a static sample budget: set "
                    "field_config.static_samples too (e.g. 64)",
                    param=f"field_config.{name}",
                )
        if self.static_visible and not self.early_stop:
            raise InputError(
                f"field_config.static_visible {self.static_visible} needs field_config.early_stop > 0 "
                "(the transmittance at which a ray stops)",
                param=("field_config.static_visible", "field_config.early_stop"),
            )

    def check_device(self, device: torch.device) -> None:
        """InputError (naming the option) for ``lookup``, ``composite`` or ``march`` "triton" on a device
        where its kernels cannot run."""
        for name in KERNEL_OPTIONS:
            reason = why_not(device) if getattr(self, name) == "triton" else ""
            if reason:
                raise InputError(f"field_config.{name}=triton: {reason}", param=f"field_config.{name}")

    # the memory estimates of fields/memory.py and ``field_memory``, per field kind
    def training_size(self) -> tuple[float, float]:
        """(parameters, samples per ray) of the training-memory estimate (``field_memory``): the VM factors
        at the largest resolution, and the march along the box's diagonal (or the ``static_samples``
        budget)."""
        r = float(max(self.n_voxels_init, self.n_voxels_final)) ** (1 / 3)
        params = 3.0 * (self.density_components + self.app_components) * (r * r + r)
        return params, float(self.static_samples) or min(
            float(self.max_samples), r * 3**0.5 / self.step_ratio
        )

    def samples_per_ray(self) -> float:
        """Samples of one ray: the march across the box's side at the final resolution (capped by
        ``max_samples``), or the ``static_samples`` budget where one is set."""
        r = float(max(self.n_voxels_init, self.n_voxels_final)) ** (1 / 3)
        return float(self.static_samples) or min(float(self.max_samples), r / self.step_ratio)

    def layer_widths(self) -> list[int]:
        """float32 words of each layer input one sample holds: plane and line values per axis, the
        decoder input with the view encoding, its hidden layers."""
        features = 6 * (self.density_components + self.app_components)
        view = 3 + 6 * self.view_freqs
        return [features, self.app_dim + view, self.hidden, self.hidden]

    def resolutions(self) -> list[int]:
        """Grid resolution R after 0, 1, … upsamplings."""
        n = len(self.upsample_steps) + 1
        lo, hi = math.log(self.n_voxels_init), math.log(self.n_voxels_final)
        return [round(math.exp(lo + (hi - lo) * i / max(n - 1, 1)) ** (1 / 3)) for i in range(n)]

    def resolution_at(self, step: int) -> int:
        """The resolution the grid should have after ``step`` completed optimiser steps."""
        return self.resolutions()[sum(1 for k in self.upsample_steps if step >= k)]


@constant_result  # a host query: fixed per device, traced as a constant
def vm_splits(device: torch.device) -> int:
    """Point chunks per plane so that the CPU kernel's batch threads balance (1 off the CPU).

    The CPU ``grid_sample`` threads only over the batch; three planes on an even thread count leave a thread
    idle, so each plane is repeated ``k`` times (3k divisible by the thread count, k ≤ 4).
    """
    if device.type != "cpu":
        return 1
    threads = torch.get_num_threads()
    return max(1, min(4, threads // math.gcd(3, threads)))


def sample_vm(planes: Tensor, lines: Tensor, xyz: Tensor, splits: int = 1) -> Tensor:
    """Per-axis-pair VM products at normalised points, with two batched 2-D ``grid_sample`` calls.

    Args:
        planes: (3, C, R, R). lines: (3, C, R, 1). xyz: (M, 3) in [−1, 1].
        splits: point chunks per plane along the batch (see :func:`vm_splits`); the result is the same.
    Returns:
        (3, C, M) ``P_m(xyz) · L_m(xyz)``.
    """
    m, c = xyz.shape[0], planes.shape[1]
    k = splits if splits > 1 and m >= 4096 * splits else 1  # splits 1 (CUDA): no guard on m under compile
    pad = (-m) % k
    if pad:
        xyz = torch.cat([xyz, xyz.new_zeros(pad, 3)])
    mat = torch.tensor(MAT, device=xyz.device)
    plane_grid = xyz[:, mat].transpose(0, 1).reshape(3 * k, 1, -1, 2)
    line_coord = xyz[:, list(VEC)].T
    line_grid = torch.stack([torch.zeros_like(line_coord), line_coord], dim=-1).reshape(3 * k, 1, -1, 2)
    if k > 1:
        planes = planes[:, None].expand(3, k, *planes.shape[1:]).reshape(3 * k, *planes.shape[1:])
        lines = lines[:, None].expand(3, k, *lines.shape[1:]).reshape(3 * k, *lines.shape[1:])
    p = F.grid_sample(planes, plane_grid, mode="bilinear", align_corners=True)
    l = F.grid_sample(lines, line_grid, mode="bilinear", align_corners=True)
    out = (p * l).view(3, k, c, -1)
    out = out[:, 0] if k == 1 else out.transpose(1, 2).reshape(3, c, -1)
    return out[..., :m] if pad else out


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

    def _density_of(self, raw: Tensor) -> Tensor:
        """Density per world unit from the summed VM lookups (any shape)."""
        return self.config.distance_scale * F.softplus(raw + self.config.density_shift)

    def density_lattice(self, coords: Tensor) -> Tensor:
        """Density per world unit (G, G, G) at every point of the lattice ``coords``³ ((G,) normalised
        coordinates, index order x, y, z): :meth:`density_norm`'s values there, computed by separable
        interpolation (``fields/vm_lattice.py``) instead of G³ lookups."""
        return self._density_of(vm_lattice_sum(self.density_planes, self.density_lines, coords))

    def color_norm(self, xyz_norm: Tensor, dirs: Tensor) -> Tensor:
        """Linear colour (M, C) in [0, 1] at normalised points (M, 3) seen along unit ``dirs`` (M, 3)."""
        feats = self._vm(self.app_planes, self.app_lines, xyz_norm)
        view = positional_encoding(dirs, self.config.view_freqs)
        m = feats.shape[0]
        feats = feats.reshape(m, -1)
        with _low_precision(xyz_norm.device, self.config.decoder_bf16):
            if bucketing(xyz_norm.device):  # bf16 on a CPU: rows padded to a bucket (fields/row_buckets.py)
                feats, view = pad_to_bucket((feats, view), torch.bfloat16)
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
