"""The vanilla NeRF MLP (Mildenhall et al. 2020), the paper's field: positional encoding, 8×256, a skip."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from spikenerf.core.config import Bound
from spikenerf.fields.base import Field
from spikenerf.fields.encoding import encoded_size, positional_encoding


@dataclass(frozen=True)
class MLPFieldConfig:
    """NeRF hyper-parameters (the paper trains with NeRF's own: these defaults).

    Attributes:
        depth / width / skip: trunk layers, their width, and the (0-based) layer whose output is concatenated
            with the encoding again (NeRF's ``skips=[4]``: the sixth layer reads ``width + encoding``).
        xyz_freqs / dir_freqs: positional-encoding octaves of positions (box-normalised to [−1, 1]) and
            of view directions.
        dir_width: width of the view-dependent head.
        n_coarse / n_fine: stratified samples of the coarse network and inverse-CDF samples added for the
            fine one (which evaluates all ``n_coarse + n_fine``).
        raw_noise_std: std of Gaussian noise on raw density while training (0 for synthetic scenes).
        lr / lr_final: Adam learning rate, decayed exponentially to ``lr_final`` (5e-4 → 5e-5).
        iterations: the paper's run length (2·10⁵).
    """

    _ABOVE0, _LEAST0 = Bound(above=0), Bound(least=0)
    BOUNDS: ClassVar[dict[str, Bound]] = {
        "depth": _ABOVE0, "width": _ABOVE0, "skip": _LEAST0, "xyz_freqs": _LEAST0, "dir_freqs": _LEAST0,
        "dir_width": _LEAST0, "n_coarse": _ABOVE0, "n_fine": _LEAST0, "raw_noise_std": _LEAST0,
        "lr": _ABOVE0, "lr_final": _ABOVE0, "iterations": _ABOVE0,
    }  # fmt: skip

    depth: int = 8
    width: int = 256
    skip: int = 4
    xyz_freqs: int = 10
    dir_freqs: int = 4
    dir_width: int = 128
    n_coarse: int = 64
    n_fine: int = 128
    raw_noise_std: float = 0.0
    lr: float = 5e-4
    lr_final: float = 5e-5
    iterations: int = 200_000

    @property
    def lr_final_ratio(self) -> float:
        return self.lr_final / self.lr

    def for_iterations(self, iterations: int) -> MLPFieldConfig:
        """The same config: the MLP has no step schedules to rescale to a run's length."""
        return self

    # the memory estimates of fields/memory.py and ``field_memory``, per field kind
    def training_size(self) -> tuple[float, float]:
        """(parameters, samples per ray) of the training-memory estimate (``field_memory``)."""
        return float(self.depth) * self.width * self.width * 2, float(self.n_coarse + self.n_fine)

    def samples_per_ray(self) -> float:
        """Samples of one ray: coarse + fine (the fine pass re-evaluates the coarse ones)."""
        return float(self.n_coarse + self.n_coarse + self.n_fine)

    def layer_widths(self) -> list[int]:
        """float32 words of each layer input one sample holds: the encoding, the trunk, the encoding again,
        the view encoding and the view head."""
        enc = 3 + 6 * self.xyz_freqs
        return [enc, *([self.width] * self.depth), enc, 3 + 6 * self.dir_freqs, self.dir_width]

    @classmethod
    def tiny(cls) -> MLPFieldConfig:
        """A small network for tests and smoke runs."""
        return cls(depth=2, width=32, skip=0, xyz_freqs=4, dir_freqs=2, dir_width=16, n_coarse=16, n_fine=16)


class NeRFMLP(nn.Module):
    """One NeRF network: normalised points (M, 3) and unit dirs (M, 3) → raw density (M,), colour (M, C)."""

    def __init__(self, channels: int, config: MLPFieldConfig) -> None:
        super().__init__()
        self.config = c = config
        d_xyz, d_dir = encoded_size(3, c.xyz_freqs), encoded_size(3, c.dir_freqs)
        layers = []
        for i in range(c.depth):
            d_in = d_xyz if i == 0 else c.width + (d_xyz if i == c.skip + 1 else 0)
            layers.append(nn.Linear(d_in, c.width))
        self.trunk = nn.ModuleList(layers)
        self.sigma = nn.Linear(c.width, 1)
        self.feature = nn.Linear(c.width, c.width)
        self.head = nn.Linear(c.width + d_dir, c.dir_width)
        self.out = nn.Linear(c.dir_width, channels)

    def forward(self, xyz_norm: Tensor, dirs: Tensor) -> tuple[Tensor, Tensor]:
        """Normalised points (M, 3), unit dirs (M, 3) → raw density (M,), colour (M, C) in [0, 1]."""
        c = self.config
        enc = positional_encoding(xyz_norm, c.xyz_freqs)
        h = enc
        for i, layer in enumerate(self.trunk):
            if i == c.skip + 1:
                h = torch.cat([h, enc], dim=-1)
            h = F.relu(layer(h))
        raw_sigma = self.sigma(h)[..., 0]
        h = torch.cat([self.feature(h), positional_encoding(dirs, c.dir_freqs)], dim=-1)
        return raw_sigma, torch.sigmoid(self.out(F.relu(self.head(h))))


class MLPField(Field):
    """Coarse and fine NeRF networks over a scene box.

    Density is ``relu(raw)`` per world unit; colour is linear radiance in [0, 1] (sigmoid), like NeRF.
    """

    def __init__(self, channels: int, scene_box: Tensor, config: MLPFieldConfig | None = None) -> None:
        super().__init__(channels, scene_box, config or MLPFieldConfig())
        self.coarse = NeRFMLP(channels, self.config)
        self.fine = NeRFMLP(channels, self.config)

    def query(self, xyz: Tensor, dirs: Tensor, fine: bool, noise_std: float = 0.0) -> tuple[Tensor, Tensor]:
        """World points (M, 3), unit dirs (M, 3) → density (M,) per world unit, colour (M, C)."""
        raw, color = (self.fine if fine else self.coarse)(self.normalize(xyz), dirs)
        if noise_std > 0:
            raw = raw + noise_std * torch.randn_like(raw)
        return F.relu(raw), color

    def forward(self, xyz: Tensor, dirs: Tensor) -> tuple[Tensor, Tensor]:
        return self.query(xyz, dirs, fine=True)
