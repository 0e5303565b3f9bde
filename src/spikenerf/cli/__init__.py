"""The ``spikenerf`` command: a click group whose subcommands load lazily (``spikenerf --help`` stays fast).

Each subcommand lives in ``spikenerf.cli.<name>`` as a click command named ``command``. Any
:class:`~spikenerf.core.errors.InputError` becomes one line on stderr and exit code 2.
"""

from __future__ import annotations

import contextlib
import gc
import importlib
import os
import signal
import sys
import threading
import traceback
import warnings
from collections.abc import Iterator
from typing import Any

import click

from spikenerf import __version__
from spikenerf.core.errors import InputError, one_line
from spikenerf.core.progress import close_bars

#: subcommand -> (module, one-line help)
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "simulate": ("spikenerf.cli.simulate", "Render a scene along a fast path and simulate a spike camera."),
    "info": ("spikenerf.cli.info", "Summarise a dataset, run or other output folder, or a .dat spike file."),
    "reconstruct": (
        "spikenerf.cli.reconstruct",
        "Reconstruct images from a .dat spike stream (TFP/TFI/TFSTP/learned).",
    ),
    "recon-eval": (
        "spikenerf.cli.recon_eval",
        "Score TFP/TFI/TFSTP/learned reconstructions against a dataset's sharp GT frames.",
    ),
    "recon-data": ("spikenerf.cli.recon_data", "Write training pairs for the learned reconstructor."),
    "recon-train": ("spikenerf.cli.recon_train", "Train the learned spike-to-image reconstructor."),
    "import": ("spikenerf.cli.import_", "Import a raw .dat recording (poses: COLMAP, a file or an orbit)."),
    "train": ("spikenerf.cli.train", "Train a radiance field on a spike dataset."),
    "render": ("spikenerf.cli.render", "Render images, depth, video and novel spike streams from a run."),
    "export": ("spikenerf.cli.export", "Export a run's geometry as a point cloud or mesh (PLY)."),
    "eval": ("spikenerf.cli.evaluate", "Evaluate a run on held-out views (PSNR, SSIM, LPIPS)."),
    "benchmark": ("spikenerf.cli.benchmark", "Reproduce the paper's Table I and Table II."),
    "report": ("spikenerf.cli.report", "Rebuild a finished benchmark's HTML report (other calls merged in)."),
    "demo": ("spikenerf.cli.demo", "Run the whole pipeline on the embedded default scene."),
}


