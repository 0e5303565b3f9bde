"""``spikenerf reconstruct``: TFP/TFI/TFSTP/learned images from a ``.dat`` stream: PNG (sRGB), NPY (linear), a
folder of PNGs, or an mp4 preview (H.264, sRGB, streamed block by block into ffmpeg).

``--encoding`` overrides the value encoding: ``linear`` PNGs hold ``round(255 · Î)`` with no gamma, as SpikeCV
and spikezoo write their reconstructions; ``srgb`` NPYs hold the display values in [0, 1].

Only the frames a result depends on are read (memory-mapped): the requested range plus the TFP window margin;
TFI widens its margin until every pixel's surrounding intervals are known, TFSTP reads from frame 0 (see
``reconstruct_frames``).
``--stride K`` keeps every K-th frame of the range and reconstructs only those (see :func:`blocks`).
"""

from __future__ import annotations

import glob
from collections.abc import Iterator
from pathlib import Path

import click
import numpy as np

from spikenerf.camera.modes import COLORS, LAYOUTS
from spikenerf.camera.reconstruct import DEFAULT_WINDOW, WINDOWLESS
from spikenerf.cli.types import COUNT, OutPath, frame_size_options
from spikenerf.core.atomic import atomic_path, clean_stale_temps, write_bytes_atomic
from spikenerf.core.errors import InputError, parse_range
from spikenerf.core.lock import output_lock
from spikenerf.data.reconstruction import RECONS

#: frames a block of TFP/learned output spans (bounds memory; one progress-bar step)
BLOCK_FRAMES = 128
#: the mp4's frame rate where --fps-video is not given (render's default too)
DEFAULT_FPS_VIDEO = 30.0
#: TFI's memory, which holds its whole range at once: bytes a pixel of each frame read (the unpacked spikes)
#: and of each frame kept (its float32 result and the int32 scan state it overwrites)
TFI_READ_BYTES, TFI_FRAME_BYTES = 1.0, 4.0
#: TFSTP's bytes a pixel of each frame kept: its two float32 states (one becomes the result) and int32 prev
TFSTP_FRAME_BYTES = 12.0


#: value encodings of the outputs; the default is per file kind (.png → srgb, .npy → linear)
ENCODINGS = ("linear", "srgb")


def encode(image: np.ndarray, encoding: str) -> np.ndarray:
    """Linear intensity (...) → float32: unchanged (``linear``) or sRGB display values [0, 1] (``srgb``)."""
    if encoding == "linear":
        return image.astype(np.float32, copy=False)
    from spikenerf.core.color import srgb_encode

    return srgb_encode(image.astype(np.float64)).astype(np.float32)


def to_png_bytes(image: np.ndarray, encoding: str = "srgb") -> bytes:
    """Linear intensity (H, W) → 8-bit PNG bytes, sRGB-encoded or linear (values clipped to [0, 1])."""
    import imageio.v3 as iio

    from spikenerf.core.color import display_uint8

    encoded = display_uint8(encode(image, encoding))
    return iio.imwrite("<bytes>", encoded, extension=".png")


def video_uint8(image: np.ndarray, encoding: str) -> np.ndarray:
    """Linear intensity (N, H, W) → uint8 (N, H, W) display values of an mp4's frames, as :func:`to_png_bytes`
    quantises them but computed in float32: 8× faster than float64 (a 128-frame block of 250 × 400), one grey
    level off for about one pixel in 10⁵, far below H.264's error."""
    from spikenerf.core.color import display_uint8, srgb_encode

    image = image.astype(np.float32, copy=False)
    return display_uint8(image if encoding == "linear" else srgb_encode(image))


def output_kind(out: Path) -> str:
    """``"png"``, ``"npy"``, ``"mp4"`` or ``"dir"`` from the --out path; other suffixes are an InputError."""
    if out.is_dir() or out.suffix == "":
        return "dir"
    if out.suffix.lower() in (".png", ".npy", ".mp4"):
        return out.suffix.lower()[1:]
    raise InputError(
        f"--out must end in .png, .npy or .mp4, or name a folder; found suffix {out.suffix!r}", path=out
    )


