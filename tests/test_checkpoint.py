"""``train/checkpoint.py``: the zip's CRC-32 of every record is checked on load, so bytes changed on disk
after the write are refused in one line instead of used."""

from __future__ import annotations

import zipfile
from pathlib import Path

import pytest
import torch

from spikenerf.core.errors import InputError
from spikenerf.train.checkpoint import FORMAT, load_checkpoint, save_checkpoint

PAYLOAD = {
    "iteration": 3, "elapsed": 1.5, "model": {"w": torch.arange(4096, dtype=torch.float32)}, "hparams": {},
    "optimizer": {"state": {}, "param_groups": []}, "rng": {"torch": torch.get_rng_state()}, "config": {},
}  # fmt: skip


def _flip_in_record(path: Path, name_end: str) -> None:
    """Flip one byte inside the stored data of the zip record whose name ends with ``name_end``."""
    with zipfile.ZipFile(path) as archive:
        info = next(i for i in archive.infolist() if i.filename.endswith(name_end))
    raw = bytearray(path.read_bytes())
    header = info.header_offset
    start = header + 30 + int.from_bytes(raw[header + 26 : header + 28], "little")
    start += int.from_bytes(raw[header + 28 : header + 30], "little")  # past the name and extra field
    raw[start + info.compress_size // 2] ^= 0x01
    path.write_bytes(bytes(raw))


def test_a_saved_checkpoint_loads_whole(tmp_path: Path) -> None:
    save_checkpoint(tmp_path / "checkpoint.pt", PAYLOAD)
    data = load_checkpoint(tmp_path / "checkpoint.pt")
    assert data["format"] == FORMAT and torch.equal(data["model"]["w"], PAYLOAD["model"]["w"])


def test_a_bit_changed_in_a_tensor_is_refused_naming_the_file(tmp_path: Path) -> None:
    path = tmp_path / "checkpoint.pt"
    save_checkpoint(path, PAYLOAD)
    _flip_in_record(path, "data/0")
    torch.load(path, weights_only=True)  # torch itself reads the changed tensor without complaint
    with pytest.raises(InputError, match="fails its CRC-32 check") as err:
        load_checkpoint(path)
    assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_the_crc_is_written_even_where_the_process_switched_it_off(tmp_path: Path) -> None:
    """save_checkpoint writes CRCs for load_checkpoint to check; a file saved without them still loads."""
    serialization = torch.serialization
    if not hasattr(serialization, "set_crc32_options"):
        pytest.skip("torch < 2.4 always writes the CRC-32")
    serialization.set_crc32_options(False)
    try:
        save_checkpoint(tmp_path / "checkpoint.pt", PAYLOAD)
        assert not serialization.get_crc32_options()  # the process's choice is put back
        torch.save({"format": FORMAT, **PAYLOAD}, tmp_path / "plain.pt")  # every CRC 0
    finally:
        serialization.set_crc32_options(True)
    _flip_in_record(tmp_path / "checkpoint.pt", "data/0")
    with pytest.raises(InputError, match="CRC-32"):  # it has its CRCs
        load_checkpoint(tmp_path / "checkpoint.pt")
    assert load_checkpoint(tmp_path / "plain.pt")["iteration"] == 3


def test_files_without_crcs_are_left_to_torch_load(tmp_path: Path) -> None:
    """torch's legacy (non-zip) format has no CRCs: it loads; a cut file is torch.load's one-line error."""
    legacy = tmp_path / "legacy.pt"
    torch.save({"format": FORMAT, **PAYLOAD}, legacy, _use_new_zipfile_serialization=False)
    assert load_checkpoint(legacy)["iteration"] == 3
    cut = tmp_path / "cut.pt"
    save_checkpoint(cut, PAYLOAD)
    cut.write_bytes(cut.read_bytes()[:300])
    with pytest.raises(InputError, match="unreadable checkpoint"):
        load_checkpoint(cut)


def test_a_changed_zip_directory_entry_is_one_damaged_line(tmp_path: Path) -> None:
    """A flipped compression method in the central directory makes zipfile raise NotImplementedError."""
    path = tmp_path / "checkpoint.pt"
    save_checkpoint(path, PAYLOAD)
    raw = bytearray(path.read_bytes())
    entry = raw.index(b"PK\x01\x02")  # the first central-directory entry; its method is at offset 10
    raw[entry + 10] = 1
    path.write_bytes(bytes(raw))
    with pytest.raises(InputError, match="damaged checkpoint: its records cannot be read"):
        load_checkpoint(path)