class LazyGroup(click.Group):
    """A group that imports a subcommand's module only when that subcommand runs."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return list(SUBCOMMANDS)

    #: the subcommand that ran last (its flags name the parameters of a lower layer's InputError)
    invoked: str | None = None

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name not in SUBCOMMANDS:
            return None
        command: click.Command = importlib.import_module(SUBCOMMANDS[cmd_name][0]).command
        command.name = cmd_name
        return command

    def resolve_command(self, ctx: click.Context, args: list[str]) -> tuple:
        name, command, rest = super().resolve_command(ctx, args)
        LazyGroup.invoked = name
        return name, command, rest

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        with formatter.section("Commands"):
            formatter.write_dl([(name, help_) for name, (_, help_) in SUBCOMMANDS.items()])


#: options of the group itself: given after a command they get a hint to move them
GLOBAL_OPTIONS = {"--threads": "--threads 1", "--no-limits": "--no-limits", "--quiet": "--quiet"}


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="spikenerf")
@click.option(
    "--threads",
    type=click.IntRange(min=1),
    help="CPU threads per process (sets OMP_NUM_THREADS, inherited by the runs that benchmark and demo "
    "start) [default: torch's choice]. On a busy 2-core machine, 1 is several times faster.",
)
@click.option(
    "--no-limits",
    is_flag=True,
    help="Skip the memory and disk estimates that refuse oversized jobs before they start "
    "(inherited by the runs that benchmark and demo start).",
)
@click.option(
    "--quiet",
    is_flag=True,
    help="No progress bars, in this command and in the runs it starts on this machine (benchmark, demo; "
    "not those of a Ray cluster); each command's --quiet/--no-progress hides its own.",
)
def cli(threads: int | None, no_limits: bool, quiet: bool) -> None:
    """spikenerf: spike cameras, from simulation to Spike-NeRF novel views and novel spike streams."""
    if threads is not None:
        set_cpu_threads(threads)
    if no_limits:
        from spikenerf.core.limits import NO_LIMITS_ENV

        os.environ[NO_LIMITS_ENV] = "1"
    if quiet:
        from spikenerf.core.progress import QUIET_ENV

        before = os.environ.get(QUIET_ENV)
        os.environ[QUIET_ENV] = "1"  # (put back when the command ends: in-process callers keep theirs)
        click.get_current_context().call_on_close(
            lambda: os.environ.pop(QUIET_ENV) if before is None else os.environ.update({QUIET_ENV: before})
        )


#: torch's CPU allocator backs each tensor of 2 MB or more with transparent huge pages where this is "1"
#: (``madvise``; read once, at torch's first allocation). A training step allocates and frees hundreds of MB
#: of large tensors (the decoder's rows, their gradients): with 4 KB pages each fresh allocation faulted in
#: page by page (36–57 k page faults a spike-integral step at 100×100, ~3 k with huge pages)
HUGE_PAGES_ENV = "THP_MEM_ALLOC_ENABLE"


def use_huge_pages() -> None:
    """Huge pages for large CPU tensors in this process and the runs it starts (:data:`HUGE_PAGES_ENV`),
    unless the variable is set already (``THP_MEM_ALLOC_ENABLE=0`` keeps 4 KB pages). Only before torch is
    imported: an in-process caller's environment stays as it was. Values are unchanged, only where memory
    comes from; where the system has transparent huge pages off the advice is ignored."""
    if "torch" not in sys.modules:
        os.environ.setdefault(HUGE_PAGES_ENV, "1")


def set_cpu_threads(threads: int) -> None:
    """Use ``threads`` OpenMP threads here and in child processes (torch reads the variable on import)."""
    os.environ["OMP_NUM_THREADS"] = str(threads)
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(threads)


def command_line() -> str:
    """The running command as the user gave it (group options, arguments and the options given on the
    command line, not defaults), as a shell command: recorded in ``config.yaml``; correct in-process too."""
    import shlex

    ctx, parts = click.get_current_context(), []
    while ctx is not None:
        words = [ctx.info_name if ctx.parent is not None else "spikenerf"]
        for param in ctx.command.params:
            if ctx.get_parameter_source(param.name) != click.core.ParameterSource.COMMANDLINE:
                continue
            value = ctx.params[param.name]
            values = value if getattr(param, "multiple", False) or param.nargs != 1 else [value]
            if isinstance(param, click.Argument):
                words += [str(v) for v in values]
            elif getattr(param, "is_flag", False):
                words.append(param.opts[0] if value else param.secondary_opts[0])
            else:
                words += [w for v in values for w in (param.opts[0], str(v))]
        parts, ctx = words + parts, ctx.parent
    return shlex.join(parts)


#: parameters of lower layers whose flag is not ``--`` + the name with dashes, for every subcommand
#: (a subcommand module adds its own as ``PARAM_FLAGS``)
PARAM_FLAGS = {
    "dataset_root": "--dataset",  # eval's and render's (train.run.open_run)
    "no_limits": "`spikenerf --no-limits ...`",
    "list_scenes": "`spikenerf simulate --list-scenes`",
}


def flag_of(param: str, command: str | None = None) -> str | None:
    """The flag that sets the lower-layer parameter ``param`` in ``command`` (None: not a flag there):
    ``--set param`` where the command's ``--set`` gave it (the module's ``SET_KEYS``), else the module's
    ``PARAM_FLAGS``, else the group's, else ``--field-option KEY`` for ``field_config.KEY`` where the
    command has that option, else the option of that name."""
    module = importlib.import_module(SUBCOMMANDS[command][0]) if command in SUBCOMMANDS else None
    if param in getattr(module, "SET_KEYS", ()):  # given as --set KEY=VALUE
        return f"--set {param}"
    aliases = {**PARAM_FLAGS, **getattr(module, "PARAM_FLAGS", {})}
    if param in aliases:
        return aliases[param]
    params = [*cli.params, *(module.command.params if module is not None else [])]
    names = {option.name for option in params if isinstance(option, click.Option)}
    if param.startswith("field_config.") and "field_options" in names:  # one entry of --field-option
        return f"--field-option {param.split('.', 1)[1]}"
    for option in params:
        if isinstance(option, click.Option) and option.name == param:
            return max(option.opts, key=len)
    return None


def _late_interrupts_end_quietly() -> None:
    """The command is over: its output is flushed, and a Ctrl-C from now on, while Python shuts down (atexit
    handlers, module teardown), ends the process by the signal as by default (the shell shows 130), not with
    a KeyboardInterrupt traceback after the command's last line (or an "Exception ignored" one and exit 0)."""
    for stream in (sys.stdout, sys.stderr):  # (the signal ends the process without flushing its buffers)
        with contextlib.suppress(OSError, ValueError, AttributeError):
            stream.flush()
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_DFL)


def _fail(message: str, code: int = 2) -> None:
    close_bars()  # the error on a line of its own, not after an interrupted bar's text
    click.echo(f"spikenerf: error: {one_line(message)}", err=True)
    sys.exit(code)


class Terminated(BaseException):
    """SIGTERM arrived: unwinds like Ctrl-C (locks released, temporaries removed), then exit 143."""