def check_out_dir(out: Path) -> None:
    """A folder output writes only its own frame PNGs, replacing those it wrote there before and no other
    file: ``out`` must be absent, empty, or a frame folder spikenerf wrote (its ``.spikenerf`` marker lists
    its frames); a link is followed."""
    from spikenerf.core.marker import check_output

    check_output(out, "frames", overwrite=True)


def blocks(frames: range, method: str, window: int = DEFAULT_WINDOW) -> Iterator[range]:
    """The output frames ``frames`` (any step: ``--stride``) in blocks, each reconstructed by one call over
    the frames ``block.start`` to ``block[-1]`` of which every ``step``-th is kept: TFI and TFSTP in one
    block (their margin is shared; TFSTP's scan runs from frame 0); TFP and learned in blocks spanning at
    most BLOCK_FRAMES frames, or one frame a block where a call per frame costs less than the frames
    skipped (learned: a step > 1; TFP: a step ≥ its ``window``, about the frames one call reads)."""
    step = frames.step
    if method in WINDOWLESS:
        size = max(1, len(frames))
    elif step == 1 or (method == "tfp" and step < window):
        size = max(1, BLOCK_FRAMES // step)
    else:
        size = 1
    for i in range(0, len(frames), size):
        yield frames[i : i + size]


@click.command(
    help="Reconstruct images from a .dat spike stream (TFP/TFI/TFSTP, or the learned reconstructor): PNG, "
    "NPY, a folder of PNGs, or an mp4 to preview the recording."
)
@click.argument("spikes", type=click.Path(path_type=Path))
@frame_size_options
@click.option("--method", type=click.Choice(RECONS), required=True)
@click.option("--weights", type=click.Path(path_type=Path), help="learned: weights file [default: shipped].")
@click.option(
    "--color",
    type=click.Choice(COLORS),
    default="gray",
    show_default=True,
    help="learned: the stream is gray, one channel of a per-channel RGB recording, or a Bayer RGGB mosaic.",
)
@click.option(
    "--window", type=int,
    help=f"TFP window length in frames, odd [default: {DEFAULT_WINDOW}]; learned: its trained window only.",
)  # fmt: skip
@click.option(
    "--frame", type=int, help="One frame index (negative: from the end, -1 = the last): .npy gets (H, W)."
)
@click.option(
    "--frames", "frame_range",
    help="A frame range A:B (B exclusive; negative: from the end, -5: = the last 5): .npy gets (B-A, H, W). "
    "[default: the whole stream]",
)  # fmt: skip
@click.option(
    "--stride", type=COUNT,
    help="Keep every K-th frame of the range (A, A+K, ...); only those are reconstructed [default: 1].",
)  # fmt: skip
@click.option(
    "--layout", type=click.Choice(LAYOUTS),
    help="Row order of the .dat file [default: config.yaml's layout, else spikecv].",
)  # fmt: skip
@click.option("--raw-width", type=int, help="Stored row width, e.g. 416 for raw 250×400 camera files.")
@click.option("--threshold", type=float, help="The camera threshold φ [default: config.yaml's, else 1].")
@click.option(
    "--encoding",
    type=click.Choice(ENCODINGS),
    help="Output values: linear (SpikeCV/spikezoo PNGs) or srgb [default: linear for .npy, else srgb].",
)
@click.option(
    "--fps-video", type=float,
    help=f"Frame rate of an --out FILE.mp4 in frames a second [default: {DEFAULT_FPS_VIDEO:g}].",
)  # fmt: skip
@click.option(
    "--out", type=OutPath(), required=True,
    help="FILE.png, FILE.npy, FILE.mp4 (a video of the frames: a preview) or a folder.",
)  # fmt: skip
@click.option(
    "--overwrite", is_flag=True,
    help="Replace an existing --out FILE.png, FILE.npy or FILE.mp4 (a frame folder that reconstruct wrote "
    "always holds the last call's frames).",
)  # fmt: skip
def command(
    spikes: Path,
    height: int | None,
    width: int | None,
    method: str,
    weights: Path | None,
    color: str,
    window: int | None,
    frame: int | None,
    frame_range: str | None,
    stride: int | None,
    layout: str | None,
    raw_width: int | None,
    threshold: float | None,
    encoding: str | None,
    fps_video: float | None,
    out: Path,
    overwrite: bool,
) -> None:
    from spikenerf.camera.frame_range import resolve_frames
    from spikenerf.camera.io import count_frames, read_dat
    from spikenerf.camera.reconstruct import reconstruct_frames
    from spikenerf.camera.streams import check_threshold
    from spikenerf.cli.types import dat_recording, given_layout
    from spikenerf.core.progress import bar as progress_bar
    from spikenerf.data.reconstruction import reconstructor

    recording = dat_recording(spikes, height, width, raw_width, refuse=True)  # (it writes what it reads)
    height, width, raw_width = recording.height, recording.width, recording.raw_width
    if threshold is None:  # the recording's φ (a SpikeCV config.yaml beside it), else 1
        threshold = recording.threshold or 1.0

    if method in WINDOWLESS and window is not None:
        raise InputError(
            f"--window applies to --method tfp and learned ({method} uses inter-spike intervals)"
        )
    if method != "learned" and color != "gray":
        raise InputError(f"--color applies to --method learned only ({method} treats every pixel alike)")
    if method != "learned" and weights is not None:
        raise InputError(f"--weights applies to --method learned only ({method} has no network)")
    check_threshold(threshold)  # (TFP, TFI and TFSTP would check φ only when they reconstruct)
    recon = reconstructor(method, window, threshold, weights=weights, color=color)
    if frame is not None and frame_range is not None:
        raise InputError("give either --frame I or --frames A:B, not both")
    if frame is not None and stride is not None:
        raise InputError("--stride applies to a frame range (--frames A:B or the whole stream), not --frame")
    total = count_frames(spikes, height, width, raw_width)
    if total == 0:
        raise InputError("the spike file holds no frames", path=spikes)
    if window is not None and window > total:  # (every window would be clipped to the whole stream)
        raise InputError(f"--window {window} is longer than the {total}-frame stream", path=spikes)
    selection = parse_range(frame_range, "frame_range") if frame_range else frame
    frames = resolve_frames(selection, total, spikes, param="frame" if frame is not None else "frame_range")
    span, frames = frames, frames[:: stride or 1]
    kind = output_kind(out)
    if fps_video is not None and kind != "mp4":
        raise InputError("--fps-video applies to --out FILE.mp4 only")
    if kind == "mp4":
        from spikenerf.core.video import check_fps, ffmpeg_module

        if frame is not None:
            raise InputError(
                "a video needs a frame range: use --frames A:B (or neither: the whole stream); one frame "
                "goes to --out FILE.png",
                path=out,
            )
        ffmpeg_module("reconstruct")  # before any work
        fps_video = DEFAULT_FPS_VIDEO if fps_video is None else fps_video
        check_fps(fps_video, "fps_video")
    if out.exists() and out.resolve() == spikes.resolve():
        raise InputError("is the spike recording being read: choose another --out", path=out)
    encoding = encoding or ("linear" if kind == "npy" else "srgb")
    if kind == "png" and len(frames) != 1:
        raise InputError(
            f"a .png holds one frame but {len(frames)} are selected; use --frame I, or --out a folder",
            path=out,
        )
    if method in WINDOWLESS:  # one block: the whole range is read (a byte a pixel) and the kept frames held
        from spikenerf.core.limits import check_memory

        pixels = float(height) * float(width)
        read_frames, kept = (
            (len(span), TFI_FRAME_BYTES) if method == "tfi" else (span.stop, TFSTP_FRAME_BYTES)
        )
        need = pixels * (read_frames * TFI_READ_BYTES + len(frames) * kept)  # (TFSTP reads from frame 0)
        check_memory(need, "frame_range/stride")
    if kind == "dir":
        check_out_dir(out)
    else:
        from spikenerf.core.marker import check_file_output

        check_file_output(out, overwrite=overwrite)

    def read(a: int, b: int) -> np.ndarray:
        return read_dat(spikes, height, width, slice(a, b), layout, raw_width)

    def reconstruct(block: range) -> np.ndarray:
        """The frames of ``block`` (N, H, W): TFI and TFSTP compute only those (one block spans the range)."""
        if method in WINDOWLESS:
            return reconstruct_frames(read, total, block.start, block[-1] + 1, method, threshold=threshold,
                                      step=block.step)  # fmt: skip
        return recon(read, total, block.start, block[-1] + 1)[:: block.step]

    def images() -> Iterator[tuple[range, np.ndarray]]:
        for block in blocks(frames, method, window or DEFAULT_WINDOW):
            try:
                image = reconstruct(block)
            except InputError as err:  # about the stream (e.g. shorter than the network's window): name it
                if err.path is not None:
                    raise
                raise InputError(err.message, path=spikes, param=err.params) from None
            yield block, image

    bar = progress_bar(
        total=len(frames), unit="frame", desc=f"{method} {spikes.name}", show=len(frames) >= 32 and None
    )
    layout = given_layout(spikes, layout, recording)  # its warning and φ's after the checks: a refusal
    if recording.threshold is not None and threshold != recording.threshold:  # is one line (as info's --fps)
        click.echo(
            f"spikenerf: warning: {spikes}: --threshold {threshold:g} differs from threshold "
            f"{recording.threshold:g} in {recording.path}; using --threshold {threshold:g}",
            err=True,
        )
    with output_lock(out), bar:
        _clean_temps(out, kind)
        if kind == "png":
            (_, image), *_ = images()
            write_bytes_atomic(out, to_png_bytes(image[0], encoding))
        elif kind == "npy" and frame is not None:
            (_, image), *_ = images()
            with atomic_path(out) as tmp, open(tmp, "wb") as fh:
                np.save(fh, encode(image[0], encoding))
        elif kind == "npy":
            with atomic_path(out) as tmp:
                dest = np.lib.format.open_memmap(tmp, "w+", np.float32, (len(frames), height, width))
                done = 0
                for block, image in images():
                    dest[done : done + len(block)] = encode(image, encoding)
                    done += len(block)
                    bar.update(len(block))
                dest.flush()
                del dest
        elif kind == "mp4":
            from spikenerf.core.video import write_video

            def video_frames() -> Iterator[np.ndarray]:  # uint8 (H, W), one block in memory at a time
                for block, image in images():
                    for i in range(0, len(image), BLOCK_FRAMES):  # (a TFI block can be the whole range)
                        yield from video_uint8(image[i : i + BLOCK_FRAMES], encoding)
                    bar.update(len(block))

            write_video(out, video_frames(), fps_video)
        else:
            from spikenerf.core.marker import listed, mark

            previous, names = set(listed(out)), [f"{i:05d}.png" for i in frames]
            for block, image in images():
                mark(out, "frames", [*previous | set(names)])  # once frames are made: nothing before
                for index, frame_image in zip(block, image, strict=True):
                    write_bytes_atomic(out / f"{index:05d}.png", to_png_bytes(frame_image, encoding))
                    bar.update(1)
            gone = previous - set(names)
            for name in gone:  # frames this command wrote before: replaced, no others
                (out / name).unlink(missing_ok=True)
            mark(out, "frames", names)
            if gone:
                count = f"{len(gone)} frame{'s' if len(gone) != 1 else ''}"
                click.echo(f"removed {count} of an earlier reconstruct into {out} (a frame folder holds one "
                           "call's frames)")  # fmt: skip
    made = f"{len(frames)} frame{'s' if len(frames) != 1 else ''}"
    if kind == "mp4":  # how long it plays, and how long the frames it shows lasted in the recording
        rate = recording.fps or 40000.0
        which = f"1 in {frames.step} of " if frames.step > 1 else ""
        lasted, plays = len(span) / rate * 1e3, len(frames) / fps_video
        click.echo(
            f"wrote {out} ({made}, {method}: {which}frames {span.start}:{span.stop}, {lasted:.4g} ms at "
            f"{rate:g} Hz; it plays {plays:.4g} s at {fps_video:g} fps)"
        )
    else:
        click.echo(f"wrote {out} ({made}, {method})")


def _clean_temps(out: Path, kind: str) -> None:
    """Remove what a killed reconstruct into ``out`` left: the temporaries in a frame folder, or those of
    the file ``out`` beside it (called holding ``out``'s writer lock)."""
    if kind == "dir":
        clean_stale_temps(out)
    elif out.parent.is_dir():
        for tmp in out.parent.glob(f".{glob.escape(out.name)}.*.tmp"):
            tmp.unlink(missing_ok=True)
