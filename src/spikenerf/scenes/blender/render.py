"""Cycles setup, the default light, the camera and one linear frame out of ``bpy`` (needs ``bpy``).

Pixels leave Blender through a 32-bit uncompressed EXR in a private temporary folder, read back with
``bpy.data.images.load`` + ``pixels.foreach_get`` (≈ 4 ms for 200 × 200 here). The compositor's Viewer
node is not evaluated by the ``bpy`` module in background mode in Blender 5.0, and ``Render Result`` has no
readable pixels, so the EXR round trip is the robust path.
"""

from __future__ import annotations

import math
import shutil
import tempfile
import weakref
from dataclasses import dataclass
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix, Vector

from spikenerf.core.errors import InputError, check_choice
from spikenerf.scenes.blender._bpy import quiet
from spikenerf.scenes.blender.catalog import (
    DEFAULT_CAMERA_ANGLE_X,
    DEFAULT_SIZE,
    DEFAULT_SPP,
    SUN_DIRECTION,
    SUN_LIGHT,
    WORLD_LIGHT,
)

GEOMETRY_TYPES = {"MESH", "CURVE", "SURFACE", "META", "FONT", "CURVES", "POINTCLOUD", "VOLUME"}
DENOISE_LEVELS = ("NONE", "FAST", "BALANCED", "HIGH")
CAMERA_NAME = "spikenerf_camera"


@dataclass(frozen=True)
class RenderSettings:
    """How Cycles renders each frame.

    Attributes:
        width, height: frame size in pixels.
        camera_angle_x: horizontal field of view, radians (sensor fit horizontal, principal point centred).
        spp: samples per pixel (adaptive sampling may stop earlier where a pixel has converged).
        seed: Cycles' sampling seed (the same for every frame).
        denoise: OpenImageDenoise quality ``FAST`` | ``BALANCED`` | ``HIGH`` or ``NONE``. ``FAST`` also uses
            the fast prefilter, the others the accurate one.
        max_bounces: total light bounces (diffuse 2, glossy 3, transmission 4, transparent 8 at most).
        device: ``auto`` (a GPU when Cycles sees one, else CPU), ``cpu`` or ``gpu``.
    """

    width: int = DEFAULT_SIZE
    height: int = DEFAULT_SIZE
    camera_angle_x: float = DEFAULT_CAMERA_ANGLE_X
    spp: int = DEFAULT_SPP
    seed: int = 0
    denoise: str = "FAST"
    max_bounces: int = 4
    device: str = "auto"

    def __post_init__(self) -> None:
        if self.width < 1 or self.height < 1:
            raise InputError(f"render size must be positive, got {self.width}x{self.height}")
        if self.spp < 1:
            raise InputError(f"spp must be ≥ 1, got {self.spp}")
        check_choice(self.denoise, DENOISE_LEVELS, "denoise")
        check_choice(self.device, ("auto", "cpu", "gpu"), "device")
        if not 0 < self.camera_angle_x < math.pi:
            raise InputError(f"camera_angle_x must be in (0, π) radians, got {self.camera_angle_x}")


_GPU_TYPE: list[str | None] = []  # cached probe result: [] = not probed, [None] = no GPU


def gpu_device_type() -> str | None:
    """The first Cycles compute backend with a GPU device (OPTIX, CUDA, HIP, ONEAPI), or None."""
    if _GPU_TYPE:
        return _GPU_TYPE[0]
    found = None
    prefs = bpy.context.preferences.addons["cycles"].preferences
    with quiet(stderr=True):  # the probe logs failed driver loads on stderr
        for kind in ("OPTIX", "CUDA", "HIP", "ONEAPI"):
            try:
                prefs.compute_device_type = kind
                prefs.get_devices()
            except (TypeError, RuntimeError):
                continue
            if any(d.type != "CPU" for d in prefs.devices):
                found = kind
                break
    _GPU_TYPE.append(found)
    return found


