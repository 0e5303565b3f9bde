"""The one reconstruction entry point (data/reconstruction.py): tfp, tfi and learned behind one dispatch,
equal bit for bit to the camera's functions on the whole stream."""

from __future__ import annotations

import numpy as np
import pytest

from spikenerf.camera.reconstruct import tfi, tfp
from spikenerf.camera.tfstp import tfstp
from spikenerf.core.errors import InputError
from spikenerf.data.reconstruction import RECONS, frame_at, reconstruct_stream, reconstructor


@pytest.fixture(scope="module")
def stream() -> np.ndarray:
    rng = np.random.default_rng(3)
    return (rng.random((90, 5, 7)) < rng.uniform(0.02, 0.6, (5, 7))).astype(np.uint8)


def test_every_form_equals_the_whole_stream_reconstruction(stream: np.ndarray) -> None:
    read = lambda a, b: stream[a:b]  # noqa: E731
    for start, stop in ((0, 90), (30, 33), (85, 90)):
        np.testing.assert_array_equal(
            reconstructor("tfp", 11, 2.0)(read, 90, start, stop), tfp(stream, 11, 2.0)[start:stop]
        )
        np.testing.assert_array_equal(
            reconstructor("tfi", None, 2.0)(read, 90, start, stop), tfi(stream, 2.0)[start:stop]
        )
        np.testing.assert_array_equal(
            reconstructor("tfstp", None, 2.0)(read, 90, start, stop), tfstp(stream, 2.0)[start:stop]
        )
    for k in (0, 7, 45, 89):
        np.testing.assert_array_equal(frame_at(stream, k, "tfp", 21, 0.5), tfp(stream, 21, 0.5, frames=k)[0])
        np.testing.assert_array_equal(frame_at(read, k, "tfi", total=90), tfi(stream)[k])
    np.testing.assert_array_equal(reconstruct_stream(stream, "tfp", 9), tfp(stream, 9))
    np.testing.assert_array_equal(reconstruct_stream(stream, "tfi", 9, 1.5), tfi(stream, 1.5))
    np.testing.assert_array_equal(
        reconstruct_stream(stream, "tfi", frames=slice(3, 60, 4)), tfi(stream)[3:60:4]
    )
    np.testing.assert_array_equal(frame_at(read, 45, "tfstp", total=90), tfstp(stream)[45])
    assert RECONS == ("tfp", "tfi", "tfstp", "learned")


def test_the_learned_path_goes_through_the_same_dispatch(stream: np.ndarray) -> None:
    from spikenerf.recon.infer import learned_reconstructor

    read = lambda a, b: stream[a:b]  # noqa: E731
    want = learned_reconstructor()(read, 90, 40, 42)
    np.testing.assert_array_equal(reconstructor("learned")(read, 90, 40, 42), want)
    np.testing.assert_array_equal(frame_at(stream, 41, "learned", window=None), want[1])


def test_bad_requests_are_input_errors(stream: np.ndarray) -> None:
    with pytest.raises(InputError, match="recon must be one of tfp, tfi, tfstp, learned, found 'tfx'"):
        reconstructor("tfx")
    with pytest.raises(InputError, match="recon must be one of"):
        reconstruct_stream(stream, "nope")
    with pytest.raises(InputError, match=r"^total: "):
        frame_at(lambda a, b: stream[a:b], 3)
    with pytest.raises(InputError, match="odd"):
        frame_at(stream, 3, "tfp", 10)


