"""core/: colour conventions, atomic writes and device resolution."""

from __future__ import annotations

import re

import numpy as np
import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

from spikenerf.core.atomic import atomic_path, write_text_atomic
from spikenerf.core.color import rgb_to_gray, srgb_decode, srgb_encode, srgb_mse
from spikenerf.core.device import resolve_device
from spikenerf.core.errors import InputError, check_choice, comma_list


@given(st.floats(0.0, 1.0))
def test_srgb_round_trip(x: float) -> None:
    assert float(srgb_decode(srgb_encode(np.float64(x)))) == pytest.approx(x, abs=1e-9)


def test_srgb_known_values_numpy_and_torch_agree() -> None:
    x = np.array([0.0, 0.0031308, 0.18, 0.5, 1.0, 2.0])
    enc = srgb_encode(x)
    assert enc[0] == 0 and enc[-1] == pytest.approx(1.0) and enc[-2] == pytest.approx(1.0)
    assert enc[2] == pytest.approx(0.4613, abs=1e-3)  # 18% gray displays near 46%
    assert np.allclose(enc, srgb_encode(torch.from_numpy(x)).numpy())


def test_gray_weights_on_both_backends() -> None:
    rgb = np.zeros((3, 2, 2))
    rgb[1] = 1.0
    assert np.allclose(rgb_to_gray(rgb), 0.587)
    t = torch.ones(4, 4, 3)
    assert torch.allclose(rgb_to_gray(t, channel_axis=-1), torch.ones(4, 4))


def test_srgb_mse_compares_display_values_clipped_to_the_unit_range() -> None:
    pred = torch.tensor([[0.0, 0.18, 1.5]], dtype=torch.float16)  # 1.5 shows as white
    target = torch.tensor([[-0.2, 0.5, 1.0]])  # −0.2 shows as black
    expected = (srgb_encode(0.18) - srgb_encode(0.5)) ** 2 / 3
    assert srgb_mse(pred, target).dtype == torch.float32
    assert srgb_mse(pred, target).item() == pytest.approx(float(expected), rel=1e-3)
    assert srgb_mse(target, target).item() == 0.0


def test_atomic_path_leaves_nothing_on_error(tmp_path) -> None:
    target = tmp_path / "out.txt"
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("interrupted")
    assert not target.exists()
    assert list(tmp_path.iterdir()) == []
    write_text_atomic(target, "done")
    assert target.read_text() == "done"


def test_a_file_write_over_a_folder_is_refused_naming_it(tmp_path) -> None:
    """A folder where a file goes: ``os.replace`` failed naming the temporary (``.out.txt.x1y2z3.tmp: Is a
    directory``); the refusal names the file, and the folder and its contents stay."""
    from spikenerf.core.errors import InputError

    (tmp_path / "out.txt").mkdir()
    (tmp_path / "out.txt" / "mine").write_text("mine")
    with pytest.raises(InputError, match="is a folder, not a file") as err:
        write_text_atomic(tmp_path / "out.txt", "done")
    assert err.value.path == str(tmp_path / "out.txt")
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"] and (tmp_path / "out.txt" / "mine").is_file()


def test_a_failed_write_removes_the_folders_it_created_and_keeps_the_others(tmp_path) -> None:
    (tmp_path / "kept").mkdir()
    (tmp_path / "kept" / "user.txt").write_text("mine")
    with pytest.raises(RuntimeError), atomic_path(tmp_path / "kept" / "a" / "b" / "out.txt"):
        assert (tmp_path / "kept" / "a" / "b").is_dir()
        raise RuntimeError("interrupted")
    assert sorted(p.name for p in (tmp_path / "kept").iterdir()) == ["user.txt"]
    with pytest.raises(RuntimeError), atomic_path(tmp_path / "x" / "out.txt"):
        (tmp_path / "x" / "other.txt").write_text("written meanwhile")  # no longer empty: stays
        raise RuntimeError("interrupted")
    assert sorted(p.name for p in (tmp_path / "x").iterdir()) == ["other.txt"]
    write_text_atomic(tmp_path / "new" / "deep" / "out.txt", "done")  # success keeps them
    assert (tmp_path / "new" / "deep" / "out.txt").read_text() == "done"


