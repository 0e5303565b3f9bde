"""Spike camera simulator throughput: pixel-steps per second and achieved memory bandwidth.

Run: ``.venv/bin/python -m benchmarks.suites.bench_simulator``. The workload is 1000 steps of 250×400 gray
intensity (float32), cycling through 64 distinct frames (25.6 MB, larger than L2) so each step streams a fresh
frame.

References, measured in the same process:
- ``naive numpy``: a straightforward vectorised loop written below, the textbook formula with new arrays every
  step (``A = A + I; s = A >= φ; A = A - s·φ`` in float64, spikes gathered in a list and stacked);
- ``np.add``: a bare ``np.add(A, I, out=A)`` over the same arrays, the memory-traffic floor. Bytes counted per
  pixel-step: simulator 13 (read I 4, read+write A 8, write spike 1), ``np.add`` 12.
"""

from __future__ import annotations

import os
import sys

import numpy as np
import torch

from benchmarks._table import Row, best_seconds, format_table
from spikenerf.camera.model import CameraConfig
from spikenerf.camera.simulation import simulate, simulate_iter

HEIGHT, WIDTH, STEPS, DISTINCT = 250, 400, 1000, 64
SIM_BYTES, ADD_BYTES = 13, 12


def _frames() -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    return [rng.random((HEIGHT, WIDTH), dtype=np.float32) * 0.6 for _ in range(DISTINCT)]


def _stream(frames: list[np.ndarray]):
    return [frames[t % DISTINCT] for t in range(STEPS)]


def naive_reference(frames: list[np.ndarray], threshold: float = 1.0) -> np.ndarray:
    """The allocation-heavy textbook loop: float64, fresh arrays each step, spikes stacked at the end."""
    acc = np.random.default_rng(0).random((HEIGHT, WIDTH)) * threshold
    out = []
    for frame in frames:
        acc = acc + frame
        spikes = acc >= threshold
        acc = acc - spikes * threshold
        out.append(spikes)
    return np.stack(out)


def _np_add(frames: list[np.ndarray]) -> None:
    acc = np.zeros((HEIGHT, WIDTH), np.float32)
    for frame in frames:
        np.add(acc, frame, out=acc)


def _consume(it) -> None:
    for _ in it:
        pass


def measure(repeats: int = 5) -> list[Row]:
    """Time the simulator (numpy, torch CPU; ideal and realistic) against the references; one Row each."""
    frames = _stream(_frames())
    pixel_steps = HEIGHT * WIDTH * STEPS
    mps = "Mpixel-steps/s"
    naive = pixel_steps / best_seconds(lambda: naive_reference(frames), repeats) / 1e6
    ideal = CameraConfig()
    ours = pixel_steps / best_seconds(lambda: simulate(frames, HEIGHT, WIDTH, ideal), repeats) / 1e6
    torch_frames = [torch.from_numpy(f) for f in frames]
    ours_torch = (
        pixel_steps / best_seconds(lambda: simulate(torch_frames, HEIGHT, WIDTH, ideal, "cpu"), repeats) / 1e6
    )
    stream = pixel_steps / best_seconds(
        lambda: _consume(simulate_iter(frames, HEIGHT, WIDTH, ideal)), repeats
    )
    add = pixel_steps / best_seconds(lambda: _np_add(frames), repeats)
    real_cfg = CameraConfig(noise="realistic")
    realistic = pixel_steps / best_seconds(lambda: simulate(frames, HEIGHT, WIDTH, real_cfg), repeats) / 1e6
    rows = [
        Row("ideal gray, numpy, simulate()", ours, naive, mps, "naive numpy"),
        Row(f"ideal gray, torch CPU ({torch.get_num_threads()} threads), simulate()", ours_torch, naive, mps,
            "naive numpy"),
        Row("ideal gray, numpy, simulate_iter() memory traffic", stream * SIM_BYTES / 1e9,
            add * ADD_BYTES / 1e9, "GB/s", "np.add same arrays"),
        Row("realistic gray, numpy, simulate()", realistic, ours, mps, "ours, ideal"),
    ]  # fmt: skip
    if torch.cuda.is_available():
        rows += _cuda_rows(frames, naive, repeats)
    return rows


def _cuda_rows(frames: list[np.ndarray], naive: float, repeats: int) -> list[Row]:
    """CUDA: frames already on the GPU; simulate() includes copying the spikes back to host memory."""
    pixel_steps = HEIGHT * WIDTH * STEPS
    on_gpu = [torch.from_numpy(f).cuda() for f in frames[:DISTINCT]]
    gpu_frames = [on_gpu[t % DISTINCT] for t in range(STEPS)]

    def timed(fn) -> float:
        def run() -> None:
            fn()
            torch.cuda.synchronize()

        run()
        return pixel_steps / best_seconds(run, repeats) / 1e6

    name = torch.cuda.get_device_name()
    rows = []
    for noise in ("ideal", "realistic"):
        config = CameraConfig(noise=noise)
        rows.append(Row(f"{noise} gray, torch CUDA ({name}), simulate()",
                        timed(lambda c=config: simulate(gpu_frames, HEIGHT, WIDTH, c, "cuda")), naive,
                        "Mpixel-steps/s", "naive numpy"))  # fmt: skip
    return rows


def main() -> None:
    print(f"spike camera simulator, {STEPS} steps at {HEIGHT}×{WIDTH}, float32; python "
          f"{sys.version.split()[0]}, numpy {np.__version__}, torch {torch.__version__}, "
          f"{os.cpu_count()} CPUs")  # fmt: skip
    print(format_table(measure()))


if __name__ == "__main__":
    main()