@contextlib.contextmanager
def _sigterm_unwinds() -> Iterator[None]:
    """While the command runs, SIGTERM raises :class:`Terminated` in this process (a worker process it
    forked dies as by default); the previous handler is restored after."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pid = os.getpid()

    def handler(signum: int, frame: object) -> None:
        if os.getpid() != pid:  # a forked worker: die as the default would
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            os.kill(os.getpid(), signal.SIGTERM)
        raise Terminated

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _unwound_quietly(err: BaseException) -> None:
    """Free what an interruption (``err``, and the exceptions it was raised from) unwound through, now and
    with finalisers' complaints muted: a library object whose ``__init__`` the interrupt cut short may fail
    in its ``__del__`` (imageio's PNG writer, stopped before its first attribute was set), which Python would
    print as a traceback after the one line. The frames still running (``main``'s) are left alone."""
    hook = sys.unraisablehook
    sys.unraisablehook = lambda unraisable: None
    try:
        chain, seen = [err], set()
        while chain:
            exc = chain.pop()
            if exc is None or id(exc) in seen:
                continue
            seen.add(id(exc))
            traceback.clear_frames(exc.__traceback__)
            chain += [exc.__cause__, exc.__context__]
        gc.collect()
    finally:
        sys.unraisablehook = hook


OUT_OF_MEMORY = "out of memory: lower the sizes (frames, width, height, batch, grid size)"


def is_allocation_failure(err: BaseException) -> bool:
    """Whether ``err`` is an allocation that failed: torch's CPU allocator ("can't allocate memory") or its
    CUDA one (``torch.OutOfMemoryError``, "out of memory")."""
    text = str(err)
    named = type(err).__name__ == "OutOfMemoryError"
    return named or "can't allocate memory" in text or "out of memory" in text


#: how an interrupted command continues (docs/reliability.md, "Kill and resume is exact")
RESUME_HINTS = {
    "train": "once it has written a checkpoint, the same command with --resume continues from it",
    **{
        name: "run the same command again to continue where it stopped"
        for name in ("simulate", "import", "render", "benchmark", "demo", "recon-data", "recon-train")
    },
}


def resume_hint(command: str | None) -> str:
    """`` (HINT)`` after "aborted" for a command that resumes (:data:`RESUME_HINTS`), else "" (also in a
    step of a benchmark or demo, whose own line says to run it again)."""
    from spikenerf.pipelines.benchmark.steps import STEP_ENV

    hint = None if os.environ.get(STEP_ENV) == "1" else RESUME_HINTS.get(command or "")
    return f" ({hint})" if hint else ""


def _warning_line(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                  file: Any = None, line: str | None = None) -> None:  # fmt: skip
    """``warnings.showwarning`` of the command line: one ``spikenerf: warning: …`` line (Python's default
    adds the file, the line number and the source line that warned)."""
    print(f"spikenerf: warning: {one_line(str(message))}", file=sys.stderr if file is None else file)


def main(argv: list[str] | None = None) -> None:
    """Console entry point: run the group; bad input (InputError, a usage error, a path the system refuses,
    an allocation that fails) → one line on stderr, exit code 2. Ctrl-C → "aborted", exit 130; SIGTERM →
    "terminated", exit 143, after the same unwinding (locks released). Python warnings print as one line.
    Called without ``argv`` (the process's entry), a Ctrl-C after the command ends the process by the
    signal, without a line (:func:`_late_interrupts_end_quietly`)."""
    shown = warnings.showwarning
    use_huge_pages()
    try:
        warnings.showwarning = _warning_line
        with _sigterm_unwinds():
            cli.main(args=argv, prog_name="spikenerf", standalone_mode=False)
    except Terminated as err:
        _unwound_quietly(err)
        close_bars()
        click.echo("spikenerf: terminated" + resume_hint(LazyGroup.invoked), err=True)
        sys.exit(143)
    except InputError as err:
        _fail(err.shown(lambda param: flag_of(param, LazyGroup.invoked)))
    except click.exceptions.Abort as err:
        _unwound_quietly(err)
        close_bars()
        click.echo("spikenerf: aborted" + resume_hint(LazyGroup.invoked), err=True)
        sys.exit(130)
    except click.UsageError as err:
        if type(err).__name__ == "NoArgsIsHelpError" and err.ctx is not None:  # no command (click 8.2+)
            click.echo(err.ctx.get_help())
            sys.exit(0)
        hint = f" (see `{err.ctx.command_path} --help`)" if err.ctx is not None else ""
        if isinstance(err, click.NoSuchOption) and err.option_name in GLOBAL_OPTIONS:
            example = f"spikenerf {GLOBAL_OPTIONS[err.option_name]} COMMAND ..."
            err = click.UsageError(f"{err.option_name} is a global option: put it first, e.g. {example}")
            hint = ""
        _fail(err.format_message() + hint, err.exit_code)
    except click.ClickException as err:
        _fail(err.format_message(), err.exit_code)
    except (
        OSError
    ) as err:  # a path the system refuses (permissions, a file where a folder must be, full disk)
        where = f"{err.filename}: " if err.filename else ""
        _fail(f"{where}{err.strerror or err}")
    except MemoryError:
        _fail(OUT_OF_MEMORY)
    # torch's allocators raise RuntimeError (CPU) or its OutOfMemoryError subclass (CUDA)
    except RuntimeError as err:
        if not is_allocation_failure(err):
            raise
        _fail(OUT_OF_MEMORY)
    except click.exceptions.Exit as err:
        sys.exit(err.exit_code)
    finally:  # (in-process callers, such as the tests, keep their own)
        warnings.showwarning = shown
        if argv is None:  # the process's own entry (the console script, ``python -m spikenerf``)
            _late_interrupts_end_quietly()
