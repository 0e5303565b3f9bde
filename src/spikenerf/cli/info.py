"""``spikenerf info PATH``: summarise a ``.dat`` spike file, or a dataset, run or render folder."""

from __future__ import annotations

import math
import struct
from pathlib import Path

import click

from spikenerf.camera.modes import LAYOUTS
from spikenerf.cli.types import dat_recording, frame_size_options, given_layout
from spikenerf.core.errors import InputError


def describe_dat(
    path: Path, height: int, width: int, layout: str, raw_width: int | None, fps: float
) -> list[str]:
    """The summary lines of a ``.dat`` file: frames, duration, mean rate and per-pixel rate percentiles."""
    from spikenerf.camera.dat_codec import frame_bytes
    from spikenerf.camera.io import count_frames
    from spikenerf.camera.stats import dat_rate_summary

    frames = count_frames(path, height, width, raw_width)
    stored = "" if raw_width is None else f" (stored rows {raw_width} wide, {raw_width - width} stripped)"
    lines = [
        f"file: {path}",
        f"frame: {width}×{height} pixels (width × height){stored}, {frame_bytes(height, width, raw_width)} "
        "bytes, "
        f"layout {layout}",
        f"frames: {frames}",
        f"duration: {frames / fps * 1e3:.4g} ms at {fps:g} Hz",
    ]
    if frames == 0:
        raise InputError("the spike file is empty (0 bytes): it holds no frames", path=path)
    summary = dat_rate_summary(path, height, width, layout, raw_width)
    rate = summary["mean_rate"]
    lines.append(
        f"mean spike rate: {rate:.4g} spikes/pixel/step ({rate * fps:.4g} Hz), {summary['spikes']} spikes"
    )
    pct = ", ".join(f"p{q} {v:.4g}" for q, v in summary["rate_percentiles"].items())
    lines.append(f"per-pixel firing rate (spikes/step): {pct}")
    lines.append(
        f"silent pixels: {summary['silent_fraction'] * 100:.3g}%   saturated (a spike every step): "
        f"{summary['saturated_fraction'] * 100:.3g}%"
    )
    return lines


#: folders spikenerf writes that ``info`` does not summarise → what to read instead
OTHER_KINDS = {
    "benchmark": "a benchmark folder: its tables are table1.md, table2.md and report.html (`spikenerf "
    "report` writes the report again); `spikenerf info` on a run folder (runs/SCENE/COLOR/VARIANT) for "
    "one cell",
    "scores": "a recon-eval folder: its scores are scores.json (per method and per step) and scores.csv",
}


def describe_frames(folder: Path) -> str:
    """The summary line of a ``reconstruct`` frame folder: how many frames, which, and their size."""
    frames = sorted((p for p in folder.glob("[0-9]*.png") if p.stem.isdigit()), key=lambda p: int(p.stem))
    if not frames:
        return f"reconstruct frame folder: no frames yet ({folder})"
    import imageio.v3 as iio

    try:
        shape = iio.improps(frames[0]).shape
    except (OSError, ValueError, SyntaxError, struct.error) as err:  # (Pillow: SyntaxError, struct.error)
        raise InputError(f"unreadable PNG ({type(err).__name__})", path=frames[0]) from err
    return (
        f"reconstruct frame folder: {len(frames)} frame{'s' if len(frames) > 1 else ''} "
        f"({frames[0].stem} to {frames[-1].stem}), {shape[1]}×{shape[0]}"
        + (" RGB" if len(shape) == 3 else " gray")
    )


def describe_render(folder: Path) -> list[str]:
    """The summary lines of a ``render`` output folder: its ``render.json`` (what was rendered, from which
    run) and each novel-view spike stream it holds (:func:`describe_dat`); an unfinished render says so."""
    from spikenerf.eval.render_record import RECORD, read_render_record

    info = read_render_record(folder)  # (a malformed one is an InputError naming it)
    if info is None:
        return [f"render folder: {folder}", "unfinished (no render.json): run its command again to resume"]
    (width, height), files = info["size"], info.get("files") or {}
    done, planned = info.get("iteration"), info.get("run_iterations")
    of = (
        ""
        if done is None
        else f" at iteration {done}" + (f" of {planned}" if planned not in (None, done) else "")
    )
    if done is not None and (now := _run_iteration(info.get("run"))) is not None and now > done:
        of += f" [the run is now at iteration {now}: render again]"  # (as info marks an older metrics.json)
    views = info.get("views")
    fmt = {"camera_path": " (a nerfstudio camera path)"}.get(str(info.get("trajectory_kind")), "")
    lines = [
        f"render folder: {folder}",
        f"run: {info.get('run')}{of}",
        f"trajectory: {info.get('trajectory')}{fmt}, {views} view{'' if views == 1 else 's'} of "
        f"{width}×{height}, video {files.get('video')}",
    ]
    streams = [name for name in files.get("spikes") or [] if str(name).endswith(".dat")]
    if streams:
        along = {"orbit": "", "spiral": "", "interpolate": "", "test": " (one step per held-out view)"}.get(
            str(info.get("trajectory")), " (one step per pose of the file)"
        )
        steps = info.get("spike_steps")
        lines.append(
            f"novel spike stream: {steps} step{'' if steps == 1 else 's'}{along}, φ {info.get('threshold')}"
        )
    for name in streams:
        try:
            config = dat_recording(folder / name, height, width, width)  # plain frames: no raw-layout guess
            fps = config.fps or 40000.0
            lines += ["", *describe_dat(folder / name, height, width, "spikecv", None, fps)]
        except InputError as err:  # the size came from the record: say so
            raise InputError(f"{err.message} (size {width}×{height} from {RECORD})", path=err.path) from None
    return lines


