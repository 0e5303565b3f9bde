"""The CLI skeleton: help, version, unknown commands and the InputError → exit 2 contract."""

from __future__ import annotations

import subprocess
import sys
import typing
from pathlib import Path

import pytest

from spikenerf.cli import OUT_OF_MEMORY, SUBCOMMANDS, Terminated, main
from spikenerf.core.errors import InputError


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "spikenerf", *args], capture_output=True, text=True)


def test_help_lists_every_design_subcommand() -> None:
    out = _run("--help")
    assert out.returncode == 0
    for name in ["simulate", "info", "reconstruct", "train", "render", "eval", "benchmark", "demo"]:
        assert name in SUBCOMMANDS
        assert name in out.stdout


def test_every_subcommands_help_is_quick_it_imports_no_torch() -> None:
    """``spikenerf CMD --help`` reads its choices and defaults from torch-free modules (``*/choices.py``,
    ``train/settings.py``, ``train/config.py``): importing torch costs 1.5 s, ten times the rest."""
    code = (
        "import sys\n"
        "from click.testing import CliRunner\n"
        "from spikenerf.cli import SUBCOMMANDS, cli\n"
        "for name in SUBCOMMANDS:\n"
        "    result = CliRunner().invoke(cli, [name, '--help'])\n"
        "    assert result.exit_code == 0 and 'Usage:' in result.output, (name, result.output)\n"
        "    if 'torch' in sys.modules:\n"
        "        print(name)\n"
        "        break\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "", f"'spikenerf {out.stdout.strip()} --help' imports torch"


def test_unknown_command_exits_2() -> None:
    assert _run("no-such-command").returncode == 2


def test_no_command_prints_the_help_and_a_global_option_after_a_command_says_where_it_goes(capsys) -> None:
    from helpers import run_cli

    code, out, err = run_cli(capsys)
    assert code == 0 and out.startswith("Usage: spikenerf") and "\nCommands:\n" in out and err == ""
    for option, example in (("--threads", "--threads 1"), ("--no-limits", "--no-limits")):
        code, _, err = run_cli(capsys, "info", option, *(["1"] if option == "--threads" else []), "x")
        assert code == 2 and err.strip() == (
            f"spikenerf: error: {option} is a global option: put it first, e.g. spikenerf {example} "
            "COMMAND ..."
        )


def test_input_error_is_one_line_and_exit_2(monkeypatch, capsys) -> None:
    import click

    import spikenerf.cli as cli_module

    @click.command()
    def boom() -> None:
        raise InputError("expected 3 fields, found 2", path="x/transforms.json")

    monkeypatch.setattr(cli_module.LazyGroup, "get_command", lambda self, ctx, name: boom)
    try:
        main(["boom"])
    except SystemExit as exit_:
        assert exit_.code == 2
    err = capsys.readouterr().err.strip()
    assert err == "spikenerf: error: x/transforms.json: expected 3 fields, found 2"


@pytest.mark.parametrize(
    ("raised", "said"),
    [(InputError("frame 3 is truncated"), "spikenerf: error: frame 3 is truncated"),
     (KeyboardInterrupt(), "spikenerf: aborted"), (Terminated(), "spikenerf: terminated")],
)  # fmt: skip
def test_an_error_inside_a_progress_bar_starts_a_line_of_its_own(monkeypatch, capsys, raised, said) -> None:
    """The error line followed the text of the bar it interrupted (``render: 0%|… 0/6 [...]spikenerf: error:
    …``), and the bar was drawn again after it."""
    import click

    import spikenerf.cli as cli_module
    from spikenerf.core.progress import bar

    @click.command()
    def broken() -> None:
        progress = bar(total=6, desc="render")  # a bar updated by hand: no loop closes it on the way out
        progress.update(3)
        raise raised

    monkeypatch.setattr(cli_module.LazyGroup, "get_command", lambda self, ctx, name: broken)
    with pytest.raises(SystemExit):
        main(["broken"])
    err = capsys.readouterr().err
    assert err.endswith("\n" + said + "\n") and "3/6" in err.split("\n")[-3], repr(err)


@pytest.mark.parametrize(("command", "hint"), [("render", "run the same command again"), ("info", None)])
def test_ctrl_c_says_how_a_command_that_resumes_continues(monkeypatch, capsys, command, hint) -> None:
    import click

    import spikenerf.cli as cli_module

    @click.command()
    def stopped() -> None:
        raise click.exceptions.Abort()

    def resolve(self, ctx, args):  # type: ignore[no-untyped-def]
        cli_module.LazyGroup.invoked = command
        return command, stopped, args[1:]

    monkeypatch.setattr(cli_module.LazyGroup, "resolve_command", resolve)
    with pytest.raises(SystemExit) as exit_:
        main([command])
    assert exit_.value.code == 130
    err = capsys.readouterr().err.strip()
    assert err == "spikenerf: aborted" + (f" ({hint} to continue where it stopped)" if hint else "")


def test_cli_choices_come_from_the_owning_literals() -> None:
    """Each choice list is one ``Literal`` in the module that implements it; the CLI shows exactly those."""
    import importlib

    import click

    from spikenerf.camera.modes import COLORS, NOISES, ColorMode
    from spikenerf.camera.reconstruct import METHODS, ReconMethod
    from spikenerf.data.choices import COLORS as TRAIN_COLORS
    from spikenerf.data.choices import METHODS as TRAIN_METHODS
    from spikenerf.data.targets import RECONS, TargetRecon
    from spikenerf.fields import FIELD_KINDS, FieldKind
    from spikenerf.importing.options import ORIENT_CHOICES
    from spikenerf.importing.orientation import Orient

    def choices(command: str, option: str) -> list[str]:
        params = importlib.import_module(SUBCOMMANDS[command][0]).command.params
        param = next(p for p in params if p.name == option)
        assert isinstance(param.type, click.Choice)
        return list(param.type.choices)

    assert typing.get_args(ColorMode) == COLORS and choices("simulate", "color") == [*COLORS, "all"]
    assert tuple(choices("reconstruct", "color")) == COLORS and tuple(choices("simulate", "noise")) == NOISES
    assert typing.get_args(ReconMethod) == METHODS and (*METHODS, "learned") == RECONS
    assert tuple(choices("reconstruct", "method")) == RECONS == typing.get_args(TargetRecon)
    assert tuple(choices("train", "recon")) == RECONS
    assert tuple(choices("train", "field")) == FIELD_KINDS == typing.get_args(FieldKind)
    assert tuple(choices("import", "orient")) == ORIENT_CHOICES == typing.get_args(Orient)
    assert (
        tuple(choices("train", "method")) == TRAIN_METHODS
        and tuple(choices("train", "color")) == TRAIN_COLORS
    )


@pytest.mark.parametrize(
    ("raised", "one_line"),
    [
        (
            RuntimeError("[enforce fail at alloc_cpu.cpp:127] DefaultCPUAllocator: can't allocate memory"),
            True,
        ),
        (RuntimeError("CUDA out of memory. Tried to allocate 2.00 GiB"), True),
        (MemoryError(), True),
        (RuntimeError("an internal bug"), False),
    ],
)
def test_a_failed_allocation_is_one_line_and_a_bug_is_not_hidden(
    capsys, monkeypatch, tmp_path: Path, raised: BaseException, one_line: bool
) -> None:
    import spikenerf.core.device

    def fail(name: str = "auto"):
        raise raised

    monkeypatch.setattr(spikenerf.core.device, "resolve_device", fail)
    if not one_line:
        with pytest.raises(RuntimeError, match="internal bug"):
            main(["demo", "--out", str(tmp_path / "d")])
        return
    with pytest.raises(SystemExit) as exit_:
        main(["demo", "--out", str(tmp_path / "d")])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.strip() == f"spikenerf: error: {OUT_OF_MEMORY}"
    assert not (tmp_path / "d").exists()


@pytest.mark.parametrize("scene", ["all", "analytic-orbs,analytic-blocks", "nope"])
def test_demo_takes_one_scene_by_name(capsys, tmp_path: Path, scene: str) -> None:
    """``demo --scene`` runs one scene: a list or ``all`` (which chose a Blender scene) is refused, not cut
    to its first name."""
    with pytest.raises(SystemExit) as exit_:
        main(["demo", "--scene", scene, "--out", str(tmp_path / "d")])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.count("\n") == 1
    assert err.startswith("spikenerf: error: --scene: expected one scene name of analytic-orbs")
    assert not (tmp_path / "d").exists()


def test_benchmark_scenes_all_without_blender_says_what_stands_in(capsys, monkeypatch, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """Without Blender ``--scenes all`` is the analytic scenes (a Table I of other scenes): said in a line."""
    import spikenerf.pipelines.benchmark.cells as cells
    import spikenerf.pipelines.suite as suite
    import spikenerf.scenes.registry as registry

    ran = []
    monkeypatch.setattr(registry, "blender_available", lambda: False)
    monkeypatch.setattr(cells, "blender_available", lambda: False)
    monkeypatch.setattr(suite, "benchmark_with_report", ran.append)
    main(["benchmark", "--scenes", "all", "--out", str(tmp_path / "b")])
    err = capsys.readouterr().err
    assert "spikenerf: warning: --scenes all: Blender is not installed" in err and err.count("\n") == 1
    assert ran[0].scenes == [s.name for s in registry.list_scenes() if not s.needs_blender]


def test_train_names_the_flag_of_a_bad_config_set_or_field_option(capsys, tmp_path: Path) -> None:
    """Errors that named no flag (a missing --config, an empty one, an unknown --set key, a section given a
    value, an unknown --field-option) name it; a run folder given as --config reads its config.yaml."""
    empty = tmp_path / "empty.yaml"
    empty.write_text("")
    cases = [
        (["--config", str(tmp_path / "nope.yaml")], "nope.yaml: --config: file not found"),
        (["--config", str(tmp_path)], "--config: is a folder without a config.yaml"),
        (["--config", str(empty)], "empty.yaml: is empty: expected a YAML mapping of TrainConfig fields"),
        (["--set", "spike=3"], "--set spike must be a mapping (KEY: VALUE), found 3"),
        (["--set", "spike.lamb=0.5"], "--set spike.lamb: unknown spike keys ['lamb']"),
        (["--set", "spike.lam=abc"], "--set spike.lam must be a number, found 'abc'"),
        (["--field-option", "nonsense=3"], "--field-option: unknown grid field config keys ['nonsense']"),
        (["--field-option", "static_sample=3"], "keys ['static_sample']; did you mean static_samples"),
    ]
    for args, words in cases:
        with pytest.raises(SystemExit) as exit_:
            main(["train", str(tmp_path / "ds"), "--out", str(tmp_path / "run"), *args])
        err = capsys.readouterr().err
        assert exit_.value.code == 2 and words in err and err.count("\n") == 1, (args, err)
    assert not (tmp_path / "run").exists()
    run = tmp_path / "done"
    run.mkdir()
    (run / "config.yaml").write_text("iters: 0\n")  # read from the folder: its value is refused
    with pytest.raises(SystemExit):
        main(["train", str(tmp_path / "ds"), "--out", str(tmp_path / "run"), "--config", str(run)])
    assert "done/config.yaml" in capsys.readouterr().err


def test_python_warnings_print_as_one_line_and_the_callers_display_comes_back(capsys) -> None:  # type: ignore[no-untyped-def]
    """A library's ``warnings.warn`` during a command prints one ``spikenerf: warning:`` line (Python's
    default adds the file, line and source line); ``main`` puts the caller's ``showwarning`` back."""
    import warnings

    from spikenerf.cli import _warning_line, main

    before = warnings.showwarning
    _warning_line(UserWarning("the kernel\nfailed"), UserWarning, "x.py", 3)
    assert capsys.readouterr().err == "spikenerf: warning: the kernel failed\n"
    with pytest.raises(SystemExit):
        main(["info", "/nonexistent/run"])
    assert warnings.showwarning is before


def test_spikenerf_quiet_hides_every_bar_and_each_command_takes_both_spellings(
    capsys, tmp_path, monkeypatch
) -> None:  # type: ignore[no-untyped-def]
    """``spikenerf --quiet COMMAND`` hides every progress bar, also in the processes it starts (the variable
    is inherited) and is put back afterwards; ``--quiet`` and ``--no-progress`` are one option on every
    command that has either; on a command without one, ``--quiet`` after it is named a global option."""
    import os

    from helpers import run_cli
    from spikenerf.core import progress

    monkeypatch.delenv(progress.QUIET_ENV, raising=False)
    assert not progress.bar(range(3), show=True).disable and progress.bar(range(3), show=False).disable
    seen: list[bool] = []
    monkeypatch.setattr("spikenerf.cli.info.command.callback", lambda *a, **k: seen.append(progress.quiet()))
    run_cli(capsys, "--quiet", "info", tmp_path)
    assert seen == [True] and progress.QUIET_ENV not in os.environ  # set for the command, then put back
    monkeypatch.setenv(progress.QUIET_ENV, "1")
    assert progress.bar(range(3), show=True).disable
    monkeypatch.delenv(progress.QUIET_ENV)
    out = tmp_path / "ds"
    code, _, err = run_cli(capsys, "simulate", "--scene", "analytic-orbs", "--width", 8, "--height", 8,
                           "--frames", 20, "--test-views", 1, "--quiet", "--out", out)  # fmt: skip
    assert code == 0 and "it/s" not in err and "step/s" not in err, err
    for command in ("train", "eval", "render"):
        code, _, err = run_cli(capsys, command, tmp_path / "nothing", "--no-progress")
        assert "No such option" not in err, err
    code, _, err = run_cli(capsys, "import", out / "spikes_gray.dat", "--quiet")
    assert code == 2 and "--quiet is a global option: put it first, e.g. spikenerf --quiet COMMAND" in err


def test_the_command_asks_for_huge_pages_before_torch_loads_only(monkeypatch: pytest.MonkeyPatch) -> None:
    """``main`` sets torch's THP_MEM_ALLOC_ENABLE for its process and children unless it is set already;
    an in-process caller (torch imported) keeps its environment."""
    import os

    from spikenerf.cli import HUGE_PAGES_ENV, use_huge_pages

    monkeypatch.delenv(HUGE_PAGES_ENV, raising=False)
    use_huge_pages()  # torch is loaded in this process: nothing changes
    assert HUGE_PAGES_ENV not in os.environ
    code = (
        "import os, sys, spikenerf.cli as c; c.use_huge_pages()\n"
        "print(os.environ.get(c.HUGE_PAGES_ENV), 'torch' in sys.modules)"
    )
    for given, seen in ((None, "1 False"), ("0", "0 False")):
        env = {k: v for k, v in os.environ.items() if k != HUGE_PAGES_ENV}
        if given is not None:
            env[HUGE_PAGES_ENV] = given
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
        assert out.stdout.strip() == seen
