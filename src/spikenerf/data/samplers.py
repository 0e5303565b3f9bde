"""Seeded, resumable samplers: random rays over (image, pixel) and contiguous step windows for the spike loss.

Each sampler owns a ``torch.Generator`` and exposes ``state_dict``/``load_state_dict`` holding only tensors
and ints, so a checkpoint loaded with ``torch.load(..., weights_only=True)`` resumes the exact same stream.
"""

from __future__ import annotations

import torch
from torch import Tensor

from spikenerf.core.errors import InputError, check_choice
from spikenerf.data.choices import WINDOW_ORDERS
from spikenerf.data.choices import WindowOrder as WindowOrder  # (defined there, without torch)


def _generator(seed: int) -> torch.Generator:
    gen = torch.Generator()
    gen.manual_seed(int(seed))
    return gen


class SeededSampler:
    """A sampler whose draws come from its own ``generator`` (seeded by ``seed``): its state is the
    generator's, saved and restored with :meth:`state_dict` / :meth:`load_state_dict`."""

    def __init__(self, seed: int) -> None:
        self.generator = _generator(seed)

    def state_dict(self) -> dict[str, Tensor]:
        """``{"generator": state}``, the generator's state, a (K,) uint8 tensor."""
        return {"generator": self.generator.get_state()}

    def load_state_dict(self, state: dict[str, Tensor]) -> None:
        """Restore what :meth:`state_dict` returned (the generator's (K,) uint8 state)."""
        self.generator.set_state(state["generator"])


class RaySampler(SeededSampler):
    """Uniform random rays over all (image, pixel) pairs of K images of H × W pixels.

    Args:
        num_images: K. height, width: image size in pixels. seed: generator seed.
        images: (K',) int64 the image indices to draw from (None: all K; the held-out steps, data/holdout.py).
    """

    def __init__(
        self, num_images: int, height: int, width: int, seed: int = 0, images: Tensor | None = None
    ) -> None:
        if num_images < 1 or height < 1 or width < 1 or (images is not None and len(images) < 1):
            raise InputError(f"no training rays: {num_images} images of {width}×{height} pixels")
        super().__init__(seed)
        self.num_images, self.height, self.width = num_images, height, width
        self.images = images

    def sample(self, batch: int) -> tuple[Tensor, Tensor]:
        """``batch`` rays: image index (B,) int64 and pixels (B, 2) int64 ``(x, y)``."""
        hw = self.height * self.width
        count = self.num_images if self.images is None else len(self.images)
        flat = torch.randint(0, count * hw, (batch,), generator=self.generator)
        pix, index = flat % hw, flat // hw
        index = index if self.images is None else self.images[index]
        return index, torch.stack([pix % self.width, pix // self.width], dim=-1)


class WindowSampler(SeededSampler):
    """Contiguous windows ``[start, start + L)`` of a T-step stream, each with P random pixels.

    ``order="sequential"`` walks the stream deterministically (start advances by ``stride``; a start past the
    last window position, T − L, becomes T − L once, so that the stream's last steps are drawn too, and then
    it wraps to 0), as the paper selects consecutive poses; ``order="random"`` draws the start uniformly.
    Windows always lie inside the stream. ``starts`` restricts the first steps drawn (the held-out bands,
    data/holdout.py): the random order draws among them, the sequential order takes the next one at or
    after its position. The checkpointed state is the same either way.

    Args:
        num_steps: T. height, width: image size. length: L ≤ T. seed: generator seed.
        order: sequential | random. stride: start advance of the sequential order (default L).
        starts: (S,) int64 sorted allowed first steps (None: all ``T − L + 1``).
    """

    def __init__(
        self,
        num_steps: int,
        height: int,
        width: int,
        length: int,
        seed: int = 0,
        order: str = "sequential",
        stride: int | None = None,
        starts: Tensor | None = None,
    ) -> None:
        if not 1 <= length <= num_steps:
            raise InputError(f"spike window length must be between 1 and the {num_steps} steps, got {length}")
        check_choice(order, WINDOW_ORDERS, "order", "window order")
        super().__init__(seed)
        self.num_steps, self.height, self.width, self.length = num_steps, height, width, length
        self.order, self.stride = order, max(1, stride or length)
        if starts is not None and len(starts) < 1:
            raise InputError(f"no {length}-step window to train on among the {num_steps} steps")
        self.starts = starts
        self.next_start = 0

    @property
    def num_starts(self) -> int:
        """How many window positions fit in the stream, ``T − L + 1``."""
        return self.num_steps - self.length + 1

    def sample(self, pixels: int) -> tuple[int, Tensor]:
        """The next window: its first step and pixels (P, 2) int64 ``(x, y)``."""
        starts = self.starts
        if self.order == "random":
            count = self.num_starts if starts is None else len(starts)
            start = int(torch.randint(0, count, (1,), generator=self.generator))
            start = start if starts is None else int(starts[start])
        else:
            start = self._next_sequential()
            self.next_start = start + self.stride
        flat = torch.randint(0, self.height * self.width, (pixels,), generator=self.generator)
        return start, torch.stack([flat % self.width, flat // self.width], dim=-1)

    def _next_sequential(self) -> int:
        """The sequential order's next first step: the first allowed one at or after ``next_start``; past the
        last allowed one, that last one if the previous window started before it (so the stream's tail is
        drawn), else the first (a new pass)."""
        first, last = (0, self.num_starts - 1) if self.starts is None else map(int, self.starts[[0, -1]])
        if self.next_start <= last:
            if self.starts is None:
                return self.next_start
            return int(self.starts[int(torch.searchsorted(self.starts, self.next_start))])
        return last if self.next_start - self.stride < last else first

    def state_dict(self) -> dict[str, Tensor | int]:
        """The generator's (K,) uint8 state and ``next_start``, the sequential order's next window."""
        return {"generator": self.generator.get_state(), "next_start": self.next_start}

    def load_state_dict(self, state: dict[str, Tensor | int]) -> None:
        """Restore what :meth:`state_dict` returned (the generator's (K,) uint8 state, ``next_start``)."""
        self.generator.set_state(state["generator"])  # type: ignore[arg-type]
        self.next_start = int(state["next_start"])
