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
