"""render.json read back (eval/render_record.py): a malformed or wrong-typed record is one InputError naming
it, for info and for a render into its folder alike."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from spikenerf.core.errors import InputError
from spikenerf.eval.render_record import read_render_record

RECORD = {
    "run": "/runs/a",
    "iteration": 2,
    "run_iterations": 2,
    "trajectory": "orbit",
    "views": 3,
    "size": [16, 16],
    "spike_steps": 40,
    "threshold": 1.0,
    "files": {"video": "orbit.mp4", "spikes": ["spikes_gray.dat", "spikes_tfp.png", "config.yaml"]},
}
#: case → (a change to the record, what the message says after "malformed render record (")
BAD = {
    "not-json": ("{not json", "JSONDecodeError"),
    "empty": ("", "JSONDecodeError"),
    "a-list": ([1, 2], "expected a JSON object, found list"),
    "no-size": ({"size": None}, "size: expected [width, height]"),
    "size-negative": ({"size": [-16, 16]}, "size: expected [width, height], two positive integers"),
    "size-fraction": ({"size": [16.5, 16]}, "size: expected"),
    "size-bool": ({"size": [True, 16]}, "size: expected"),
    "views-text": ({"views": "many"}, "views: expected an integer ≥ 0, found 'many'"),
    "iteration-negative": ({"iteration": -1}, "iteration: expected an integer ≥ 0 or null"),
    "threshold-text": ({"threshold": "1"}, "threshold: expected a number ≥ 0 or null"),
    "files-text": ({"files": "abc"}, "files: expected an object, found 'abc'"),
    "spikes-number": ({"files": {"spikes": 5}}, "files.spikes: expected a list of file names, found 5"),
    "spikes-path": ({"files": {"spikes": ["../x.dat"]}}, "files.spikes[0]: expected a file name in"),
    "video-number": ({"files": {"video": 3}}, "files.video: expected a file name in the folder, found 3"),
    "video-up": ({"files": {"video": ".."}}, "files.video: expected a file name"),
}


def _write(folder: Path, change: object) -> None:
    if isinstance(change, dict):
        change = json.dumps({**RECORD, **change})
    elif not isinstance(change, str):
        change = json.dumps(change)
    (folder / "render.json").write_text(change)


def test_a_whole_record_reads_back_and_none_is_none(tmp_path: Path) -> None:
    assert read_render_record(tmp_path) is None
    _write(tmp_path, {})
    assert read_render_record(tmp_path) == RECORD
    _write(tmp_path, {"files": {}, "spike_steps": None, "iteration": None})  # no video, no stream
    assert read_render_record(tmp_path)["files"] == {}


@pytest.mark.parametrize("case", list(BAD))
def test_a_malformed_record_is_one_error_naming_it(tmp_path: Path, case: str) -> None:
    change, found = BAD[case]
    _write(tmp_path, change)
    with pytest.raises(InputError) as err:
        read_render_record(tmp_path)
    message = str(err.value)
    assert message.startswith(f"{tmp_path / 'render.json'}: malformed render record ({found}"), message
    assert "\n" not in message and message.endswith("then render again"), message
