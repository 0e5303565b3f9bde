"""Marks for ``torch.compile`` that do not import its compiler (Dynamo) until something compiles.

``torch.compiler.assume_constant_result`` imports ``torch._dynamo`` as it decorates: 2–3 s on a busy CPU,
paid by every command that imported a field (``info``, ``render``, ``eval``), though only ``--compile``
traces anything. :func:`constant_result` marks a function the way that decorator does (the attribute Dynamo
reads at tracing) without that import, and :func:`prepare_compile`, called before each ``torch.compile`` of
ours, applies the official decorator to every function marked so far, in case a torch version reads
something else.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any, TypeVar, get_type_hints

F = TypeVar("F", bound=Callable)

#: functions marked by :func:`constant_result` that the official decorator has not seen yet
_PENDING: list[Callable] = []


def constant_result(fn: F) -> F:
    """``torch.compiler.assume_constant_result`` without importing Dynamo: ``fn``'s result is a constant to
    a trace (a host query fixed per process or device). Returns ``fn`` itself."""
    # Dynamo stores the result as a global of the traced module named after ``fn``'s code; before torch 2.6
    # it overwrote a global of that name: ``fn`` itself, where that module defines or imports it
    fn.__code__ = fn.__code__.replace(co_name=f"{fn.__code__.co_name}_constant")
    if "torch._dynamo" in sys.modules:  # already paid for: the official decorator at once
        import torch

        return torch.compiler.assume_constant_result(fn)
    fn._dynamo_marked_constant = True  # type: ignore[attr-defined]  # what the decorator sets (torch 2.x)
    _PENDING.append(fn)
    return fn


def prepare_compile() -> None:
    """Pass the functions :func:`constant_result` marked to ``torch.compiler.assume_constant_result``
    (imports Dynamo), and turn off Dynamo's two-line advice on Python 3.13.0 (slower guards, fixed in
    3.13.1), a warning about the user's Python, not about the run. Call it before ``torch.compile``."""
    import torch
    import torch._dynamo.config

    if hasattr(torch._dynamo.config, "issue_3_13_0_warning"):  # (its own switch, where torch has one)
        torch._dynamo.config.issue_3_13_0_warning = False
    while _PENDING:
        torch.compiler.assume_constant_result(_PENDING.pop())


def custom_op(name: str) -> Callable[[Callable], Any]:
    """``torch.library.custom_op(name, mutates_args=())`` for a function of a module with postponed
    annotations: torch 2.4 infers the op's schema from annotations that are types, not strings."""
    import torch

    def register(fn: Callable) -> Any:
        fn.__annotations__ = get_type_hints(fn)
        return torch.library.custom_op(name, mutates_args=())(fn)

    return register
