"""The grid field's settings: :class:`GridFieldConfig` (sizes, schedules, budgets, kernels, priors, learning
rates) and the kernel choices (:data:`Lookup`, :data:`Composite`, :data:`March`, :data:`KERNEL_OPTIONS`);
the field itself is ``grid.py``."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import ClassVar, Literal

import torch

from spikenerf.core.config import Bound
from spikenerf.core.errors import InputError
from spikenerf.fields.vm_triton import why_not

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
            device multiplies bfloat16 natively (:func:`spikenerf.fields.grid.native_bf16`: a CPU with
            AVX512-BF16 or AMX, a CUDA GPU with bf16); float32 elsewhere, and everywhere with ``False``.
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
