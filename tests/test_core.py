"""core/: colour conventions, atomic writes and device resolution."""

from __future__ import annotations

import re

import numpy as np
import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

from spikenerf.core.atomic import atomic_path, write_text_atomic
from spikenerf.core.color import rgb_to_gray, srgb_decode, srgb_encode
from spikenerf.core.device import resolve_device
from spikenerf.core.errors import InputError, comma_list


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


def test_atomic_path_leaves_nothing_on_error(tmp_path) -> None:
    target = tmp_path / "out.txt"
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("interrupted")
    assert not target.exists()
    assert list(tmp_path.iterdir()) == []
    write_text_atomic(target, "done")
    assert target.read_text() == "done"


def test_an_interrupt_right_after_the_temporary_is_made_leaves_nothing(tmp_path, monkeypatch) -> None:
    import spikenerf.core.atomic as atomic

    def interrupted(fd: int) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(atomic.os, "close", interrupted)
    with pytest.raises(KeyboardInterrupt), atomic_path(tmp_path / "out.txt"):
        pass
    monkeypatch.undo()
    assert list(tmp_path.iterdir()) == []


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
    with pytest.raises(InputError, match="auto, cpu, cuda or mps"):
        resolve_device("tpu")


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
    from spikenerf.core.marker import mark, replace_dir

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
