"""Lens distortion of a camera, on normalised image coordinates (numpy or torch, no torch import).

Two models, named as nerfstudio's ``transforms.json`` names them (``camera_model``):

* ``OPENCV``, radial-tangential: a point ``(x, y)`` of the pinhole image plane at ``r² = x² + y²`` lands at
  ``x·d + 2·p1·x·y + p2·(r² + 2x²)``, ``y·d + p1·(r² + 2y²) + 2·p2·x·y`` with
  ``d = 1 + k1·r² + k2·r⁴ + k3·r⁶ + k4·r⁸`` (COLMAP's ``SIMPLE_RADIAL``, ``RADIAL``, ``OPENCV`` and the
  polynomial part of ``FULL_OPENCV``; nerfstudio's ``k4`` is the r⁸ term).
* ``OPENCV_FISHEYE``, equidistant: the ray at ``θ = atan(r)`` off the axis lands at the radius
  ``θ·(1 + k1·θ² + k2·θ⁴ + k3·θ⁶ + k4·θ⁸)`` in its own direction (COLMAP's ``OPENCV_FISHEYE``,
  ``RADIAL_FISHEYE``, ``SIMPLE_RADIAL_FISHEYE``, ``FISHEYE``, ``SIMPLE_FISHEYE``); no tangential terms.

Coordinates are OpenCV's normalised ones, ``x = (u − cx) / fl_x`` to the right and
``y = (v − cy) / fl_y`` down, ``(u, v)`` in pixels with pixel ``(i, j)``'s centre at ``(i + 0.5, j + 0.5)``
(COLMAP's and our convention). :meth:`Distortion.distort` maps the pinhole point to the recorded one,
:meth:`Distortion.undistort` inverts it by Newton's method, a fixed number of steps (no data-dependent loop:
no host sync, one compiled graph). :func:`checked` refuses a lens that is not invertible over its image, so
that every pixel of a camera has exactly one ray.
"""

from __future__ import annotations

import functools
import math
import sys
from dataclasses import dataclass
from typing import Any, Literal, Protocol, get_args

import numpy as np

from spikenerf.core.errors import InputError, is_finite

CameraModel = Literal["OPENCV", "OPENCV_FISHEYE"]
#: the lens models (nerfstudio's ``camera_model`` values)
CAMERA_MODELS: tuple[str, ...] = get_args(CameraModel)
#: the terms of :class:`Distortion`, as a ``transforms.json`` names them
TERMS = ("k1", "k2", "k3", "k4", "p1", "p2")
#: Newton steps of :meth:`Distortion.undistort` (:func:`checked` proves them enough over the image)
NEWTON_STEPS = 10
#: largest round-trip error (normalised units, float64) :func:`checked` accepts over the image
TOLERANCE = 1e-9
#: how far off the axis a fisheye image may reach: its rays are cast through the pinhole plane
FISHEYE_MAX_DEG = 89.0
#: pinhole radii sampled to find where the radial mapping stops growing (from 0 to 10⁴: 89.99° off axis)
_RADII = np.concatenate([np.linspace(0.0, 4.0, 40001), np.geomspace(4.0, 1e4, 2001)[1:]])


def _ops(x: Any) -> tuple[Any, Any, Any, Any]:
    """(sqrt, atan, tan, where) of ``x``'s library: torch for a tensor (imported already), else numpy."""
    torch = sys.modules.get("torch")
    if torch is not None and isinstance(x, torch.Tensor):
        return torch.sqrt, torch.atan, torch.tan, torch.where
    return np.sqrt, np.arctan, np.tan, np.where