def configure(scene: bpy.types.Scene, settings: RenderSettings) -> str:
    """Set Cycles, colour management, film and output of ``scene`` for linear frames; return the device.

    Returns:
        ``"CPU"`` or the GPU backend name used.
    """
    render, cycles = scene.render, scene.cycles
    render.engine = "CYCLES"
    gpu = gpu_device_type() if settings.device in ("auto", "gpu") else None
    if settings.device == "gpu" and gpu is None:
        raise InputError("device 'gpu' was asked for, but Cycles sees no GPU (use auto or cpu)")
    if gpu is not None:
        prefs = bpy.context.preferences.addons["cycles"].preferences
        prefs.compute_device_type = gpu
        prefs.get_devices()
        for dev in prefs.devices:
            dev.use = dev.type != "CPU"
    cycles.device = "GPU" if gpu else "CPU"
    render.threads_mode = "AUTO"  # all cores
    render.use_persistent_data = True  # sync the scene once, then only the camera moves
    render.resolution_x, render.resolution_y, render.resolution_percentage = (
        settings.width,
        settings.height,
        100,
    )
    render.pixel_aspect_x = render.pixel_aspect_y = 1.0
    render.film_transparent = True  # alpha → composited on white in numpy
    render.use_motion_blur = False
    render.use_compositing = False
    render.use_sequencer = False
    cycles.samples = settings.spp
    cycles.use_adaptive_sampling = True
    cycles.adaptive_threshold = 0.01
    cycles.seed = settings.seed
    cycles.use_animated_seed = False
    cycles.use_denoising = settings.denoise != "NONE"
    if cycles.use_denoising:
        cycles.denoiser = "OPENIMAGEDENOISE"
        cycles.denoising_quality = settings.denoise
        cycles.denoising_prefilter = "FAST" if settings.denoise == "FAST" else "ACCURATE"
        cycles.denoising_input_passes = "RGB_ALBEDO_NORMAL"
    cycles.max_bounces = settings.max_bounces
    cycles.diffuse_bounces = min(2, settings.max_bounces)
    cycles.glossy_bounces = min(3, settings.max_bounces)
    cycles.transmission_bounces = min(4, settings.max_bounces)
    cycles.transparent_max_bounces = 8
    cycles.volume_bounces = 0
    cycles.caustics_reflective = cycles.caustics_refractive = False
    cycles.blur_glossy = 1.0  # filter glossy: fewer fireflies at 16 spp
    view = scene.view_settings
    view.view_transform = "Standard"
    view.look = "None"
    view.exposure = 0.0
    view.gamma = 1.0
    fmt = render.image_settings
    fmt.file_format = "OPEN_EXR"
    fmt.color_mode = "RGBA"
    fmt.color_depth = "32"
    fmt.exr_codec = "NONE"
    return gpu if gpu else cycles.device


def add_default_light(scene: bpy.types.Scene) -> None:
    """Add the default sun and uniform white world so that a white diffuse plane facing the sun renders 1.0.

    Cycles' sun strength is irradiance; a white Lambertian surface reflects ``strength / π``, and a uniform
    world of strength ``w`` adds ``w`` on a surface that sees the whole sky: ``π·SUN_LIGHT / π + WORLD_LIGHT
    = 0.8 + 0.2 = 1.0``.
    """
    data = bpy.data.lights.new("spikenerf_sun", type="SUN")
    data.energy = math.pi * SUN_LIGHT
    data.angle = math.radians(3.0)  # slightly soft shadows
    sun = bpy.data.objects.new("spikenerf_sun", data)
    sun.rotation_mode = "QUATERNION"
    sun.rotation_quaternion = Vector(SUN_DIRECTION).to_track_quat("Z", "Y")  # light shines along local −Z
    scene.collection.objects.link(sun)
    world = bpy.data.worlds.new("spikenerf_world")
    background = world.node_tree.nodes["Background"]
    background.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    background.inputs["Strength"].default_value = WORLD_LIGHT
    scene.world = world