@pytest.mark.parametrize("where", ["in the block", "before the replace"])
def test_an_interrupt_right_after_the_temporary_is_made_leaves_nothing(tmp_path, monkeypatch, where) -> None:
    """The temporary is named first and made by the writer, so an interrupt finds it wherever it lands:
    inside the ``with`` block, or once the temporary is complete and not yet in place (``write:NAME``)."""
    import spikenerf.core.atomic as atomic

    def interrupted(name: str) -> None:
        raise KeyboardInterrupt

    if where == "before the replace":
        monkeypatch.setattr(atomic, "failpoint", interrupted)
    (tmp_path / "out.txt").write_text("previous")
    with pytest.raises(KeyboardInterrupt), atomic_path(tmp_path / "out.txt") as tmp:
        tmp.write_text("half")
        if where == "in the block":
            raise KeyboardInterrupt
    monkeypatch.undo()
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]
    assert (tmp_path / "out.txt").read_text() == "previous"


def test_resolve_device() -> None:
    assert resolve_device("cpu").type == "cpu"
    assert resolve_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")
    with pytest.raises(InputError):
        resolve_device("tpu")
    if not torch.cuda.is_available():
        with pytest.raises(InputError):
            resolve_device("cuda")


def test_device_mps_is_accepted_where_torch_has_it(monkeypatch) -> None:
    monkeypatch.setattr(torch.backends.mps, "is_available", lambda: True)
    assert resolve_device("mps") == torch.device("mps")
    monkeypatch.setattr(torch.backends.mps, "is_available", lambda: False)
    with pytest.raises(InputError, match="no Apple-GPU"):
        resolve_device("mps")
    for bad in ("tpu", "cuda:x", "cuda1", " cpu", "cuda:00", "cuda:-1", "cuda:12345"):
        with pytest.raises(InputError, match=r"one of auto \| cpu \| cuda\[:N\] \| mps"):
            resolve_device(bad)


def test_a_cuda_index_is_named_where_torch_sees_no_cuda(monkeypatch) -> None:
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(InputError, match="device cuda:1 was asked for, but torch sees no CUDA device"):
        resolve_device("cuda:1")


def test_a_cuda_index_the_machine_lacks_is_named(monkeypatch) -> None:
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)
    assert resolve_device("cuda:1") == torch.device("cuda:1")
    for name in ("cuda:2", "cuda:256", "cuda:257"):  # torch alone reads 256 as 0, 257 as 1
        with pytest.raises(InputError, match=f"device {name} was asked for, but torch sees 2 CUDA device"):
            resolve_device(name)


def test_every_command_takes_the_same_device_names() -> None:
    """One ``--device`` option (``cli/types.device_option``): cuda:N everywhere, a typo refused as parsed."""
    import click
    from click.testing import CliRunner

    from spikenerf.cli import cli

    for command in ("train", "eval", "render", "benchmark", "demo"):
        result = CliRunner().invoke(cli, [command, "--device", "cuda:x"])
        assert result.exit_code == 2 and "'cuda:x' is not one of auto | cpu | cuda[:N] | mps" in result.output
        options = {p.name: p for p in cli.get_command(click.Context(cli), command).params}
        assert options["device"].type.name == "device", command


def test_check_choice_names_the_parameter_and_the_choices() -> None:
    check_choice("rgb", ("gray", "rgb"), "color")  # a choice passes
    with pytest.raises(InputError, match=r"^colour mode must be one of gray, rgb, found 'tfx'$") as err:
        check_choice("tfx", ("gray", "rgb"), "mode", "colour mode")
    assert err.value.params == ("mode",)
    with pytest.raises(InputError, match=r"^order must be one of a, b, found 3$"):
        check_choice(3, iter("ab"), "order")


