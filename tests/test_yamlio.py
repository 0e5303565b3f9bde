"""Strict YAML: a key given twice in a file that a user wrote is refused, not read as its last value."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from helpers import run_cli
from spikenerf.camera.spikecv import read_spikecv_config
from spikenerf.core.errors import InputError
from spikenerf.core.yamlio import load_yaml


def test_load_yaml_reads_what_safe_load_reads() -> None:
    text = "a: 1\nb: {c: [1, 2], d: null}\ne: 1e-3\nf: '2'\n"
    assert load_yaml(text) == yaml.safe_load(text)
    assert load_yaml("") is None and load_yaml("- a\n- a\n") == ["a", "a"]  # equal list items are fine
    assert load_yaml("a: {x: 1}\nb: {x: 2}\n") == {"a": {"x": 1}, "b": {"x": 2}}  # one key per mapping
    merges = [  # merge keys and anchors: a key of its own overrides a merged one (no duplicate)
        "base: &b {lam: 0.25, window: 4}\nspike:\n  <<: *b\n  window: 8\n",
        "a: &a {x: 1}\nb: &b {y: 2}\nc:\n  <<: [*a, *b]\n  x: 3\n",
        "spike:\n  <<: {lam: 0.25}\n  window: 8\n",
        "c: &c\n  <<: &b\n    <<: {x: 1}\n    x: 2\nd: *b\n",  # an anchor flattened in place, then aliased
    ]
    for text in merges:
        assert load_yaml(text) == yaml.safe_load(text)


@pytest.mark.parametrize(
    ("text", "key", "line"),
    [("spike_h: 32\nspike_w: 4\nspike_h: 16\n", "spike_h", 3), ("a:\n  x: 1\n  x: 2\n", "x", 3)],
)
def test_load_yaml_refuses_a_repeated_key_naming_it_and_its_line(text: str, key: str, line: int) -> None:
    with pytest.raises(yaml.YAMLError, match=rf"^duplicate key '{key}' at line {line} \(given twice"):
        load_yaml(text)
    assert yaml.safe_load(text)  # (what safe_load kept: the last value, silently)


def test_a_spikecv_config_with_a_repeated_key_is_refused_and_an_empty_one_named(tmp_path: Path) -> None:
    """A config with spike_h 32 then 16 imported a garbage 48×16 dataset."""
    path = tmp_path / "config.yaml"
    path.write_text("spike_h: 32\nspike_h: 16\nspike_w: 48\n")
    with pytest.raises(InputError, match="duplicate key 'spike_h' at line 2"):
        read_spikecv_config(path)
    path.write_text("")
    with pytest.raises(InputError, match="is empty: expected spike_h and spike_w"):
        read_spikecv_config(path)
    with pytest.raises(InputError, match=r"nope\.yaml: no such file$"):
        read_spikecv_config(tmp_path / "nope.yaml")


def test_train_config_and_field_option_with_a_repeated_key_are_one_line(capsys, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    config = tmp_path / "c.yaml"
    config.write_text("iters: 10\nbatch: 64\niters: 20\n")
    code, _, err = run_cli(capsys, "train", "--config", config, "--out", tmp_path / "run")
    assert code == 2 and "duplicate key 'iters' at line 3" in err and err.count("\n") == 1
    assert not (tmp_path / "run").exists()


def test_a_bad_value_in_a_config_file_is_named_as_its_key_not_as_a_flag(capsys, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """``iters: many`` in a --config file read "c.yaml: --iters must be an integer" (no such flag given)."""
    for text, message in (
        ("iters: many\n", "c.yaml: iters must be an integer, found 'many'"),
        ("method: foo\n", "c.yaml: method must be one of"),
        ("spike: {lam: [1]}\n", "c.yaml: spike.lam must be a number"),
        ("device: bogus\n", "c.yaml: device must be one of auto"),  # read "--device must be one of"
        ("field_config: {foo: 1}\n", "c.yaml: unknown grid field config keys ['foo']"),  # no file named
        ("iters: 99999999999999999999\n", "found 99999999999999999999 (too large: 64-bit integers"),
    ):
        (tmp_path / "c.yaml").write_text(text)
        code, _, err = run_cli(capsys, "train", "--config", tmp_path / "c.yaml", "--out", tmp_path / "run")
        assert code == 2 and message in err and "--" not in err.split("c.yaml:")[1], err


def test_a_datasets_camera_config_given_as_a_train_config_is_named_as_such(capsys, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """``train --config DATASET`` listed the camera config's keys as unknown train config keys."""
    from spikenerf.core.marker import mark

    dataset = tmp_path / "ds"
    dataset.mkdir()
    (dataset / "config.yaml").write_text("spike_h: 16\nspike_w: 16\n")
    mark(dataset, "dataset")
    code, _, err = run_cli(capsys, "train", "--config", dataset, "--out", tmp_path / "run")
    assert code == 2 and "ds: is a dataset folder, not a run folder" in err and "unknown" not in err, err


def test_a_train_config_beside_another_tools_manifest_is_read(tmp_path: Path) -> None:
    """A folder with a ``manifest.json`` was taken for a recon-data pair folder (no marker: not ours)."""
    from spikenerf.train.config_file import load_config

    (tmp_path / "manifest.json").write_text("{}")
    (tmp_path / "config.yaml").write_text("iters: 7\n")
    assert load_config(tmp_path / "config.yaml").iters == 7


def test_load_config_reads_a_run_folder_and_refuses_a_dataset_folder(tmp_path: Path) -> None:
    """``load_config(RUN)`` said "missing run config (not a run folder…)" of a real run folder."""
    from spikenerf.core.marker import mark
    from spikenerf.train.config_file import load_config

    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "config.yaml").write_text("iters: 5\n")
    assert load_config(tmp_path / "run").iters == 5
    (tmp_path / "ds").mkdir()
    (tmp_path / "ds" / "config.yaml").write_text("spike_h: 4\n")
    mark(tmp_path / "ds", "dataset")
    with pytest.raises(InputError, match="is a dataset folder, not a run folder"):
        load_config(tmp_path / "ds")
