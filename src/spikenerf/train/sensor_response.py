"""spike-integral's learned per-pixel sensor response (``integral.pixel_gain``, docs/camera.md).

A real spike camera's pixel ``p`` has its own gain ``g_p`` (PRNU) and threshold ``φ_p``: its window count mean
``φ N / L`` reads ``(g_p φ / φ_p)`` times the light. :class:`SensorResponse` learns ``m_p = log(g_p φ / φ_p)``
for every sensor pixel (one per channel in colour) jointly with the scene: each rendered intensity is
multiplied by ``exp(m_p)`` at the pixel the target was counted in and cut at φ (one spike a step;
``SpikeIntegral.sensed``). The camera moves, so each scene point is seen through many pixels and the
pixel-to-pixel pattern is identifiable. Its mean is not (it trades with the scene's brightness), nor, on an
orbit that keeps the object in the middle of the image, its smooth part (a pixel sees much the same part of
the scene from every view, and a smooth map took up the scene's own shading: measured in docs/camera.md). So
the map is used high-passed and centred: ``m`` minus its local mean over :data:`HIGHPASS` × :data:`HIGHPASS`
pixels, then minus its mean (the prior that keeps its mean at 0); a fixed pattern drawn independently per
pixel is nearly all in that part. A small L2 term ``integral.pixel_gain_weight · mean(m²)`` keeps pixels
seldom drawn near 1. The map has its own Adam (:class:`SensorLearner`), is checkpointed and written to
``RUN/sensor_map.npy``. Evaluation renders never use it: the test views are the scene's radiance.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from spikenerf.core.atomic import write_bytes_atomic
from spikenerf.train.pose_refine import PoseLearner

#: the side of the square whose local mean is taken off the map (odd; pixels near the border average the
#: part of it inside the image)
HIGHPASS = 5
#: the learned response factors ``exp(centred m)`` (:meth:`SensorResponse.centred`) in the run folder: float32
#: (H, W) gray, (3, H, W) rgb
SENSOR_MAP = "sensor_map.npy"
#: the map's rate rises linearly from 0 over this fraction of the run (the scene takes shape first) …
WARMUP_FRACTION = 0.1
#: … and decays exponentially to this fraction of ``integral.pixel_gain_lr`` at the run's end
LR_FINAL_RATIO = 0.1


class SensorResponse(torch.nn.Module):
    """Per-pixel log-responses ``m`` (C, H, W), zero at the start (every pixel nominal)."""

    def __init__(self, channels: int, height: int, width: int) -> None:
        super().__init__()
        self.log_response = torch.nn.Parameter(torch.zeros(channels, height, width))

    def centred(self) -> Tensor:
        """The log-responses the counts see (C, H, W): ``m`` less its local mean over :data:`HIGHPASS` ×
        :data:`HIGHPASS` pixels, less the mean of that per channel (0)."""
        m = self.log_response
        local = torch.nn.functional.avg_pool2d(
            m[:, None], HIGHPASS, stride=1, padding=HIGHPASS // 2, count_include_pad=False
        )[:, 0]
        high = m - local
        return high - high.mean(dim=(1, 2), keepdim=True)

    def factor(self, pixels: Tensor) -> Tensor:
        """Response factors ``exp(c_p)`` (B, C) at ``pixels`` (B, 2) int ``(x, y)``, ``c`` the high-passed,
        centred map (:meth:`centred`)."""
        m = self.centred()
        channels, _, width = m.shape
        flat = pixels[:, 1].long() * width + pixels[:, 0].long()  # row-major index (B,)
        return torch.exp(m.reshape(channels, -1)[:, flat.to(m.device)]).transpose(0, 1)

    def penalty(self) -> Tensor:
        """0-d ``mean(c²)`` of the high-passed, centred map ``c`` (:meth:`centred`): the L2 prior towards the
        nominal response."""
        return self.centred().square().mean()

    @torch.no_grad()
    def sensor_map(self) -> np.ndarray:
        """The learned response factors, float32 (H, W) for one channel, else (C, H, W); mean log 0."""
        out = torch.exp(self.centred()).float().cpu().numpy()
        return out[0] if out.shape[0] == 1 else out


@dataclass(frozen=True)
class _Rate:
    """What :func:`spikenerf.train.pose_refine.pose_lr` reads: the rate and its final ratio."""

    lr: float
    lr_final_ratio: float = LR_FINAL_RATIO


class SensorLearner(PoseLearner):
    """The trainer's hooks for :class:`SensorResponse`: its own Adam (rate ``lr``, a linear warm-up over
    :data:`WARMUP_FRACTION` of ``iters``, then an exponential decay to :data:`LR_FINAL_RATIO`), its checkpoint
    state and ``RUN/sensor_map.npy``.

    Args:
        channels, height, width: the map's shape (C, H, W): the sensor's pixels, one map per channel.
        lr: ``integral.pixel_gain_lr``. iters: the run's length. device: where the map lives.
    """

    def __init__(self, channels: int, height: int, width: int, lr: float, iters: int, device: object) -> None:
        self.response = SensorResponse(channels, height, width).to(device)
        super().__init__(self.response, _Rate(lr), iters, int(WARMUP_FRACTION * iters))

    def write(self, out: Path) -> None:
        """Write ``RUN/sensor_map.npy`` (:meth:`SensorResponse.sensor_map`) atomically."""
        buf = io.BytesIO()
        np.save(buf, self.response.sensor_map())
        write_bytes_atomic(Path(out) / SENSOR_MAP, buf.getvalue())


def read_sensor_map(path: str | Path) -> np.ndarray:
    """A ``sensor_map.npy`` (float32 (H, W) or (3, H, W)), read without pickles."""
    return np.load(path, allow_pickle=False)
