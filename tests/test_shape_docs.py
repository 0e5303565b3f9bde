"""Tensor-handling public functions state their shapes, in the project's one style: a parenthesised shape
beside each tensor in the docstring (``origins (N, 3)``, ``(T, H, W)``, ``(...)``; a scalar is ``()``)."""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import re

import spikenerf.data
import spikenerf.fields
import spikenerf.render

#: a shape: (N, 3), (T, H, W), (M,), (...), (2, 3), (), (n_rays, C)
SHAPE = re.compile(r"\((?:\.\.\.|[A-Z0-9…]|[a-z]\w*,)[^()]*\)|\(\)")
TENSORS = re.compile(r"\b(Tensor|ndarray|Array)\b")
MODULES = [
    *(
        f"{pkg.__name__}.{m.name}"
        for pkg in (spikenerf.render, spikenerf.fields, spikenerf.data)
        for m in pkgutil.iter_modules(pkg.__path__)
    ),
    "spikenerf.camera.reconstruct",
    "spikenerf.camera.streams",
    "spikenerf.camera.tfstp",
    "spikenerf.camera.masks",
    "spikenerf.camera.layout",
    # camera/model.py and the modules split out of it
    *(f"spikenerf.camera.{m}" for m in ("model", "firing", "bayer", "simulation")),
    "spikenerf.core.ply",
    "spikenerf.eval.export",
    "spikenerf.eval.piqe",
    "spikenerf.eval.recon_scores",
    # the modules split out of eval/video.py, capture/simulate.py and importing/importer.py (and those three);
    # fields/ (grid.py and vm_kernel.py split too) is listed whole above
    *(f"spikenerf.eval.{m}" for m in ("video", "trajectories", "render_output")),
    *(f"spikenerf.capture.{m}" for m in ("simulate", "options", "frame_cache", "render_workers")),
    *(f"spikenerf.importing.{m}" for m in ("importer", "options", "keyframes")),
    # the modules split out of importing/alignment.py and importing/poses.py (and those two), and out of
    # pipelines/report.py
    *(
        f"spikenerf.importing.{m}"
        for m in (
            "alignment",
            "interpolation",
            "orientation",
            "normalisation",
            "poses",
            "pose_set",
            "colmap_model",
        )
    ),
    *(f"spikenerf.pipelines.{m}" for m in ("report", "report_tables", "report_figures")),
    # the modules split out of scenes/trajectory.py and train/trainer.py (and what is left of those two)
    *(f"spikenerf.scenes.{m}" for m in ("trajectory", "poses", "render_paths", "projection")),
    *(f"spikenerf.train.{m}" for m in ("trainer", "loop", "preflight", "resume", "optimizer")),
]


def _public_functions(module_name: str) -> list[tuple[str, object]]:
    """Public functions of the module and public methods (and properties) of its public classes."""
    module = importlib.import_module(module_name)
    found = []
    for name, obj in vars(module).items():
        if name.startswith("_") or getattr(obj, "__module__", None) != module_name:
            continue
        if inspect.isfunction(obj):
            found.append((name, obj))
        elif inspect.isclass(obj):
            for attr, member in vars(obj).items():
                func = member.fget if isinstance(member, property) else getattr(member, "__func__", member)
                if not attr.startswith("_") and inspect.isfunction(func):
                    found.append((f"{name}.{attr}", func))
    return found


def _handles_tensors(func: object) -> bool:
    """Takes or returns a tensor/array by its annotations (a bool predicate states no shape)."""
    sig = inspect.signature(func)  # type: ignore[arg-type]
    if str(sig.return_annotation) == "bool":
        return False
    annotations = [str(p.annotation) for p in sig.parameters.values()] + [str(sig.return_annotation)]
    return any(TENSORS.search(a) for a in annotations)


def test_every_tensor_function_in_render_fields_and_reconstruction_states_shapes() -> None:
    missing = [
        f"{module}.{name}"
        for module in MODULES
        for name, func in _public_functions(module)
        if _handles_tensors(func) and not SHAPE.search(inspect.getdoc(func) or "")
    ]
    assert len(MODULES) > 10
    assert not missing, "state the shapes, e.g. 'origins (N, 3)', in the docstring of:\n" + "\n".join(missing)


def test_the_check_sees_a_function_without_shapes() -> None:
    def render(origins: "spikenerf.render.volume.Tensor") -> "spikenerf.render.volume.Tensor":  # noqa: UP037
        """Render the rays."""

    assert _handles_tensors(render) and not SHAPE.search(inspect.getdoc(render) or "")
    assert (
        SHAPE.search("origins (N, 3)") and SHAPE.search("a scalar ()") and not SHAPE.search("TFP (a method)")
    )
