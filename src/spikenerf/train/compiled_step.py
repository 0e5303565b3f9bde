"""``train --compile`` with the grid's ``static_samples``: a step's device part as one graph (issue 27).

With ``static_samples`` N > 0 the part of a step after its host draws (:meth:`TrainMethod.step_losses`:
gather the targets, render, loss) has fixed shapes and reads no device value, so :func:`compile_step`
compiles it as one graph, ``torch.compile(fullgraph=True)``: ``mode="reduce-overhead"`` (CUDA graphs) on
CUDA, the default mode on a CPU. Its backward is the graph's compiled backward; the host draws, the
optimiser, the schedules and the logging stay eager. Without ``static_samples`` ``--compile`` compiles the
field's functions instead (``fields/compiled.py``).

- The fused CPU VM kernel is a ``torch.library`` custom op (``fields/vm_kernel.py``), so the CPU graph calls
  it as the eager step does. Before, it was switched off inside the compiled call and the graph sampled the
  factors with ``grid_sample``, whose backward made a compiled CPU step 3.7× slower than an eager one.
- One graph for every grid resolution: the sizes that upsampling changes (the factors' R, the occupancy
  grid's; ``GridField.resized``) are traced as symbols from the first call (``maybe_mark_dynamic``, with
  ``force_parameter_static_shapes`` off inside the call). Before, the first graph was specialised to the
  first resolution and the first upsampling recompiled with symbolic sizes: two compiles a run (on an
  H200 about 60 s and 20 s; on the CPU 55 s and 56 s, against one of 77 s now,
  ``benchmarks/tools/bench_compile_cache.py``). spike-nerf's steps that render a spike window (its draws of
  :meth:`SpikeNeRF.draw_window` follow the rays' ones) make a second graph. A total-variation prior
  (``tv_density``/``tv_app``) adds a graph for the steps where ``iteration % tv_every`` is 0 (only that prior
  reads the iteration; Dynamo makes it a symbolic int after its first change: no recompile per step). Dynamo's
  recompile limit (per method instance) is raised to cover them.
- CUDA graphs: each call starts a new cudagraph-tree step (its outputs of the previous step are dead by
  then); the method's target tensors kept on the GPU are marked static (not copied into the graph's pool at
  every replay); the draws stay CPU tensors, copied to the device inside the graph (inductor's graph
  partition, on by default in recent torch, keeps those CPU ops out of the CUDA graph; without it inductor
  skips CUDA graphs for the step, which stays correct). Where every target tensor lives on the GPU (and no
  pose refiner indexes host tensors with them) the draws are copied there before the call instead, from
  page-locked memory without waiting (:func:`pinned_copies`; a copy from pageable memory synchronises the
  stream): spike-integral's counts and poses, and the image targets' images and poses, are kept there
  (``train/device.py``). The H200 profile before this change: 4.3 host synchronisations a step, 2.4 ms of
  a 13.2 ms step at 16384 rays (nerf-gt); the effect of the change is not measured yet.
- Fallback: if ``torch.compile`` or a compiled call raises (no compiler, a graph break, the recompile limit),
  one warning line and the step runs eagerly from then on, the same function (the global RNG states are put
  back to where the failed call began).
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Callable
from typing import Any

import torch

from spikenerf.core.errors import one_line
from spikenerf.core.tracing import prepare_compile
from spikenerf.fields.compiled import dynamic_parameters
from spikenerf.render.base import RadianceModel
from spikenerf.train.methods import StepLosses, TrainMethod

FAILED = "torch.compile of the training step failed, training eagerly: "
#: the ``torch.compile`` backend (None: its default, inductor, in :func:`step_mode`); tests set a cheaper one
BACKEND: str | None = None
#: trace the sizes that upsampling changes as symbols from the first call (one graph a run); False: the
#: first graph specialised to the first resolution, a recompile after the first upsampling (two graphs;
#: ``benchmarks/tools/bench_compile_cache.py`` times both)
SYMBOLIC_FROM_START = True


def static_samples(model: RadianceModel) -> int:
    """The field's ``static_samples`` (0: the default packed render, or a field without the option)."""
    return int(getattr(model.field.config, "static_samples", 0) or 0)


def step_mode(device: torch.device) -> str | None:
    """The ``torch.compile`` mode of the step on ``device``: CUDA graphs on CUDA, the default elsewhere."""
    return "reduce-overhead" if device.type == "cuda" else None


def compiles_needed(model: RadianceModel, variants: int = 1) -> int:
    """Compiles a run's step may need: two per grid resolution (see the module doc) for each of the step's
    ``variants`` (spike-nerf's steps with and without a spike window), and a margin."""
    resolutions = getattr(model.field.config, "resolutions", lambda: [0])
    return 2 * len(resolutions()) * variants + 4


def allow_recompiles(limit: int) -> None:
    """Raise Dynamo's recompile limit (per code object) to ``limit``; only ever raised (a process-wide
    setting)."""
    config = torch._dynamo.config  # cache_size_limit: recompile_limit's older name, in every torch ≥ 2.3
    if config.cache_size_limit < limit:
        config.cache_size_limit = limit


def _rng_state(device: torch.device) -> tuple[torch.Tensor, torch.Tensor | None]:
    cuda = torch.cuda.get_rng_state(device) if device.type == "cuda" else None
    return torch.get_rng_state(), cuda


def _set_rng_state(device: torch.device, state: tuple[torch.Tensor, torch.Tensor | None]) -> None:
    torch.set_rng_state(state[0])
    if state[1] is not None:
        torch.cuda.set_rng_state(state[1], device)


