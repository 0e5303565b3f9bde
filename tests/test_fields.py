"""Grid and MLP fields: shapes, upsampling, checkpoints, occupancy skipping, and that they can fit."""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Iterator
from dataclasses import replace

import numpy as np
import pytest
import torch

from spikenerf.core.errors import InputError
from spikenerf.data.rays import pixel_rays, ray_box_bounds
from spikenerf.fields import Field, GridFieldConfig, MLPFieldConfig, build_field, field_config
from spikenerf.fields.encoding import encoded_size, positional_encoding
from spikenerf.fields.grid import FACTORS
from spikenerf.fields.vm_sample import sample_vm
from spikenerf.render import build_model, render_image
from spikenerf.scenes.poses import look_at
from spikenerf.scenes.trajectory import Intrinsics

BOX = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])


@pytest.fixture(autouse=True, scope="module")
def _one_thread() -> Iterator[None]:
    """Tiny tensors: threading only adds overhead (and stalls badly on a busy machine)."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


CFG = GridFieldConfig(
    n_voxels_init=16**3,
    n_voxels_final=28**3,
    upsample_steps=(10,),
    density_components=4,
    app_components=6,
    app_dim=9,
    hidden=16,
    occupancy=False,
)


def smooth_field(cfg: GridFieldConfig = CFG, channels: int = 3):
    """A grid field whose factors are low-frequency sinusoids (so bilinear resampling is nearly exact)."""
    field = build_field("grid", channels, BOX, cfg)
    r = field.resolution
    u = torch.linspace(-1, 1, r)
    with torch.no_grad():
        for planes, lines in (
            (field.density_planes, field.density_lines),
            (field.app_planes, field.app_lines),
        ):
            c = planes.shape[1]
            k = 0.3 * torch.arange(1, c + 1, dtype=torch.float32)[:, None, None]
            planes.copy_((torch.sin(k * u[None, :, None] + 0.5 * u[None, None, :]) * 2.0).expand_as(planes))
            lines.copy_(torch.cos(0.7 * k * u[None, :, None]).expand_as(lines))
    return field


def test_positional_encoding_width() -> None:
    x = torch.rand(5, 3)
    assert positional_encoding(x, 10).shape == (5, encoded_size(3, 10)) == (5, 63)
    assert positional_encoding(x, 4).shape == (5, 27)


@pytest.mark.parametrize("kind", ["grid", "mlp"])
@pytest.mark.parametrize("channels", [1, 3])
def test_forward_shapes_and_ranges(kind: str, channels: int) -> None:
    config = CFG if kind == "grid" else MLPFieldConfig.tiny()
    field = build_field(kind, channels, BOX, config)
    xyz, dirs = torch.rand(37, 3) * 2 - 1, torch.nn.functional.normalize(torch.randn(37, 3), dim=-1)
    sigma, color = field(xyz, dirs)
    assert sigma.shape == (37,) and color.shape == (37, channels)
    assert (sigma >= 0).all() and (color >= 0).all() and (color <= 1).all()


@pytest.mark.parametrize("kind", ["grid", "mlp"])
def test_fields_share_the_base_box_and_groups(kind: str) -> None:
    """Both fields are a :class:`Field`: box normalisation and inverse, every parameter in exactly one Adam
    group, and the state-dict keys of old checkpoints (the base class must not rename or add any)."""
    box = torch.tensor([[-1.0, 0.0, 2.0], [3.0, 1.0, 2.5]])  # not a cube
    field = build_field(kind, 3, box, CFG if kind == "grid" else MLPFieldConfig.tiny())
    assert isinstance(field, Field) and field.channels == 3
    torch.testing.assert_close(field.normalize(box), torch.tensor([[-1.0] * 3, [1.0] * 3]))
    x = torch.rand(9, 3) * 2 - 1
    torch.testing.assert_close(field.normalize(field.denormalize(x)), x)
    grouped = [id(p) for g in field.param_groups(1e-3) for p in g["params"]]
    assert sorted(grouped) == sorted(id(p) for p in field.parameters()) and len(set(grouped)) == len(grouped)
    keys = list(field.state_dict())
    if kind == "grid":
        assert keys[:6] == [*FACTORS, "scene_box", "occupancy_step"] and keys[-2:] == [
            "occupancy.grid",
            "occupancy.bounds",
        ]
    else:
        assert keys[0] == "scene_box" and all(k.startswith(("coarse.", "fine.")) for k in keys[1:])


def test_paper_mlp_config_is_recorded() -> None:
    c = MLPFieldConfig()
    assert (c.depth, c.width, c.skip, c.xyz_freqs, c.dir_freqs, c.n_coarse, c.n_fine) == (
        8,
        256,
        4,
        10,
        4,
        64,
        128,
    )
    assert (c.lr, c.lr_final) == (5e-4, 5e-5)
    field = build_field("mlp", 3, BOX, c)
    assert field.fine.trunk[5].in_features == 256 + 63 and field.fine.head.in_features == 256 + 27


def test_config_from_dict_schedules_and_errors() -> None:
    cfg = field_config("grid", {"upsample_steps": [100, 200], "n_voxels_init": 4096})
    assert cfg.upsample_steps == (100, 200) and cfg.resolutions()[0] == 16
    assert cfg.resolution_at(0) == 16 and cfg.resolution_at(99) == 16 and cfg.resolution_at(200) == 200
    scaled = GridFieldConfig().for_iterations(6000)
    assert scaled.upsample_steps == tuple(2 * k for k in GridFieldConfig().upsample_steps)
    with pytest.raises(InputError):
        field_config("grid", {"n_voxel": 3})


def test_upsampling_keeps_the_function_approximately() -> None:
    field = smooth_field()
    xyz = torch.rand(500, 3) * 1.8 - 0.9
    dirs = torch.nn.functional.normalize(torch.randn(500, 3), dim=-1)

    def features() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        with torch.no_grad():
            raw = sample_vm(field.density_planes, field.density_lines, xyz).sum(dim=(0, 1))
            return raw, sample_vm(field.app_planes, field.app_lines, xyz), field(xyz, dirs)[1]

    raw0, app0, color0 = features()
    field.upsample(28)
    assert field.density_planes.shape[-2:] == (28, 28) and field.app_lines.shape[-2:] == (28, 1)
    raw1, app1, color1 = features()
    # bilinear resampling with aligned corners: well under the 1.5 % / 3.5 % a half-texel shift would give
    assert (raw1 - raw0).abs().max() / raw0.abs().max() < 0.005
    assert (app1 - app0).abs().max() / app0.abs().max() < 0.02
    assert (color1 - color0).abs().max() < 0.01


def test_resized_names_the_dimensions_that_upsampling_changes() -> None:
    field = build_field("grid", 1, BOX, replace(CFG, occupancy_max_resolution=20))
    names = [*FACTORS, "occupancy"]
    before = [getattr(field, n) for n in FACTORS] + [field.occupancy.grid]
    resized = field.resized()  # all five: the occupancy grid grows from 16 to 20
    assert len(resized) == 5 and all(t is b for (t, _), b in zip(resized, before, strict=True))
    field.upsample(28)
    after = [getattr(field, n) for n in FACTORS] + [field.occupancy.grid]
    for name, (old, dims), new in zip(names, resized, after, strict=True):
        changed = tuple(i for i, (a, b) in enumerate(zip(old.shape, new.shape, strict=True)) if a != b)
        assert changed == dims, name
    assert field.resized() == []  # at the last resolution, the occupancy grid at its largest


def test_state_dict_round_trip_after_upsampling() -> None:
    model = build_model("grid", 3, BOX, CFG)
    assert model.on_step(9) is False
    assert model.on_step(10) is True and model.field.resolution == 28
    assert model.on_step(10) is False  # idempotent
    groups = model.param_groups()
    assert groups[0]["name"] == "grid" and groups[0]["lr"] > groups[1]["lr"]
    assert groups[0]["params"][0] is model.field.density_planes  # the new tensors
    torch.optim.Adam(groups)

    fresh = build_model("grid", 3, BOX, CFG)
    assert fresh.field.resolution == 16
    fresh.load_state_dict(model.state_dict())
    assert fresh.field.resolution == 28
    pose = look_at(np.array([2.5, 1.0, 1.5]), np.zeros(3))
    intr = Intrinsics.from_fov(9, 7, 0.7)
    assert torch.equal(render_image(fresh, pose, intr).color, render_image(model, pose, intr).color)
    for f in (model.field, fresh.field):  # channels-last after upsampling and after loading a bigger grid
        assert all(_channels_last(getattr(f, n)) for n in FACTORS)


def _channels_last(t: torch.Tensor) -> bool:
    return t.is_contiguous(memory_format=torch.channels_last) and not t.is_contiguous()


def test_grid_factors_are_stored_channels_last_and_take_gradients_without_a_copy() -> None:
    from spikenerf.fields import vm_kernel

    field = build_field("grid", 1, BOX, CFG)
    assert all(_channels_last(getattr(field, n)) for n in FACTORS)
    if not vm_kernel.available():
        pytest.skip("no C++ compiler for the fused VM kernel")
    xyz = torch.rand(300, 3) * 2 - 1
    field.density_norm(xyz).sum().backward()
    for name in ("density_planes", "density_lines"):
        p = getattr(field, name)
        big = [d for d in range(p.dim()) if p.shape[d] > 1]  # a size-1 dimension's stride is arbitrary
        assert [p.grad.stride(d) for d in big] == [p.stride(d) for d in big]  # the kernel's own layout


def cube_model(channels: int = 3):
    """A 'fitted toy': an opaque cube |x|, |y|, |z| < 0.4 with a view-dependent colour, empty elsewhere."""
    cfg = GridFieldConfig(n_voxels_init=32**3, n_voxels_final=32**3, upsample_steps=(), occupancy_start=1)
    torch.manual_seed(
        0
    )  # the decoder's weights and the occupancy grid's jittered points: not the test order's
    model = build_model("grid", channels, BOX, cfg)
    f = model.field
    with torch.no_grad():
        ind = (torch.linspace(-1, 1, f.resolution).abs() < 0.4).float()
        f.density_planes.zero_()
        f.density_lines.zero_()
        f.density_planes[0, 0] = ind[:, None] * ind[None, :]
        f.density_lines[0, 0, :, 0] = 40.0 * ind
        f.density_planes[0, 1] = 1.0  # raw −20 everywhere: no softplus haze outside the cube
        f.density_lines[0, 1] = -20.0
    return model


def test_occupancy_skips_empty_space_without_changing_the_image() -> None:
    model = cube_model()
    pose = look_at(np.array([2.0, -2.2, 1.3]), np.zeros(3))
    intr = Intrinsics.from_fov(24, 20, 0.9)
    model.use_occupancy = True
    before = render_image(model, pose, intr).color  # occupancy not built yet: all cells occupied
    assert model.on_step(1) is False  # occupancy_start = 1 → built now
    assert model.field.occupancy.occupied_fraction() < 0.25
    o, d = pixel_rays(
        torch.as_tensor(pose, dtype=torch.float32), intr, torch.tensor([[x, 10] for x in range(24)])
    )
    near, far = ray_box_bounds(o, d, BOX)
    with torch.no_grad():
        model.use_occupancy = False
        full = model.render_rays(o, d, near, far)
        model.use_occupancy = True
        skip = model.render_rays(o, d, near, far)
    assert skip.num_samples < 0.3 * full.num_samples
    assert torch.allclose(skip.color, full.color, atol=1e-5)
    assert torch.allclose(skip.depth, full.depth, atol=1e-4)
    after = render_image(model, pose, intr).color
    assert (before - after).abs().max() < 1e-5
    assert (after < 0.99).any() and (after > 0.999).any()  # the image shows the cube and the background


def _sphere_rays(n_views: int = 8, size: int = 16) -> tuple[torch.Tensor, ...]:
    """Rays of a few views of a shaded sphere (radius 0.5) on white and their target colours."""
    intr = Intrinsics.from_fov(size, size, 0.8)
    origins, dirs = [], []
    for i in range(n_views):
        az = 2 * math.pi * i / n_views
        eye = np.array([3.0 * math.cos(az), 3.0 * math.sin(az), 1.0 + 0.5 * (i % 2)])
        ys, xs = torch.meshgrid(torch.arange(size), torch.arange(size), indexing="ij")
        pix = torch.stack([xs.reshape(-1), ys.reshape(-1)], -1)
        o, d = pixel_rays(torch.as_tensor(look_at(eye, np.zeros(3)), dtype=torch.float32), intr, pix)
        origins.append(o)
        dirs.append(d)
    o, d = torch.cat(origins), torch.cat(dirs)
    b = (o * d).sum(-1)
    disc = b**2 - ((o * o).sum(-1) - 0.25)
    hit = disc > 0
    t_hit = -b - disc.clamp_min(0).sqrt()
    normal = torch.nn.functional.normalize(o + t_hit[:, None] * d, dim=-1)
    shade = torch.stack(
        [0.2 + 0.6 * (normal[:, 2] + 1) / 2, 0.3 + 0.2 * normal[:, 0], 0.5 * (normal[:, 1] + 1)], -1
    )
    target = torch.where(hit[:, None], shade, torch.ones_like(shade))
    return (o, d, *ray_box_bounds(o, d, BOX), target)


@pytest.mark.parametrize("kind", ["grid", "mlp"])
def test_tiny_fit_lowers_the_loss(kind: str) -> None:
    torch.manual_seed(0)
    o, d, near, far, target = _sphere_rays(8, 12)
    if kind == "grid":
        cfg = replace(CFG, n_voxels_final=24**3, upsample_steps=(60,), occupancy=True, occupancy_start=40)
        model, lr = build_model("grid", 3, BOX, replace(cfg, occupancy_every=40, app_components=8)), None
    else:
        model, lr = build_model("mlp", 3, BOX, MLPFieldConfig.tiny()), 5e-3

    def loss_all() -> float:
        with torch.no_grad():
            return float(((model.render_rays(o, d, near, far).color - target) ** 2).mean())

    initial = loss_all()
    opt = torch.optim.Adam(model.param_groups(lr))
    for step in range(1, 101):
        idx = torch.randint(0, len(o), (128,))
        out = model.render_rays(o[idx], d[idx], near[idx], far[idx], perturb=True)
        loss = ((out.color - target[idx]) ** 2).mean()
        if out.coarse_color is not None:
            loss = loss + ((out.coarse_color - target[idx]) ** 2).mean()
        opt.zero_grad()
        (loss + model.regularization()).backward()
        opt.step()
        if model.on_step(step):
            opt = torch.optim.Adam(model.param_groups(lr))
    final = loss_all()
    assert final < 0.3 * initial, (initial, final)
    if kind == "grid":
        assert model.field.resolution == 24 and 0.0 < model.field.occupancy.occupied_fraction() < 1.0


def test_total_variation_values_and_gradient() -> None:
    """Mean squared neighbour difference along H and W (lines: H only); 0 on a constant; exact gradient."""
    from spikenerf.fields.grid import total_variation

    assert float(total_variation(torch.full((3, 2, 5, 5), 0.7))) == 0.0
    ramp = torch.arange(6.0)[:, None].expand(6, 4)[None, None].expand(3, 2, 6, 4)  # +1 along H, flat along W
    assert float(total_variation(ramp)) == pytest.approx(1.0)
    assert float(total_variation(2 * ramp[..., :1])) == pytest.approx(4.0)  # a line: H only
    x = torch.randn(3, 2, 5, 4, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(total_variation, (x,))
    line = torch.randn(3, 2, 5, 1, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(total_variation, (line,))


def test_tv_prior_is_weighted_and_runs_every_tv_every_steps() -> None:
    """regularization(step): 0 without weights; with them, tv_every × weight × TV at multiples of tv_every
    and 0 between (step None: every call, unscaled); the prior smooths the factors it is applied to."""
    from spikenerf.fields.grid import total_variation

    field = build_field("grid", 1, BOX, CFG)
    assert float(field.regularization(0)) == 0.0
    cfg = replace(CFG, tv_app=0.5, tv_density=0.25, tv_every=3)
    field = build_field("grid", 1, BOX, cfg)
    tv_d = total_variation(field.density_planes) + total_variation(field.density_lines)
    tv_a = total_variation(field.app_planes) + total_variation(field.app_lines)
    expected = 0.25 * tv_d.item() + 0.5 * tv_a.item()
    assert float(field.regularization()) == pytest.approx(expected)
    assert float(field.regularization(6)) == pytest.approx(3 * expected)
    assert float(field.regularization(7)) == 0.0
    only_app = build_field("grid", 1, BOX, replace(CFG, tv_app=1.0, tv_every=1))
    only_app.regularization(5).backward()
    assert only_app.density_planes.grad is None and only_app.app_planes.grad is not None
    opt = torch.optim.Adam(only_app.parameters(), lr=0.02)
    before = float(total_variation(only_app.app_planes))
    for step in range(20):
        opt.zero_grad()
        only_app.regularization(step).backward()
        opt.step()
    assert float(total_variation(only_app.app_planes)) < 0.5 * before


def test_occupancy_update_never_empties_the_grid() -> None:
    from spikenerf.fields.occupancy import OccupancyGrid

    occ = OccupancyGrid(8)
    assert occ.update(lambda x: torch.zeros(len(x)), step_size=0.1) == 1.0  # an untrained field: refused
    blob = occ.update(lambda x: 100.0 * (x.norm(dim=-1) < 0.3).float(), step_size=0.1, dilation=0)
    assert 0.0 < blob < 0.1 and occ.query(torch.zeros(1, 3)).item()
    assert occ.update(lambda x: torch.zeros(len(x)), step_size=0.1) == blob  # keeps the last useful grid
    assert torch.all(occ.bounds.abs() < 0.6)
    addresses = occ.grid.data_ptr(), occ.bounds.data_ptr()
    occ.update(lambda x: 100.0 * (x.norm(dim=-1) < 0.6).float(), step_size=0.1, dilation=0)
    assert (occ.grid.data_ptr(), occ.bounds.data_ptr()) == addresses  # in place: a CUDA graph reads it
    assert occ.occupied_fraction() > blob


def test_decoder_bf16_is_close_to_float32_forward_and_backward(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """``decoder_bf16`` changes only the decoder's precision: colours and gradients stay close to float32.
    Runs on every CPU: bf16 autocast is emulated where it is not native (the check is pretended true)."""
    from spikenerf.fields import grid

    monkeypatch.setattr(grid, "cpu_has", lambda *flags: True)
    torch.manual_seed(0)
    ref = smooth_field(replace(CFG, hidden=32, decoder_bf16=False))
    low = smooth_field(replace(CFG, hidden=32, decoder_bf16=True))
    low.load_state_dict(ref.state_dict())
    xyz, dirs = torch.rand(500, 3) * 2 - 1, torch.nn.functional.normalize(torch.randn(500, 3), dim=-1)
    outs = []
    for field in (ref, low):
        rgb = field.color_norm(xyz, dirs)
        (rgb * torch.linspace(0, 1, rgb.numel()).view_as(rgb)).sum().backward()
        outs.append((rgb, field.app_planes.grad, field.decoder[0].weight.grad))
    assert outs[0][0].dtype == outs[1][0].dtype == torch.float32
    assert not torch.equal(outs[0][0], outs[1][0])  # really another precision
    for a, b in zip(outs[0], outs[1], strict=True):  # bf16 keeps 8 bits: a few % on the grid's gradient
        assert ((a - b).norm() / a.norm()).item() < 0.06


def test_float32_decoder_keeps_an_outer_autocast() -> None:
    """Without ``decoder_bf16`` the field adds no autocast of its own (``--amp bf16`` still applies)."""
    field = smooth_field(replace(CFG, decoder_bf16=False))
    xyz, dirs = torch.rand(50, 3) * 2 - 1, torch.nn.functional.normalize(torch.randn(50, 3), dim=-1)
    ref = field.color_norm(xyz, dirs)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        amp = field.color_norm(xyz, dirs)
    assert not torch.equal(ref, amp.float())
    assert torch.allclose(ref, amp.float(), atol=0.02)


def test_decoder_bf16_only_where_the_device_has_native_bf16(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """On a CPU without AVX512-BF16/AMX the default decoder stays float32 (emulated bf16 would be slower)."""
    from spikenerf.fields import grid

    field = smooth_field(replace(CFG, decoder_bf16=True))
    xyz, dirs = torch.rand(50, 3) * 2 - 1, torch.nn.functional.normalize(torch.randn(50, 3), dim=-1)
    monkeypatch.setattr(grid, "cpu_has", lambda *flags: False)
    plain = field.color_norm(xyz, dirs)
    with torch.no_grad():
        field.config = replace(field.config, decoder_bf16=False)
        assert torch.equal(plain, field.color_norm(xyz, dirs))
    monkeypatch.setattr(grid, "cpu_has", lambda *flags: "avx512_bf16" in flags)
    field.config = replace(field.config, decoder_bf16=True)
    assert not torch.equal(plain, field.color_norm(xyz, dirs))


def test_a_checkpoint_from_before_decoder_bf16_keeps_a_float32_decoder() -> None:
    from spikenerf.render import model_from_hparams

    hparams = build_model("grid", 1, BOX, CFG).hparams()
    assert model_from_hparams(hparams).field.config.decoder_bf16  # today's default, stored
    del hparams["config"]["decoder_bf16"]
    assert not model_from_hparams(hparams).field.config.decoder_bf16


def test_every_field_kind_is_one_registry_entry_read_by_every_dispatch_site() -> None:
    """Each ``FieldKind`` name has exactly one FIELD_REGISTRY entry (and one render model); building,
    config parsing, the memory estimates and the CLI choices read the registry."""
    import typing

    from spikenerf.cli.benchmark import command as benchmark
    from spikenerf.cli.train import command as train
    from spikenerf.fields import FIELD_KINDS, FIELD_REGISTRY, FieldKind, field_memory
    from spikenerf.fields.memory import ray_bytes
    from spikenerf.render.model import MODELS, build_model

    assert tuple(FIELD_REGISTRY) == FIELD_KINDS == typing.get_args(FieldKind) and set(MODELS) == set(
        FIELD_KINDS
    )
    for command in (train, benchmark):
        option = next(p for p in command.params if p.name in ("field", "field_kind"))
        assert tuple(option.type.choices) == FIELD_KINDS  # type: ignore[attr-defined]
    for kind, entry in FIELD_REGISTRY.items():
        cfg = (
            GridFieldConfig(n_voxels_init=8**3, n_voxels_final=8**3)
            if kind == "grid"
            else MLPFieldConfig.tiny()
        )
        assert isinstance(field_config(kind, dataclasses.asdict(cfg)), entry.config)
        assert type(build_field(kind, 1, BOX, cfg)) is entry.field
        assert build_model(kind, 1, BOX, cfg).kind == kind
        assert min(field_memory(kind, cfg)) > 0 and ray_bytes(kind, cfg) > 0


def test_field_configs_are_checked_by_the_one_config_validator() -> None:
    """Types, finiteness and BOUNDS (spikenerf.core.config), as for TrainConfig: errors name the key."""
    assert field_config("mlp", {"lr": 1}).lr == 1.0 and isinstance(field_config("mlp", {"lr": 1}).lr, float)
    assert field_config("grid", {"lr": "2e-2"}).lr == 2e-2
    for kind, entry, words in [
        ("grid", {"lr": -1.0}, "field_config.lr must be a finite number > 0"),
        ("grid", {"lr_final_ratio": 2.0}, "field_config.lr_final_ratio must be a finite number in (0, 1]"),
        ("grid", {"n_voxels_init": 4}, "field_config.n_voxels_init must be ≥ 8"),
        ("grid", {"upsample_steps": [1, -2]}, "field_config.upsample_steps must be a list of integers ≥ 0"),
        ("grid", {"occupancy": 1}, "field_config.occupancy must be true or false"),
        ("grid", {"hidden": 1.5}, "field_config.hidden must be an integer"),
        ("mlp", {"raw_noise_std": float("nan")}, "field_config.raw_noise_std must be a finite number"),
        ("mlp", {"depth": 0}, "field_config.depth must be > 0"),
        ("grid", {"tv_app": -0.1}, "field_config.tv_app must be a finite number ≥ 0"),
        ("grid", {"tv_density": float("inf")}, "field_config.tv_density must be a finite number"),
        ("grid", {"tv_every": 0}, "field_config.tv_every must be ≥ 1"),
    ]:
        with pytest.raises(InputError, match=re.escape(words)):
            field_config(kind, entry)
    assert field_config("grid", {"density_shift": -30.0}).density_shift == -30.0


@pytest.mark.parametrize("resolution", [5, 128])
def test_occupancy_cells_are_the_flat_index_of_the_truncated_coordinates(resolution: int) -> None:
    from spikenerf.fields.occupancy import OccupancyGrid

    occ = OccupancyGrid(resolution)
    gen = torch.Generator().manual_seed(4)
    xyz = torch.rand(5000, 3, generator=gen) * 2.6 - 1.3  # some outside: the nearest cell
    xyz[:4] = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0], [-1.0, 1.0, 0.999]])
    ijk = ((xyz + 1.0) * (0.5 * resolution)).long().clamp(0, resolution - 1)  # the int64 formula
    want = (ijk[:, 0] * resolution + ijk[:, 1]) * resolution + ijk[:, 2]
    got = occ.cell_index(xyz)
    assert got.dtype == torch.int64 and torch.equal(got, want)
    occ.grid.view(-1)[want[::2]] = False
    assert torch.equal(occ.lookup(xyz), occ.grid.view(-1)[want])


def test_a_config_holding_the_removed_batch_rays_still_loads() -> None:
    """``batch_rays`` was never read (a step's rays are train's ``batch``); checkpoints that hold it load."""
    assert field_config("grid", {"batch_rays": 4096, "tv_app": 0.5}) == field_config("grid", {"tv_app": 0.5})
    assert field_config("mlp", {"batch_rays": 1024}) == field_config("mlp")
    assert not hasattr(field_config("grid"), "batch_rays")


@pytest.mark.parametrize(
    ("box", "problem"),
    [
        (np.array([[-1, 1], [-1, 1], [-1, 1]]), r"\(2, 3\) \[min, max\] corners, found shape \(3, 2\)"),
        (np.array([[1, 1, 1], [-1, -1, -1]]), "max > min on every axis"),  # inverted: rendered nothing
        (np.zeros((2, 3)), "max > min on every axis"),
        (np.array([[-1, -1, np.nan], [1, 1, 1]]), "finite"),
    ],
)
def test_a_field_refuses_a_scene_box_that_is_not_min_max_corners(box: np.ndarray, problem: str) -> None:
    """A (3, 2) box was reshaped into other corners, an inverted or flat one rendered nothing."""
    from spikenerf.render import build_model

    for kind in ("grid", "mlp"):
        with pytest.raises(InputError, match=problem) as err:
            build_model(kind, 1, box)
        assert err.value.params == ("scene_box",)
    assert build_model("grid", 1, np.array([[-1, -2, -3], [1, 2, 3]])).scene_box.tolist() == [
        [-1, -2, -3],
        [1, 2, 3],
    ]
