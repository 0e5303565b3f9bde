"""An orbit's elevation and turns are bounded: beyond them the poses would be degenerate or not finite."""

from __future__ import annotations

import numpy as np
import pytest

from spikenerf.core.errors import InputError
from spikenerf.importing.poses import orbit_poses
from spikenerf.scenes.trajectory import MAX_TURNS, orbit, orbit_angle_problem


@pytest.mark.parametrize(("elevation", "turns"), [(30, 1), (-90, 0), (90, -MAX_TURNS), (0, MAX_TURNS)])
def test_in_range_orbits_are_accepted_and_finite(elevation: float, turns: float) -> None:
    assert orbit_angle_problem(elevation, turns) is None
    assert np.isfinite(orbit(4.0, elevation, turns, duration=1e-3).poses).all()


@pytest.mark.parametrize(
    ("elevation", "turns", "word"),
    [(90.5, 1, "elevation"), (-1e308, 1, "elevation"), (float("nan"), 1, "elevation"),
     (30, 1e308, "turns"), (30, -2 * MAX_TURNS, "turns"), (30, float("nan"), "turns")],
)  # fmt: skip
def test_out_of_range_orbits_are_refused_naming_the_value(elevation: float, turns: float, word: str) -> None:
    problem = orbit_angle_problem(elevation, turns)
    assert problem is not None and problem.startswith(word)
    with pytest.raises(InputError, match=word) as err:
        orbit(4.0, elevation, turns, duration=1e-3)
    assert err.value.params == ("elevation_deg" if word == "elevation" else word,)  # orbit()'s names
    with pytest.raises(InputError, match="orbit") as err:
        orbit_poses(f"4,{elevation},{turns}", 40, 40000.0)
    assert err.value.params == ("orbit",)