@dataclass(frozen=True)
class Distortion:
    """A lens model and its terms (see the module doc); all terms zero is no distortion for ``OPENCV``
    (:attr:`is_pinhole`), an equidistant lens for ``OPENCV_FISHEYE``.

    Raises:
        InputError: naming ``camera_model`` for another model, a term that is not a finite number, or ``p1``
            / ``p2`` non-zero in a fisheye model (which has no tangential terms).
    """

    model: CameraModel = "OPENCV"
    k1: float = 0.0
    k2: float = 0.0
    k3: float = 0.0
    k4: float = 0.0
    p1: float = 0.0
    p2: float = 0.0

    def __post_init__(self) -> None:
        if self.model not in CAMERA_MODELS:
            models = ", ".join(CAMERA_MODELS)
            message = f"camera_model must be one of {models}, found {self.model!r}"
            raise InputError(message, param="camera_model")
        for name in TERMS:
            value = getattr(self, name)
            if not is_finite(value):
                raise InputError(f"{name} must be a finite number, found {value!r}", param=name)
            object.__setattr__(self, name, float(value))
        if self.fisheye and (self.p1 or self.p2):
            name = "p1" if self.p1 else "p2"
            raise InputError(
                f"{name} must be 0 for OPENCV_FISHEYE (a fisheye lens has no tangential terms), found "
                f"{getattr(self, name)!r}",
                param=name,
            )
        _ = self.limit  # (worked out now, not inside a compiled graph's first trace)

    @property
    def fisheye(self) -> bool:
        """The equidistant fisheye model."""
        return self.model == "OPENCV_FISHEYE"

    @property
    def is_pinhole(self) -> bool:
        """True for ``OPENCV`` with every term zero: the pinhole camera itself."""
        return not self.fisheye and not any(getattr(self, name) for name in TERMS)

    def as_json(self) -> dict[str, Any]:
        """The ``transforms.json`` keys of this lens: ``camera_model`` and its non-zero terms."""
        return {"camera_model": self.model, **{n: getattr(self, n) for n in TERMS if getattr(self, n)}}

    def describe(self) -> str:
        """One line for ``info``: ``OPENCV k1=-0.12 k2=0.03`` (the non-zero terms)."""
        terms = " ".join(f"{n}={getattr(self, n):.6g}" for n in TERMS if getattr(self, n))
        return f"{self.model} {terms}".strip()

    # ----------------------------------------------------------------------------------- the radial part
    def _radial(self, s: Any) -> Any:
        """``1 + k1·s + k2·s² + k3·s³ + k4·s⁴`` of ``s`` = r² (or θ² for the fisheye), any shape."""
        return 1.0 + s * (self.k1 + s * (self.k2 + s * (self.k3 + s * self.k4)))

    def _slope(self, s: Any) -> Any:
        """d/dr of ``r·radial(r²)`` at ``s`` = r²: ``1 + 3k1·s + 5k2·s² + 7k3·s³ + 9k4·s⁴``."""
        return 1.0 + s * (3 * self.k1 + s * (5 * self.k2 + s * (7 * self.k3 + s * 9 * self.k4)))

    @functools.cached_property
    def limit(self) -> tuple[float, float]:
        """(pinhole radius, distorted radius) where the radial mapping stops growing (tangential terms
        left out): beyond it the polynomial folds back, so :meth:`distort` continues it as a straight
        line and the mapping stays one to one. A fisheye's pinhole radius is at most
        ``tan(FISHEYE_MAX_DEG)``; a lens that never folds has ``(inf, inf)``."""
        radii = np.linspace(0.0, math.radians(FISHEYE_MAX_DEG), 20001) if self.fisheye else _RADII
        with np.errstate(over="ignore", invalid="ignore"):  # (absurd terms: refused by the image check)
            bad = np.flatnonzero(self._slope(radii**2) <= 0)
        if self.fisheye:
            top = float(radii[max(bad[0] - 1, 1)] if len(bad) else radii[-1])  # (> 0: a divisor)
            return math.tan(top), top * float(self._radial(top**2))
        if not len(bad):
            return math.inf, math.inf
        top = float(radii[max(bad[0] - 1, 1)])
        return top, top * float(self._radial(top**2))

    # ------------------------------------------------------------------------------------------- mapping
    def distort(self, x: Any, y: Any) -> tuple[Any, Any]:
        """Where the lens puts pinhole-plane points.

        Args:
            x, y: (...) normalised pinhole coordinates (OpenCV axes: x right, y down), numpy or torch.
        Returns:
            xd, yd (...) normalised distorted coordinates, same type and dtype. Beyond :attr:`limit` (outside
            any image :func:`checked` accepts) the radius grows on linearly, so such points stay outside.
        """
        sqrt, atan, _, where = _ops(x)
        r2 = x * x + y * y
        top, reach = self.limit
        if self.fisheye:
            r = sqrt(r2)
            safe = where(r > 1e-12, r, 1.0)
            theta = atan(r)
            bent = theta * self._radial(theta * theta)
            bent = where(theta > math.atan(top), theta * (reach / math.atan(top)), bent)
            scale = where(r > 1e-12, bent / safe, 1.0)
            return x * scale, y * scale
        d = self._radial(r2)
        xd = x * d + 2 * self.p1 * x * y + self.p2 * (r2 + 2 * x * x)
        yd = y * d + self.p1 * (r2 + 2 * y * y) + 2 * self.p2 * x * y
        if math.isfinite(top):  # (a lens that never folds keeps the plain polynomial)
            beyond = r2 > top * top
            xd, yd = where(beyond, x * (reach / top), xd), where(beyond, y * (reach / top), yd)
        return xd, yd

    def undistort(self, xd: Any, yd: Any, steps: int = NEWTON_STEPS) -> tuple[Any, Any]:
        """The pinhole-plane points the lens put at ``(xd, yd)``: ``steps`` Newton steps from ``(xd, yd)``
        (radial-tangential: the 2×2 system; fisheye: the angle θ along each point's own direction).

        Args:
            xd, yd: (...) normalised distorted coordinates (OpenCV axes), numpy or torch, any float dtype.
            steps: Newton steps (:data:`NEWTON_STEPS`).
        Returns:
            x, y (...) normalised pinhole coordinates, same type and dtype. Within an image that
            :func:`checked` accepts, ``distort(x, y)`` is ``(xd, yd)`` to < 1e-9 in float64 and to the
            dtype's rounding (a few 1e-7) in float32.
        """
        sqrt, _, tan, where = _ops(xd)
        if self.fisheye:
            rd = sqrt(xd * xd + yd * yd)
            top = math.atan(self.limit[0])
            theta = rd
            for _ in range(steps):
                t2 = theta * theta
                theta = theta - (theta * self._radial(t2) - rd) / self._slope(t2)
                theta = where(theta > top, top, where(theta < 0, 0.0, theta))
            scale = where(rd > 1e-12, tan(theta) / where(rd > 1e-12, rd, 1.0), 1.0)
            return xd * scale, yd * scale
        x, y = xd, yd
        for _ in range(steps):
            r2 = x * x + y * y
            d = self._radial(r2)
            dd = self.k1 + r2 * (2 * self.k2 + r2 * (3 * self.k3 + r2 * 4 * self.k4))  # d(d)/d(r²)
            fx = x * d + 2 * self.p1 * x * y + self.p2 * (r2 + 2 * x * x) - xd
            fy = y * d + self.p1 * (r2 + 2 * y * y) + 2 * self.p2 * x * y - yd
            a = d + 2 * x * x * dd + 2 * self.p1 * y + 6 * self.p2 * x  # ∂fx/∂x
            b = 2 * x * y * dd + 2 * self.p1 * x + 2 * self.p2 * y  # ∂fx/∂y = ∂fy/∂x
            c = d + 2 * y * y * dd + 6 * self.p1 * y + 2 * self.p2 * x  # ∂fy/∂y
            det = a * c - b * b
            det = where(det == 0, 1.0, det)
            x, y = x - (fx * c - fy * b) / det, y - (fy * a - fx * b) / det
        return x, y

    def jacobian_det(self, x: Any, y: Any) -> Any:
        """det of ∂(xd, yd)/∂(x, y) (...) of the radial-tangential polynomial at (...) points (numpy):
        positive wherever the lens maps a neighbourhood one to one without mirroring it."""
        r2 = x * x + y * y
        d = self._radial(r2)
        dd = self.k1 + r2 * (2 * self.k2 + r2 * (3 * self.k3 + r2 * 4 * self.k4))
        a = d + 2 * x * x * dd + 2 * self.p1 * y + 6 * self.p2 * x
        b = 2 * x * y * dd + 2 * self.p1 * x + 2 * self.p2 * y
        c = d + 2 * y * y * dd + 6 * self.p1 * y + 2 * self.p2 * x
        return a * c - b * b