def _target_tensors(method: TrainMethod) -> list[torch.Tensor]:
    """The tensors that a step reads from the method's target holders (``targets``, ``counts``,
    ``spikes``): every tensor field but a holder's ``HOST_FIELDS`` (read on the host only)."""
    found = []
    for holder in (getattr(method, name, None) for name in ("targets", "counts", "spikes")):
        if holder is None or not dataclasses.is_dataclass(holder):
            continue
        host = getattr(holder, "HOST_FIELDS", ())
        values = (getattr(holder, f.name) for f in dataclasses.fields(holder) if f.name not in host)
        found += [value for value in values if isinstance(value, torch.Tensor)]
    return found


def _mark_static_targets(method: TrainMethod) -> None:
    """Mark the method's target tensors on a CUDA device as fixed addresses (CUDA graphs read them there)."""
    for value in _target_tensors(method):
        if value.device.type == "cuda":
            torch._dynamo.mark_static_address(value)


def draws_to_device(method: TrainMethod, device: torch.device) -> bool:
    """Whether the step's host draws go to ``device`` before the compiled call: on CUDA, where every target
    tensor of the method lives there (so nothing in the step indexes a host tensor with them)."""
    targets = _target_tensors(method)
    return device.type == "cuda" and bool(targets) and all(same_device(t.device, device) for t in targets)


def same_device(where: torch.device, device: torch.device) -> bool:
    """Whether a tensor on ``where`` lives on ``device``, where ``cuda`` without an index means the current
    one (a tensor moved there reports ``cuda:0``, which does not compare equal to ``cuda``)."""
    if where.type != device.type:
        return False
    if device.index is None and where.type == "cuda":
        return where.index == torch.cuda.current_device()
    return device.index is None or where.index == device.index


def pinned_copies(drawn: tuple[torch.Tensor, ...], device: torch.device) -> tuple[torch.Tensor, ...]:
    """``drawn`` copied to ``device`` from page-locked memory without waiting: a copy from pageable
    memory makes the host wait for the GPU to finish the previous step's work (a stream synchronisation
    per copy) so that the next step's host part could not overlap it."""
    return tuple(t.pin_memory().to(device, non_blocking=True) for t in drawn)


class CompiledStep:
    """``method.step_losses`` compiled (see the module doc); eager from its first failure on (``warn`` told
    once, and ``method.step_losses`` is the class's method again)."""

    def __init__(self, method: TrainMethod, device: torch.device, warn: Callable[[str], None]) -> None:
        self.method, self.device, self.warn = method, device, warn
        self.eager = method.step_losses
        mode = step_mode(device)
        options: dict[str, Any] = {"mode": mode} if BACKEND is None else {"backend": BACKEND}
        prepare_compile()
        self.compiled = torch.compile(self.eager, fullgraph=True, **options)
        self.cuda_graphs = BACKEND is None and mode == "reduce-overhead"
        self.move_draws = draws_to_device(method, device)
        self.failed: str | None = None
        self.marked = False  # the resized sizes marked symbolic (on the first call)
        #: a backward of the compiled step has run (the trainer falls back to eager if the first one fails)
        self.backward_ran = False

    def __call__(self, state: Any, iteration: int, drawn: tuple[torch.Tensor, ...]) -> StepLosses:
        if self.failed is None:
            rng = _rng_state(self.device)
            try:
                # cuDNN's grid sampler has no fake-tensor kernel (a 16384-ray step failed to compile on an
                # H200); the step uses no other cuDNN op, so the graph is traced without it
                with torch.backends.cudnn.flags(enabled=False), dynamic_parameters():
                    if not self.marked and SYMBOLIC_FROM_START:
                        self.marked = True
                        for tensor, dims in getattr(state.model.field, "resized", list)():
                            torch._dynamo.maybe_mark_dynamic(tensor, dims)
                    if self.cuda_graphs:
                        torch.compiler.cudagraph_mark_step_begin()
                    if self.move_draws and getattr(state, "pose_refine", None) is None:
                        step = self.compiled(state, iteration, pinned_copies(drawn, self.device))
                    else:
                        step = self.compiled(state, iteration, drawn)
                # fresh containers: a method adds its eager terms (the learned prior) to them
                return dataclasses.replace(step, terms=dict(step.terms), weights=dict(step.weights))
            except Exception as err:  # any compiler failure: the eager step is always a correct answer
                _set_rng_state(self.device, rng)
                self.fail(one_line(f"{type(err).__name__}: {err}"))
        return self.eager(state, iteration, drawn)

    def fail(self, reason: str) -> None:
        """Go eager for good, with one warning line."""
        self.failed = reason
        vars(self.method).pop("step_losses", None)  # the class's eager method again
        self.warn(FAILED + reason)


def compile_step(
    method: TrainMethod, model: RadianceModel, device: torch.device, warn: Callable[[str], None]
) -> bool:
    """Replace ``method.step_losses``, on the instance only, by its :class:`CompiledStep` (compiled on its
    first call); True when installed, False (after ``warn``, one line) when ``torch.compile`` itself fails.
    Call after the targets are on their device."""
    # a graph break is a fullgraph failure, told in the one warning line: not twice
    warnings.filterwarnings("ignore", message="Dynamo does not know how to trace", category=UserWarning)
    allow_recompiles(compiles_needed(model, method.step_variants))
    try:
        if device.type == "cuda":
            _mark_static_targets(method)
        method.step_losses = CompiledStep(method, device, warn)  # type: ignore[method-assign]
    except Exception as err:
        warn(FAILED + one_line(f"{type(err).__name__}: {err}"))
        return False
    return True