def renders(obj: bpy.types.Object) -> bool:
    """True when ``obj`` is enabled for rendering (itself and the collections holding it)."""
    return not obj.hide_render and not any(c.hide_render for c in obj.users_collection)


def has_lights(scene: bpy.types.Scene) -> bool:
    """True when the active view layer has a light object that renders."""
    return any(o.type == "LIGHT" and renders(o) for o in bpy.context.view_layer.objects)


def remove_cameras(scene: bpy.types.Scene) -> None:
    """Delete every camera object of ``scene`` (the trajectory provides the camera)."""
    for obj in [o for o in scene.objects if o.type == "CAMERA"]:
        bpy.data.objects.remove(obj, do_unlink=True)
    bpy.context.view_layer.update()  # refresh the view layer's object list


def geometry_box(scene: bpy.types.Scene) -> np.ndarray:
    """(2, 3) world-space bounds of the geometry that renders (evaluated, modifiers applied)."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    corners = []
    for obj in bpy.context.view_layer.objects:
        if obj.type not in GEOMETRY_TYPES or not renders(obj):
            continue
        evaluated = obj.evaluated_get(depsgraph)
        m = np.array(evaluated.matrix_world)
        local = np.array([tuple(c) for c in evaluated.bound_box], dtype=np.float64)
        corners.append(local @ m[:3, :3].T + m[:3, 3])
    if not corners:
        raise InputError("the scene has no visible geometry to render (meshes, curves, …)")
    pts = np.concatenate(corners)
    return np.stack([pts.min(0), pts.max(0)])


class FrameRenderer:
    """Renders linear RGB frames of the current ``bpy`` scene from camera-to-world poses."""

    def __init__(self, settings: RenderSettings) -> None:
        self.settings = settings
        self.scene = bpy.context.scene
        self.device = configure(self.scene, settings)
        cam = bpy.data.objects.get(CAMERA_NAME)
        if cam is None:
            cam = bpy.data.objects.new(CAMERA_NAME, bpy.data.cameras.new(CAMERA_NAME))
            self.scene.collection.objects.link(cam)
        cam.data.sensor_fit = "HORIZONTAL"
        cam.data.angle_x = settings.camera_angle_x
        cam.data.shift_x = cam.data.shift_y = 0.0
        cam.data.clip_start, cam.data.clip_end = 1e-3, 1e5
        self.camera = cam
        self.scene.camera = cam
        self._dir = Path(tempfile.mkdtemp(prefix="spikenerf-blender-"))
        self._finalizer = weakref.finalize(self, shutil.rmtree, self._dir, True)
        self.scene.render.filepath = str(self._dir / "frame.exr")

    def render(self, c2w: np.ndarray) -> np.ndarray:
        """One frame from the camera-to-world pose ``c2w`` (4, 4), OpenGL axes, world +Z up.

        Returns:
            (H, W, 3) float32 linear radiance composited over a white (1.0) background.
        """
        pose = np.asarray(c2w, dtype=np.float64)
        if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
            raise InputError(f"a camera pose must be a finite (4, 4) matrix, got shape {pose.shape}")
        self.camera.matrix_world = Matrix(pose.tolist())
        with quiet():
            bpy.ops.render.render(write_still=True)
        image = bpy.data.images.load(self.scene.render.filepath, check_existing=False)
        try:
            w, h = image.size
            buf = np.empty(w * h * 4, dtype=np.float32)
            image.pixels.foreach_get(buf)
        finally:
            bpy.data.images.remove(image)
        rgba = buf.reshape(h, w, 4)[::-1]  # Blender stores rows bottom-up
        rgb = rgba[..., :3] + (1.0 - rgba[..., 3:4])  # premultiplied colour over white
        return np.ascontiguousarray(rgb, dtype=np.float32)

    def close(self) -> None:
        """Remove the temporary folder."""
        self._finalizer()