class Pinhole(Protocol):
    """What :func:`checked` reads of a camera (``scenes.trajectory.Intrinsics``)."""

    width: int
    height: int
    fl_x: float
    fl_y: float
    cx: float
    cy: float


def checked(distortion: object, camera: Pinhole) -> Distortion | None:
    """The lens of ``camera``, checked over its image: None for None or a pinhole-equivalent lens (so that
    a pinhole camera's rays stay bit for bit what they were), else ``distortion`` itself.

    Raises:
        InputError: naming ``distortion`` when it is not a :class:`Distortion`, or when it is not invertible
            over the ``width × height`` image: its radial mapping folds back before the image's farthest
            corner, a fisheye image reaches :data:`FISHEYE_MAX_DEG` off the axis, or Newton's
            :data:`NEWTON_STEPS` steps do not undo it to :data:`TOLERANCE` over the image.
    """
    if distortion is None:
        return None
    if not isinstance(distortion, Distortion):
        found = f"{distortion!r:.60}"
        raise InputError(f"distortion must be a Distortion or None, found {found}", param="distortion")
    if distortion.is_pinhole:
        return None
    size = (camera.width, camera.height, camera.fl_x, camera.fl_y, camera.cx, camera.cy)
    problem = _problem(distortion, *(float(v) for v in size))
    if problem:
        raise InputError(
            f"distortion: the {distortion.describe()} lens is not invertible over the "
            f"{camera.width}×{camera.height} image ({problem}); check the calibration",
            param="distortion",
        )
    return distortion