def test_comma_list_keeps_known_names_and_words_the_error_through_the_caller() -> None:
    known = ("gray", "rgb", "bayer")
    assert comma_list(" rgb,, gray ", known, str) == [
        "rgb",
        "gray",
    ]  # stripped, empty items dropped, in order
    for spec, unknown in (("rgb,cmyk,x", "['cmyk', 'x']"), (" , ", "[]"), ("", "[]")):
        with pytest.raises(InputError, match=rf"^--color: {re.escape(unknown)}$"):
            comma_list(spec, known, lambda bad: f"--color: {bad}")


def test_replace_dir_swaps_a_finished_folder_in(tmp_path) -> None:
    from spikenerf.core.marker import mark
    from spikenerf.core.replacement import replace_dir

    out, work = tmp_path / "out", tmp_path / "work"
    out.mkdir()
    mark(out, "dataset")
    (out / "old.txt").write_text("old")
    work.mkdir()
    (work / "new.txt").write_text("new")
    replace_dir(work, out)
    assert sorted(p.name for p in out.iterdir()) == ["new.txt"] and not work.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # the retired folder is gone
    with pytest.raises(FileNotFoundError):
        replace_dir(tmp_path / "nothing", tmp_path / "else")


def test_an_output_where_no_file_can_be_made_is_named_as_such(tmp_path, monkeypatch) -> None:
    """A read-only file system, a folder without write permission, or a virtual file system (no size, and
    a file cannot be made there) is refused for what it is, naming the parameter and the path; a
    file system that reports no size but takes files (ramfs) is accepted, and the probe leaves nothing."""
    import os
    from types import SimpleNamespace

    from spikenerf.core import marker

    out = tmp_path / "new" / "ds"
    marker.check_output(out, "dataset")
    real = os.statvfs(tmp_path)
    fake = {"f_flag": real.f_flag, "f_blocks": real.f_blocks}
    monkeypatch.setattr(os, "statvfs", lambda _: SimpleNamespace(**fake))
    fake["f_flag"] = real.f_flag | os.ST_RDONLY
    with pytest.raises(InputError, match=r"ds: out: cannot write there: .* is on a read-only file") as err:
        marker.check_output(out, "dataset")
    assert err.value.params == ("out",) and err.value.path == str(out)
    fake["f_flag"], fake["f_blocks"] = real.f_flag, 0
    marker.check_output(out, "dataset")  # no size, but it takes a file
    from spikenerf.core.limits import free_disk

    assert free_disk(out) is None  # nor is its free space blamed: unknown, so not checked
    marker.check_file_output(tmp_path / "x.png", param="out")
    assert sorted(p.name for p in tmp_path.iterdir()) == []

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(marker.tempfile, "mkstemp", refuse)
    with pytest.raises(InputError, match="virtual file system that cannot hold files"):
        marker.check_file_output(tmp_path / "x.png", param="out")
    fake["f_blocks"] = real.f_blocks
    monkeypatch.setattr(os, "access", lambda *args, **kwargs: False)
    with pytest.raises(InputError, match="no permission"):
        marker.check_output(out, "dataset")


def test_an_unknown_key_suggests_the_closest_known_one() -> None:
    """``seeds`` beside a given ``seed`` suggested ``poses`` (keys already given were left out); the closest
    comes first, and of two as close the one not given yet."""
    from dataclasses import dataclass

    from spikenerf.core.config import close_keys, from_mapping

    @dataclass
    class Settings:
        seed: int = 0
        poses: str = "orbit"
        steps: int = 1
        step: int = 1

    with pytest.raises(InputError, match=r"unknown settings keys \['seeds'\]; did you mean seed, "):
        from_mapping(Settings, {"seed": 1, "seeds": 2}, "settings")
    assert close_keys("stepss", {"steps", "step"}, {"steps"}) == ["steps", "step"]  # the closest, given too
    assert close_keys("stepx", {"steps", "step"}, {"steps"}) == ["step", "steps"]  # as close: the free one
    assert close_keys("zzz", {"steps", "step"}, set()) == []
