"""``train --compile-optimizer``: the Adam update as one compiled graph (issue 27).

The eager step runs torch's fused Adam: one multi-tensor kernel per parameter group, but a few hundred
microseconds of Python around it every step. :class:`CompiledAdamStep` runs ``optimizer.step`` through
``torch.compile`` instead (the recipe of torch's "compiled optimizer" tutorial): inductor fuses the update of
every parameter into a few kernels and the Python runs once, at tracing.

- The learning rates are 0-dim CPU tensors (:func:`use_tensor_lr`), changed in place by the schedule
  (``optimizer.set_learning_rate``), so the decay does not recompile: a float rate is a constant of the graph.
- A new optimiser (after the grid's upsampling replaces the parameters) gets a new wrapper; its graph is a
  recompile of the same code, the changed sizes traced as symbols from the second one on (Dynamo's automatic
  dynamic shapes), so a run compiles two or three times.
- It is plain ``torch.optim.Adam`` (no ``fused``, no ``DenseAdam``): inductor reads the channels-last grid
  factors as they are.
- A checkpoint stores each group's flags and rate with its state; :func:`load_state` keeps the optimiser's
  own, so a run resumes with or without ``--compile-optimizer`` whichever way it was started.
- Fallback: if compiling raises (the first call of an optimiser's compiled update), one warning line and the
  eager ``optimizer.step`` from then on, for later optimisers too; the parameters are not updated by a
  failed compile (Dynamo may have initialised the optimiser's state and flags, as its first step would).
  A compiled update that ran before and raises is not retried eagerly (it may have updated part of the
  parameters): the error propagates.

On a CPU it is slower: at a 100³ grid the compiled update took 3.57 ms against fused Adam's 1.60 ms, one
thread (``benchmarks/tools/bench_optimizer.py``; docs/performance.md). It is meant for CUDA, where it is not
measured yet.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import torch

from spikenerf.core.errors import one_line
from spikenerf.core.tracing import prepare_compile
from spikenerf.train.compiled_step import allow_recompiles

FAILED = "torch.compile of the optimiser step failed, stepping eagerly: "
#: the ``torch.compile`` backend (None: inductor); tests set a cheaper one
BACKEND: str | None = None
#: the implementation flags a checkpoint stores in each parameter group; :func:`load_state` keeps the
#: optimiser's own
FLAGS = ("foreach", "fused", "capturable", "differentiable")
#: Dynamo's note that the optimiser's profiler range is not traced, on every compile
_PROFILER_NOTE = "will be ignored"


def _quiet(record: logging.LogRecord) -> bool:
    return _PROFILER_NOTE not in record.getMessage()


def use_tensor_lr(optimizer: torch.optim.Optimizer) -> None:
    """Make each group's ``lr`` a 0-dim float32 CPU tensor of the same value, in place (a float rate is a
    constant of a compiled graph: each change would recompile)."""
    for group in optimizer.param_groups:
        group["lr"] = torch.tensor(float(group["lr"]), dtype=torch.float32)


def set_lr(group: dict[str, Any], value: float) -> None:
    """Set ``group``'s rate to ``value``: in place where it is a tensor (see :func:`use_tensor_lr`)."""
    if isinstance(group["lr"], torch.Tensor):
        group["lr"].fill_(value)
    else:
        group["lr"] = value


def load_state(optimizer: torch.optim.Optimizer, state: dict[str, Any]) -> None:
    """``optimizer.load_state_dict(state)``, keeping ``optimizer``'s implementation flags (:data:`FLAGS`)
    and the kind of its rates (float or tensor): ``load_state_dict`` takes both from ``state``, which may come
    from a run with the other ``--compile-optimizer`` setting, or another device. Adam's ``step`` counters go
    where the kept flags want them (on the parameter's device for fused or capturable, else the CPU)."""
    groups = optimizer.param_groups
    kept = [({k: g[k] for k in FLAGS if k in g}, isinstance(g["lr"], torch.Tensor)) for g in groups]
    optimizer.load_state_dict(state)
    for group, (flags, tensor_lr) in zip(optimizer.param_groups, kept, strict=True):
        group.update(flags)
        rate = float(group["lr"])
        group["lr"] = torch.tensor(rate, dtype=torch.float32) if tensor_lr else rate
        on_device = bool(group.get("fused")) or bool(group.get("capturable"))
        for p in group["params"]:
            step = optimizer.state.get(p, {}).get("step")
            if isinstance(step, torch.Tensor):
                where = p.device if on_device else torch.device("cpu")
                optimizer.state[p]["step"] = step.to(device=where, dtype=torch.float32)


class CompiledAdamStep:
    """``optimizer.step`` compiled (see the module doc); eager from its first failure on (``warn`` told
    once). Call it instead of ``optimizer.step()``."""

    def __init__(self, optimizer: torch.optim.Optimizer, warn: Callable[[str], None], compiles: int) -> None:
        """``compiles``: how many optimisers a run may build (each one recompiles; Dynamo's limit is
        raised to it)."""
        self.warn = warn
        self.failed: str | None = None
        logger = logging.getLogger("torch._dynamo.variables.ctx_manager")
        if _quiet not in logger.filters:
            logger.addFilter(_quiet)
        allow_recompiles(compiles)
        self.use(optimizer)

    def use(self, optimizer: torch.optim.Optimizer) -> None:
        """Step ``optimizer`` from now on (a new one after the parameters were replaced); still eagerly
        after a failure."""
        self.optimizer = optimizer
        options: dict[str, Any] = {} if BACKEND is None else {"backend": BACKEND}
        prepare_compile()
        self.compiled = torch.compile(optimizer.step, **options)
        self.ran = False  # this optimiser's compiled update has run (a later failure is not a compile's)

    def __call__(self) -> None:
        if self.failed is None:
            try:
                self.compiled()
                self.ran = True
                return
            except Exception as err:  # a compiler failure: the eager step is a correct answer
                if self.ran:
                    raise
                self.failed = one_line(f"{type(err).__name__}: {err}")
                self.warn(FAILED + self.failed)
        self.optimizer.step()