@functools.lru_cache(maxsize=64)
def _problem(lens: Distortion, w: float, h: float, fx: float, fy: float, cx: float, cy: float) -> str:
    """Why ``lens`` cannot be undone over the image ("" when it can): a lattice of 65 × 65 points over the
    whole image, edges and corners included, undistorted and distorted back in float64."""
    u, v = np.meshgrid(np.linspace(0.0, w, 65), np.linspace(0.0, h, 65), indexing="xy")
    xd, yd = (u - cx) / fx, (v - cy) / fy
    corner = float(np.hypot(xd, yd).max())
    top, reach = lens.limit
    if corner >= reach:
        if lens.fisheye and top >= math.tan(math.radians(FISHEYE_MAX_DEG)) * (1 - 1e-9):
            return f"its corners reach beyond {FISHEYE_MAX_DEG:g}° off the axis"
        return (
            f"the distorted radius stops growing at {reach:.4g} normalised units, "
            f"{math.degrees(math.atan(top)):.3g}° off the axis, and the image corners lie at {corner:.4g}"
        )
    with np.errstate(all="ignore"):
        x, y = lens.undistort(xd, yd)
        bx, by = lens.distort(x, y)
        error = float(np.nanmax(np.hypot(bx - xd, by - yd))) if np.isfinite(x).all() else math.inf
        folded = not lens.fisheye and bool((lens.jacobian_det(x, y) <= 0).any())
    if not error <= TOLERANCE or not np.isfinite(y).all():
        return f"{NEWTON_STEPS} Newton steps leave a round-trip error of {error:.3g} normalised units"
    if folded:
        return "its tangential terms fold the image over"
    return ""


#: the COLMAP camera models ``import`` reads (colmap/sensor/models.h), each with its parameters in order: one
#: focal length ``f`` or two; ``FULL_OPENCV``'s rational terms (the divisor ``1 + k4·r² + k5·r⁴ + k6·r⁶``,
#: not nerfstudio's k4) must be zero. Any other model (``FOV``, ``THIN_PRISM_FISHEYE``, ...) is refused.
COLMAP_PARAMS = {
    "SIMPLE_PINHOLE": ("f", "cx", "cy"),
    "PINHOLE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL": ("f", "cx", "cy", "k1"),
    "RADIAL": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
    "FULL_OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "rational k4", "k5", "k6"),
    "OPENCV_FISHEYE": ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"),
    "SIMPLE_RADIAL_FISHEYE": ("f", "cx", "cy", "k1"),
    "RADIAL_FISHEYE": ("f", "cx", "cy", "k1", "k2"),
    "SIMPLE_FISHEYE": ("f", "cx", "cy"),
    "FISHEYE": ("fx", "fy", "cx", "cy"),
}
#: FULL_OPENCV's parameters that no :class:`Distortion` holds
_RATIONAL = ("rational k4", "k5", "k6")


def colmap_camera(model: str, params: list[float]) -> tuple[tuple[float, ...], Distortion | None]:
    """``(fl_x, fl_y, cx, cy)`` and the lens (None: none) of a COLMAP camera ``model`` and its ``params``
    (:data:`COLMAP_PARAMS`); the focal lengths and principal point are not checked here. A radial-tangential
    model whose terms are all zero is None (:attr:`Distortion.is_pinhole`); a fisheye model never is, its
    terms zero or not (equidistant: ``r_d = θ``).

    Raises:
        InputError: naming ``camera_model`` for a model not in :data:`COLMAP_PARAMS` (its terms would be
            dropped), the wrong number of parameters, or non-zero ``FULL_OPENCV`` rational terms; naming the
            term for one that is not finite.
    """
    names = COLMAP_PARAMS.get(model)
    if names is None:
        known = ", ".join(COLMAP_PARAMS)
        raise InputError(
            f"camera_model {model} is not supported (its lens terms cannot be applied); supported: {known}",
            param="camera_model",
        )
    if len(params) != len(names):
        raise InputError(
            f"camera_model {model} has {len(names)} parameters ({', '.join(names)}), found {len(params)}",
            param="camera_model",
        )
    given = dict(zip(names, params, strict=True))
    rational = {n: given[n] for n in _RATIONAL if given.get(n, 0.0) != 0.0}
    if rational:
        found = ", ".join(f"{n} = {v:g}" for n, v in rational.items())
        raise InputError(
            f"camera_model {model}: its rational terms (the divisor 1 + k4·r² + k5·r⁴ + k6·r⁶) are not "
            f"supported, found {found}; calibrate with OPENCV (or RADIAL) instead",
            param="camera_model",
        )
    fx = given.get("f", given.get("fx"))
    fy = given.get("f", given.get("fy"))
    pinhole = (float(fx), float(fy), float(given["cx"]), float(given["cy"]))  # type: ignore[arg-type]
    terms = {n: given[n] for n in TERMS if n in given}
    fisheye = "FISHEYE" in model
    lens = Distortion("OPENCV_FISHEYE" if fisheye else "OPENCV", **terms)
    return pinhole, None if lens.is_pinhole else lens
