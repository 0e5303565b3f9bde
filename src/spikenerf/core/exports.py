"""Lazy public exports for package ``__init__`` modules (PEP 562): ``spikenerf.camera.tfp`` imports
``spikenerf.camera.reconstruct`` only when first used, so ``import spikenerf`` and the CLI stay fast and the
package ``__init__`` files create no import cycles."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any


def lazy_exports(
    package: str, exports: dict[str, str]
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """``(__getattr__, __dir__)`` for ``package`` whose public names map to their defining modules."""

    def getattr_(name: str) -> Any:
        if name not in exports:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(exports[name]), name)

    def dir_() -> list[str]:
        return sorted(exports)

    return getattr_, dir_