def test_scattered_frames_equal_per_frame_calls_in_fewer_scans(monkeypatch: pytest.MonkeyPatch) -> None:
    """frames_reconstructor (recon-eval, the no-reference checks) equals one reconstructor call per frame
    bit for bit, in one TFSTP scan, and one TFP/TFI call per run of nearby frames (far ones read apart)."""
    from spikenerf.camera import reconstruct
    from spikenerf.data.reconstruction import frames_reconstructor

    rng = np.random.default_rng(5)
    stream = (rng.random((400, 4, 5)) < rng.uniform(0.01, 0.5, (4, 5))).astype(np.uint8)
    stream[:, 0, 0] = 0  # a silent pixel: TFI and TFSTP read to the stream's ends
    read = lambda a, b: stream[a:b]  # noqa: E731
    # runs: TFP (reach 41) 4, TFI (reach 128) 3, but the silent pixel makes TFI's first read the whole
    # stream, which then makes every frame
    frames = np.array([0, 3, 4, 50, 51, 200, 399])
    calls = {name: 0 for name in ("tfp", "tfi", "tfstp")}
    for name in calls:
        real = getattr(reconstruct, name)

        def counted(*args: object, _real=real, _name=name, **kwargs: object) -> np.ndarray:
            calls[_name] += 1
            return _real(*args, **kwargs)

        monkeypatch.setattr(reconstruct, name, counted)
    for name, window, want_calls in (("tfp", 41, 4), ("tfi", None, 1), ("tfstp", None, 1)):
        calls[name] = 0
        got = frames_reconstructor(name, window, 1.5)(read, 400, frames)
        assert calls[name] == want_calls, (name, calls)
        one = reconstructor(name, window, 1.5)
        want = np.stack([one(read, 400, int(k), int(k) + 1)[0] for k in frames])
        assert got.dtype == np.float32
        np.testing.assert_array_equal(got, want)
    learned = frames_reconstructor("learned")  # (its frames were not checked: [] a ValueError of np.stack)
    for bad in ([], [3, 3], [5, 2], [0, 400], [-1, 2], [[1, 2]], [1.0, 2.0]):
        for recon in (frames_reconstructor("tfstp"), learned):
            with pytest.raises(InputError) as err:
                recon(read, 400, np.asarray(bad))
            assert err.value.params == ("frames",), bad


def test_training_targets_are_one_tfstp_scan(stream: np.ndarray, monkeypatch: pytest.MonkeyPatch) -> None:
    """``train --recon tfstp`` targets (reconstruct_stream, every step) and a strided slice: one scan each,
    equal to the whole run there."""
    from spikenerf.camera import reconstruct

    calls: list[int] = []
    monkeypatch.setattr(reconstruct, "tfstp", lambda *a, **k: calls.append(1) or tfstp(*a, **k))
    np.testing.assert_array_equal(reconstruct_stream(stream, "tfstp", threshold=2.0), tfstp(stream, 2.0))
    np.testing.assert_array_equal(
        reconstruct_stream(stream, "tfstp", frames=slice(3, 60, 4)), tfstp(stream)[3:60:4]
    )
    assert len(calls) == 2


def test_frames_all_along_a_long_stream_are_read_a_piece_at_a_time() -> None:
    """GT frames every 10 steps of a long stream were one TFP or TFI read of the whole stream (each frame
    within the other's reach): a read now holds at most RUN_SPAN frames and the margins, and the result is
    still the whole stream's."""
    from spikenerf.camera.reconstruct import RUN_SPAN, TFI_MARGIN, reconstruct_at

    total = 3 * RUN_SPAN + 100
    rng = np.random.default_rng(8)
    stream = (rng.random((total, 2, 3)) < rng.uniform(0.2, 0.6, (2, 3))).astype(np.uint8)
    spans: list[int] = []

    def read(a: int, b: int) -> np.ndarray:
        spans.append(b - a)
        return stream[a:b]

    frames = np.arange(5, total, 10)
    for name, whole, margins in (
        ("tfp", tfp(stream, 41, 0.5), 40),
        ("tfi", tfi(stream, 0.5), 2 * TFI_MARGIN),
    ):
        spans.clear()
        got = reconstruct_at(read, total, frames, name, 41, 0.5)
        np.testing.assert_array_equal(got, whole[frames])
        assert len(spans) >= 3 and max(spans) <= RUN_SPAN + margins, (name, max(spans))
    stream[:, 1, 2] = 0  # a pixel that never fires: TFI reads the whole stream, once, for every frame
    spans.clear()
    np.testing.assert_array_equal(
        reconstruct_at(read, total, frames, "tfi", threshold=0.5), tfi(stream, 0.5)[frames]
    )
    assert spans[-1] == total and spans.count(total) == 1, spans  # (after the margins' doublings)
