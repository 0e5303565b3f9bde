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
import warnings
from collections.abc import Callable
from typing import TypeVar

F = TypeVar("F", bound=Callable)

#: functions marked by :func:`constant_result` that the official decorator has not seen yet
_PENDING: list[Callable] = []


def constant_result(fn: F) -> F:
    """``torch.compiler.assume_constant_result`` without importing Dynamo: ``fn``'s result is a constant to
    a trace (a host query fixed per process or device). Returns ``fn`` itself."""
    if "torch._dynamo" in sys.modules:  # already paid for: the official decorator at once
        import torch

        return torch.compiler.assume_constant_result(fn)
    fn._dynamo_marked_constant = True  # type: ignore[attr-defined]  # what the decorator sets (torch 2.x)
    _PENDING.append(fn)
    return fn


def prepare_compile() -> None:
    """Pass the functions :func:`constant_result` marked to ``torch.compiler.assume_constant_result``
    (imports Dynamo), and mute torch's two-line advice on Python 3.13.0 (slower guards, fixed in 3.13.1):
    a compiled run warns in one line of ours. Call it before ``torch.compile``."""
    import torch

    warnings.filterwarnings("ignore", message="Guards may run slower on Python 3.13", category=RuntimeWarning)
    while _PENDING:
        torch.compiler.assume_constant_result(_PENDING.pop())
