"""Optional ``torch.compile`` of a field's per-sample functions (``train --compile``; off by default).

The grid field's ``density_norm`` and ``color_norm`` and the MLP field's two networks are replaced, on the
instance only (the state dict, checkpoints and ``hparams`` are unchanged), by compiled versions with
dynamic shapes (the renderer's packed sample counts change every step). :func:`compile_field` first runs
one small forward and backward pass to compile them; if that fails (no compiler, an unsupported op), or a
compiled call fails later, the field goes back to its eager functions with one warning, and training
goes on.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch

from spikenerf.core.errors import one_line
from spikenerf.core.tracing import prepare_compile
from spikenerf.fields.base import Field


def compiled_parts(field: Field) -> dict[str, tuple[Any, str]]:
    """The per-sample functions of ``field`` that compile: name → (owner object, attribute name)."""
    if hasattr(field, "density_norm") and hasattr(field, "color_norm"):
        return {"density_norm": (field, "density_norm"), "color_norm": (field, "color_norm")}
    return {name: (getattr(field, name), "forward") for name in ("coarse", "fine") if hasattr(field, name)}


def dynamic_parameters() -> Any:
    """A context in which parameter sizes are traced as symbols once they change (a grid's upsampling):
    without it every new resolution recompiles, and a run's upsamplings (× grad on and off) pass Dynamo's
    recompile limit. Imports Dynamo (not at import time: see ``core/tracing.py``)."""
    return torch._dynamo.config.patch(force_parameter_static_shapes=False)


class Fallback:
    """Calls ``compiled`` (within :func:`dynamic_parameters`); after its first failure, ``eager`` from then on
    (``on_fail`` is told once)."""

    def __init__(self, eager: Callable, compiled: Callable, on_fail: Callable[[str], None]) -> None:
        self.eager, self.compiled, self.on_fail = eager, compiled, on_fail
        self.failed: str | None = None

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        if self.failed is None:
            try:
                with dynamic_parameters():
                    return self.compiled(*args, **kwargs)
            except Exception as err:  # any compiler failure: eager is always a correct answer
                self.failed = one_line(f"{type(err).__name__}: {err}")
                self.on_fail(self.failed)
        return self.eager(*args, **kwargs)


def _trial(field: Field) -> None:
    """One small forward and backward pass through the field's functions (compiles them); grads cleared."""
    gen = torch.Generator().manual_seed(0)  # the global RNG is left alone
    dev = field.scene_box.device
    xyz = (torch.rand(64, 3, generator=gen) * 1.8 - 0.9).to(dev)
    dirs = torch.nn.functional.normalize(torch.randn(64, 3, generator=gen), dim=-1).to(dev)
    parts = compiled_parts(field)
    if "density_norm" in parts:
        total = field.density_norm(xyz).sum() + field.color_norm(xyz, dirs).sum()  # type: ignore[operator]
    else:
        total = sum(sum(o.sum() for o in getattr(field, n)(xyz, dirs)) for n in parts)  # type: ignore[misc]
    total.backward()
    for p in field.parameters():
        p.grad = None


def compile_field(field: Field, warn: Callable[[str], None]) -> bool:
    """Compile ``field``'s per-sample functions in place (see the module doc); True when the compiled ones
    are in use, False (after ``warn`` with the reason, one line) when the field stays eager."""
    parts = compiled_parts(field)
    eager = {name: getattr(owner, attr) for name, (owner, attr) in parts.items()}

    def restore(reason: str) -> None:
        for name, (owner, attr) in parts.items():
            if attr in vars(owner):
                delattr(owner, attr)  # the class's eager method again
            elif getattr(owner, attr) is not eager[name]:
                setattr(owner, attr, eager[name])
        warn(f"torch.compile of the {type(field).__name__} failed, training eagerly: {reason}")

    try:
        prepare_compile()
        for name, (owner, attr) in parts.items():
            compiled = torch.compile(eager[name], dynamic=True)
            setattr(owner, attr, Fallback(eager[name], compiled, restore))
        _trial(field)
    except Exception as err:  # the trial failed: no compiler, an unsupported op, ...
        restore(one_line(f"{type(err).__name__}: {err}"))
        return False
    return all(isinstance(getattr(owner, attr), Fallback) for owner, attr in parts.values())