def _run_iteration(run: str | None) -> int | None:
    """The iteration of the checkpoint in the run folder ``run`` (a render's record names it); None where it
    is gone or unreadable (``info`` of the render still describes it; ``info RUN`` names the problem)."""
    from spikenerf.core.marker import folder_kind

    if not run or folder_kind(run) != "run":
        return None
    from spikenerf.train.run import run_iteration

    try:
        return run_iteration(run)
    except InputError:  # (the checkpoint's schema check makes ``iteration`` an int)
        return None


@click.command(
    help="Summarise a dataset, run or render folder, a recon-data pair folder, a recon-train folder, a "
    "reconstruct frame folder, or a .dat spike file (needs --height/--width, or a SpikeCV config.yaml beside "
    "it)."
)
@click.argument("path", type=click.Path(path_type=Path))
@frame_size_options
@click.option(
    "--layout",
    type=click.Choice(LAYOUTS),
    help="Row order of a .dat file [default: config.yaml's layout, else spikecv].",
)
@click.option("--raw-width", type=int, help="Stored row width, e.g. 416 for raw 250×400 camera files.")
@click.option(
    "--fps",
    type=float,
    help="Readout rate in Hz [default: fps of the config.yaml beside the file, else 40000].",
)
def command(
    path: Path,
    height: int | None,
    width: int | None,
    layout: str | None,
    raw_width: int | None,
    fps: float | None,
) -> None:
    if not path.exists():
        partial = path.with_name(path.name + ".partial")
        if path.name and partial.is_dir():  # a simulate or import that has not finished
            raise InputError(
                f"not written yet: {partial} is its unfinished work folder (run the same simulate or import "
                "command again to finish it)",
                path=path,
            )
        raise InputError("no such file or folder", path=path)
    from spikenerf.core.marker import MARKER, folder_kind, marker_problem

    if path.is_dir() and (problem := marker_problem(path)) is not None:  # (else known by its files, silently)
        raise InputError(
            f"a damaged folder marker: {problem} (spikenerf's record of the folders it wrote; delete it, and "
            "the folder is known by its files, as one written before markers were)",
            path=path / MARKER,
        )
    if path.is_dir():
        dat_options = {"--height": height, "--width": width, "--layout": layout, "--raw-width": raw_width}
        given = [flag for flag, value in {**dat_options, "--fps": fps}.items() if value is not None]
        if given:
            raise InputError(
                f"{', '.join(given)}: for a .dat file only (a folder's own files give its size and rate)",
                path=path,
            )

    if path.is_dir() and folder_kind(path) == "run":  # a run's missing file is named as such
        from spikenerf.eval.describe import metrics_lines
        from spikenerf.train.run import describe_run

        click.echo(describe_run(path, metrics_lines))
        return
    if path.is_dir() and folder_kind(path) == "render":
        click.echo("\n".join(describe_render(path)))
        return
    if path.is_dir() and (kind := folder_kind(path)) in ("pairs", "recon", "frames"):
        from spikenerf.recon.describe import describe_pairs, describe_recon

        click.echo({"pairs": describe_pairs, "recon": describe_recon, "frames": describe_frames}[kind](path))
        return
    if path.is_dir() and (kind := folder_kind(path)) in OTHER_KINDS:
        if kind == "scores":  # (an interrupted or mismatched pair: say so, not where the scores are)
            from spikenerf.eval.recon_scores import pair_problem

            if (problem := pair_problem(path)) not in ("", "absent"):
                raise InputError(f"a recon-eval folder with unfinished scores: {problem}; run it again", path)
        raise InputError(OTHER_KINDS[kind], path=path)
    if path.is_dir():
        from spikenerf.data.summary import describe

        click.echo(describe(path))
        return
    config = dat_recording(path, height, width, raw_width)
    height, width, raw_width = config.height, config.width, config.raw_width
    read_as = given_layout(path, layout, config, warn=False)  # (its warning once the file is read)
    given_fps, fps = fps, fps if fps is not None else config.fps or 40000.0
    if not 0 < fps < math.inf:
        raise InputError(f"--fps must be a finite number > 0, found {fps}")
    lines = describe_dat(path, height, width, read_as, raw_width, fps)  # (its refusals come alone)
    given_layout(path, layout, config)
    if given_fps is not None and config.fps is not None and given_fps != config.fps:  # as --width/--height
        click.echo(f"spikenerf: warning: {path}: --fps {fps:g} differs from fps {config.fps:g} in "
                   f"{config.path}; using --fps {fps:g}", err=True)  # fmt: skip
    click.echo("\n".join(lines))
