"""The learned reconstructor: a compact two-level U-Net on spike-window features, and its weights file.

``forward(window, scale)`` maps (N, K, H, W) spike windows to (N, H, W) rates (intensity / φ). The network
predicts a brightness-normalised residual over the 11-step TFP rate; the result is multiplied back by the
brightness scale. A weights file (``torch.save`` of plain containers, read with ``weights_only=True``)::

    {"format": FORMAT, "arch": ARCH, "hparams": {"window", "width"}, "modes": [...], "state": fp16 state dict,
     "record": {...}}   # record: how the weights were made (command, data, iterations)
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from spikenerf.camera.modes import COLORS
from spikenerf.camera.reconstruct import DEFAULT_WINDOW, check_window
from spikenerf.core.atomic import atomic_path
from spikenerf.core.errors import InputError
from spikenerf.recon.features import feature_count, nested_lengths, spike_features

FORMAT = "spikenerf-recon-weights-1"
ARCH = "unet2-v1"
#: the weights shipped inside the package
SHIPPED = "recon-v1.pt"
#: colour modes a model can be trained for (rgb = each per-channel stream; bayer = each CFA plane)
MODES = COLORS


@dataclass(frozen=True)
class NetConfig:
    """Architecture: ``window`` K (odd, steps) and ``width`` (channels at full resolution)."""

    window: int = DEFAULT_WINDOW
    width: int = 16

    def check(self) -> NetConfig:
        check_window(self.window, "window", least=3)
        if not isinstance(self.width, int) or self.width < 4:
            raise InputError(f"width must be an integer ≥ 4, found {self.width!r}", param="width")
        return self


def _block(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, padding=1),
        nn.LeakyReLU(0.1),
        nn.Conv2d(cout, cout, 3, padding=1),
        nn.LeakyReLU(0.1),
    )


class ReconNet(nn.Module):
    """Two-level U-Net: features → encoder (1, 1/2, 1/4 resolution) → decoder with skips → residual rate."""

    def __init__(self, config: NetConfig) -> None:
        super().__init__()
        self.config = config.check()
        c1, c2, c3 = config.width, config.width * 3 // 2, config.width * 2
        self.enc1 = _block(feature_count(config.window), c1)
        self.enc2 = nn.Sequential(
            nn.Conv2d(c1, c2, 3, stride=2, padding=1), nn.LeakyReLU(0.1), _block(c2, c2)
        )
        self.mid = nn.Sequential(nn.Conv2d(c2, c3, 3, stride=2, padding=1), nn.LeakyReLU(0.1), _block(c3, c3))
        self.up2, self.dec2 = nn.Conv2d(c3, c2, 1), _block(2 * c2, c2)
        self.up1, self.dec1 = nn.Conv2d(c2, c1, 1), _block(2 * c1, c1)
        self.head = nn.Conv2d(c1, 1, 1)
        self.base = nested_lengths(config.window).index(min(11, config.window))  # the residual's base channel

    def forward(self, window: Tensor, scale: Tensor) -> Tensor:
        """Rates (intensity / φ) of the middle step of each window.

        Args:
            window: (N, K, H, W) 0/1 spikes, K = ``config.window``. scale: (N,) brightness scales.
        Returns:
            float32 (N, H, W); clipped at 0 in eval mode (not while training: the clip would stop gradients).
        """
        if window.dim() != 4 or window.shape[1] != self.config.window:
            raise InputError(
                f"spike window must be (N, {self.config.window}, H, W), found {tuple(window.shape)}"
            )
        return self.decode(spike_features(window, scale), scale)

    def decode(self, feats: Tensor, scale: Tensor) -> Tensor:
        """Rates from features (see :func:`~spikenerf.recon.features.spike_features`).

        Args:
            feats: (N, C, H, W) features (any memory format). scale: (N,) brightness scales.
        Returns:
            float32 (N, H, W), clipped at 0 in eval mode.
        """
        h, w = feats.shape[-2:]
        ph, pw = (-h) % 4, (-w) % 4
        x = nn.functional.pad(feats, (0, pw, 0, ph), mode="replicate") if ph or pw else feats
        e1 = self.enc1(x)
        e2 = self.enc2(e1)
        m = self.mid(e2)
        # the 1×1 up-convolutions run before the nearest up-sampling: the same values at a quarter of the cost
        d2 = self.dec2(torch.cat([nn.functional.interpolate(self.up2(m), scale_factor=2.0), e2], 1))
        d1 = self.dec1(torch.cat([nn.functional.interpolate(self.up1(d2), scale_factor=2.0), e1], 1))
        out = (self.head(d1)[:, 0, :h, :w] + feats[:, self.base]) * scale.to(feats).view(-1, 1, 1)
        return out if self.training else out.clamp_min(0.0)


def save_weights(path: str | Path, net: ReconNet, modes: list[str], record: dict[str, Any]) -> None:
    """Write ``net`` as an fp16 weights file (atomically) for the colour ``modes`` it was trained on."""
    state = {k: v.detach().to("cpu", torch.float16).contiguous() for k, v in net.state_dict().items()}
    payload = {
        "format": FORMAT,
        "arch": ARCH,
        "hparams": asdict(net.config),
        "modes": list(modes),
        "state": state,
        "record": record,
    }
    save_torch(path, payload)


def save_torch(path: str | Path, payload: dict[str, Any]) -> None:
    """``torch.save`` of plain containers, atomically."""
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)


def read_torch(path: Path, what: str, fmt: str) -> dict[str, Any]:
    """Load a dict written by :func:`save_torch` (``weights_only=True``); its ``format`` must be ``fmt``.

    Raises:
        InputError: missing, unreadable (truncated, not a torch file) or foreign (another ``format``) file.
    """
    if not path.is_file():
        raise InputError(f"is a folder, not a {what}" if path.is_dir() else f"{what} not found", path=path)
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises many types for truncated or foreign files
        raise InputError(f"unreadable {what} ({type(err).__name__})", path=path) from err
    if not isinstance(data, dict) or data.get("format") != fmt:
        found = data.get("format") if isinstance(data, dict) else type(data).__name__
        raise InputError(f"not a spikenerf reconstructor {what} (format {found!r}, expected {fmt!r})", path)
    return data


def shipped_weights() -> Path:
    """Path of the weights file shipped in the package."""
    return Path(str(resources.files("spikenerf.recon") / "weights" / SHIPPED))


def load_weights(path: str | Path | None = None, mode: str | None = None) -> tuple[ReconNet, dict[str, Any]]:
    """Load a weights file (default: the shipped one) with ``weights_only=True``, checked for compatibility.

    Args:
        path: the file; None = :func:`shipped_weights`. mode: gray | rgb | bayer to check, or None.
    Returns:
        the network in eval mode (float32, CPU) and the file's metadata (everything but ``state``).
    Raises:
        InputError: missing, corrupt or foreign file, another architecture or format version, a colour mode
            the weights were not trained for, or a weight that is not finite.
    """
    path = shipped_weights() if path is None else Path(path)
    data = read_torch(path, "weights file", FORMAT)
    if data.get("arch") != ARCH:
        raise InputError(
            f"weights are for architecture {data.get('arch')!r}; this version runs {ARCH!r}", path
        )
    modes = data.get("modes", [])
    if not (isinstance(modes, list) and all(isinstance(m, str) for m in modes)):
        raise InputError(f"weights file has a malformed 'modes' entry ({type(modes).__name__})", path=path)
    if mode is not None and mode not in modes:
        raise InputError(f"weights were trained for colour modes {', '.join(modes)}, not {mode!r}", path=path)
    try:
        net = ReconNet(NetConfig(**data["hparams"]))
        net.load_state_dict({k: v.float() for k, v in data["state"].items()})
    except InputError as err:  # a bad hparams value (NetConfig.check): the file's, not a parameter's
        raise InputError(f"weights file hparams: {err.message}", path=path) from None
    except (KeyError, TypeError, RuntimeError, AttributeError, ValueError) as err:  # wrong inner types too
        raise InputError(
            f"weights do not fit architecture {ARCH!r} ({type(err).__name__})", path=path
        ) from err
    bad = [name for name, value in net.state_dict().items() if not torch.isfinite(value).all()]
    if bad:
        raise InputError(f"weights are not finite (NaN or inf in {bad[0]}): a diverged training", path=path)
    net.eval()
    return net, {k: v for k, v in data.items() if k != "state"}
