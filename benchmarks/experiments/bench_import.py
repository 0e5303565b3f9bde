"""The real-data path checked where the truth is known: simulate, hide the poses, ``spikenerf import``.

Run: ``.venv/bin/python -m benchmarks.experiments.bench_import --out /tmp/bench-import`` (resumable: finished
simulations and imports in ``--out`` are reused). Any named scene works: the analytic ones (the default) or
Blender ones (``--scenes bricks,food --spp 4``; needs bpy). Per scene: ``spikenerf simulate --noise
realistic`` at 400×250; the spike stream is rewritten in the raw 416-column sps10 layout with a SpikeCV
``config.yaml`` (spike_h, spike_w, raw_width, fps) and nothing else: no poses, no intrinsics. Then ``spikenerf
import REC.dat`` estimates the keyframe poses with COLMAP and interpolates them to every step.

Reported per scene, against the simulated truth after a similarity (Umeyama) alignment of the positions:
the fraction of keyframes COLMAP registered, the rotation error (mean and max, degrees) and the absolute
trajectory error (ATE RMSE, relative to the orbit radius) at the keyframes and at every step. The reference,
measured in the same run, is the true keyframe poses interpolated to every step the same way (the floor that
interpolation alone sets); the ratio is ours / reference for the every-step ATE.

Checks of the import itself (analytic scenes): whether the unit box holds the scene (the largest
|coordinate| of the scene's box corners and spheres in the dataset's frame; over 1 is clipped), how far its
frame is turned off the scene's axis-aligned boxes about the up axis (``axes_off_deg``), and whether
COLMAP's observations can tell its poses from the true ones (the mean reprojection error with either pose
set, the points re-solved by a bundle adjustment with the poses fixed).

With ``--train-iters N`` it also trains ``nerf-recon`` on the exact-pose dataset and on the imported one (the
true held-out views mapped into the estimated frame) and reports both test PSNRs.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from spikenerf.capture.recording import RAW_FILE, write_raw_recording
from spikenerf.data.dataset import TRANSFORMS_TEST, SpikeDataset, load_dataset
from spikenerf.importing.alignment import trajectory_errors, umeyama
from spikenerf.importing.interpolation import per_step_poses
from spikenerf.importing.keyframes import keyframe_steps

RAW_EXTRA = 16


def spikenerf(*args: object) -> None:
    """Run one ``spikenerf`` command (the same interpreter); a failure stops the benchmark."""
    cmd = [sys.executable, "-m", "spikenerf", "--threads", "1", *map(str, args)]
    print("$", " ".join(cmd[2:]), flush=True)
    subprocess.run(cmd, check=True)


def simulate(scene: str, out: Path, a: argparse.Namespace) -> Path:
    sim = out / f"sim-{scene}{sweep_tag(a)}"
    if not sim.exists():
        spp = ["--spp", a.spp] if a.spp else []
        spp += ["--elevation-sweep", a.elevation_sweep] if a.elevation_sweep else []
        spikenerf(
            "simulate",
            "--scene",
            scene,
            "--width",
            a.width,
            "--height",
            a.height,
            "--frames",
            a.frames,
            "--noise",
            "realistic",
            "--blur-fps",
            0,
            "--test-views",
            4,
            "--no-progress",
            *spp,
            "--out",
            sim,
        )
    return sim


def sweep_tag(a: argparse.Namespace) -> str:
    """The folder suffix of a path whose elevation sweeps (``-sweepDEG``); empty for the flat orbit."""
    return f"-sweep{a.elevation_sweep:g}" if a.elevation_sweep else ""


def raw_recording(sim: Path, out: Path) -> Path:
    """The simulated stream as a raw 416-column recording + a SpikeCV config.yaml; no poses."""
    ds = load_dataset(sim)
    h, w = ds.intrinsics.height, ds.intrinsics.width
    rec = out / f"rec-{sim.name[4:]}" / RAW_FILE
    if not rec.exists():
        fps = float(ds.trajectory.fps)
        write_raw_recording(sim / "spikes_gray.dat", h, w, fps, rec.parent, w + RAW_EXTRA)
    return rec


def import_(rec: Path, out: Path, a: argparse.Namespace, fov: float | None) -> tuple[Path, float]:
    """Import ``rec`` with COLMAP: the focal length fixed by ``fov`` (horizontal, degrees) or estimated."""
    tag = f"-{a.tag}" if a.tag else ""
    name = f"imp-{rec.parent.name[4:]}-{'fov' if fov else 'selfcal'}-w{a.window}{tag}"
    ds, start = out / name, time.perf_counter()
    if not ds.exists():
        extra = ["--fov", fov] if fov else []
        spikenerf(
            "import",
            rec,
            "--out",
            ds,
            "--keyframe-every",
            a.keyframe_every,
            "--window",
            a.window,
            *extra,
            *a.import_args.split(),
        )
    return ds, time.perf_counter() - start


def orbit_radius(truth: SpikeDataset) -> float:
    """Mean distance of the true camera centres from the orbit centre (``trajectory.center`` in the
    simulation's config; the origin when absent): the orbit radius for the built-in scenes."""
    center = np.asarray(truth.config.get("trajectory", {}).get("center", (0.0, 0.0, 0.0)), dtype=float)
    return float(np.linalg.norm(truth.trajectory.poses[:, :3, 3] - center, axis=1).mean())


def errors(sim: Path, imp: Path) -> dict:
    truth, est = load_dataset(sim), load_dataset(imp)
    info = est.config["imported"]
    keys = keyframe_steps(len(truth.trajectory), info["keyframe_every"], info["window"])
    t_all, e_all = truth.trajectory.poses, est.trajectory.poses
    floor = per_step_poses(t_all[keys], keys, np.arange(len(t_all)))
    radius = orbit_radius(truth)
    at_keys = trajectory_errors(e_all[keys], t_all[keys])
    every = trajectory_errors(e_all, t_all)
    ref = trajectory_errors(floor, t_all)
    return {
        "registered": f"{info['poses_known']}/{info['keyframes']}",
        "registered_frac": info["poses_known"] / info["keyframes"],
        "rot_mean_deg": at_keys["rot_mean_deg"],
        "rot_max_deg": at_keys["rot_max_deg"],
        "ate_keys_over_radius": at_keys["ate_rmse"] / radius,
        "ate_all_over_radius": every["ate_rmse"] / radius,
        "ate_all_reference_over_radius": ref["ate_rmse"] / radius,
        "ate_all": every["ate_rmse"],
        "radius": radius,
        "rot_all_mean_deg": every["rot_mean_deg"],
    }


def box_fit(sim: Path, imp: Path) -> dict:
    """How the imported unit box holds an analytic scene: the largest |coordinate| of the scene's extreme
    points (box corners, sphere poles) in the imported dataset's frame (over 1: clipped) and how many lie
    outside. The truth is mapped by the similarity that aligns the imported trajectory with the true one."""
    import itertools

    from spikenerf.scenes.analytic import SCENES, Box

    truth, est = load_dataset(sim), load_dataset(imp)
    name = truth.config.get("scene")
    if name not in SCENES:
        return {}
    s, rot, t = umeyama(est.trajectory.poses[:, :3, 3], truth.trajectory.poses[:, :3, 3])
    reach = []  # per extreme: its largest |coordinate| per axis in the imported frame
    for prim in SCENES[name][1]:
        if isinstance(prim, Box):
            corners = np.array(list(itertools.product(*zip(prim.lo, prim.hi, strict=True))))
            reach += list(np.abs((corners - t) @ rot / s))
        else:  # a sphere reaches its radius along every axis of any frame
            reach.append(np.abs((np.array(prim.center) - t) @ rot / s) + prim.radius / s)
    reach = np.array(reach)
    outside = int((reach > 1).any(1).sum())
    # the scene's boxes are axis-aligned in the simulation: how far the imported frame is turned off them
    # about the up axis (modulo 90°); import --orient up aims for 0
    turn = math.degrees(math.atan2(rot[1, 0], rot[0, 0])) % 90
    return {"box_max_coord": float(reach.max()), "box_outside": outside, "box_extremes": len(reach),
            "axes_off_deg": min(turn, 90 - turn)}  # fmt: skip


def _bundle_adjust_points(rec: object) -> float:
    """Re-solve the 3-D points of a pycolmap reconstruction with every pose and camera fixed; the mean
    reprojection error (px) after."""
    import pycolmap

    opts = pycolmap.BundleAdjustmentOptions()
    opts.refine_focal_length = opts.refine_principal_point = opts.refine_extra_params = False
    opts.print_summary = False
    cfg = pycolmap.BundleAdjustmentConfig()
    for image_id, image in rec.images.items():
        cfg.add_image(image_id)
        cfg.set_constant_rig_from_world_pose(image.frame_id)
    for camera_id in rec.cameras:
        cfg.set_constant_cam_intrinsics(camera_id)
    pycolmap.create_default_bundle_adjuster(opts, cfg, rec).solve()
    rec.update_point_3d_errors()
    return float(rec.compute_mean_reprojection_error())


def _with_true_poses(sim: Path, model: Path) -> object:
    """The COLMAP model at ``model`` with every keyframe's pose replaced by the true one, mapped into the
    model's frame by the similarity of the camera centres (the points re-solved for those poses)."""
    import pycolmap

    from spikenerf.importing.colmap_model import CV_TO_GL, read_colmap_text

    truth = load_dataset(sim).trajectory.poses
    found = read_colmap_text(model)
    s, rot, t = umeyama(np.asarray(found.poses)[:, :3, 3], truth[np.asarray(found.steps)][:, :3, 3])
    rec = pycolmap.Reconstruction(str(model))
    for image in rec.images.values():
        c2w = truth[int(Path(image.name).stem)]
        w2c = (rot.T @ c2w[:3, :3] @ CV_TO_GL[:3, :3]).T  # OpenGL camera → COLMAP's, in its frame
        centre = rot.T @ (c2w[:3, 3] - t) / s
        rec.frames[image.frame_id].rig_from_world = pycolmap.Rigid3d(pycolmap.Rotation3d(w2c), -w2c @ centre)
    _bundle_adjust_points(rec)
    return rec


def truth_reprojection(sim: Path, imp: Path) -> dict:
    """Can COLMAP's own observations tell its poses from the true ones? The mean reprojection error of the
    model's 2-D observations with its estimated poses and with the true poses (mapped into its frame by the
    similarity of the camera centres), the 3-D points re-solved by a bundle adjustment with every pose and
    the camera fixed in both cases (pycolmap)."""
    import pycolmap

    from spikenerf.importing.keyframes import COLMAP_WORK

    model = imp / COLMAP_WORK / "model"
    if not (model / "images.txt").is_file():
        return {}
    estimated = _bundle_adjust_points(pycolmap.Reconstruction(str(model)))
    true = float(_with_true_poses(sim, model).compute_mean_reprojection_error())
    return {"reproj_estimated_px": estimated, "reproj_true_px": true}


def truth_import(sim: Path, imp: Path, rec: Path, a: argparse.Namespace, fov: float) -> Path | None:
    """The recording imported through the same pipeline with the **true** keyframe poses: COLMAP's model
    with its poses replaced by the true ones (its points re-solved for them) is given as the pose source, so
    the keyframes, the upright box from the points and near/far are made the same way; only the poses
    differ (``IMPORT-truth``). None without a COLMAP model."""
    from spikenerf.importing.keyframes import COLMAP_WORK

    model = imp / COLMAP_WORK / "model"
    dst = imp.parent / f"{imp.name}-truth"
    if not (model / "images.txt").is_file():
        return None
    if not dst.exists():
        true_model = imp / COLMAP_WORK / "model-truth"
        true_model.mkdir(exist_ok=True)
        _with_true_poses(sim, model).write_text(str(true_model))
        spikenerf("import", rec, "--out", dst, "--keyframe-every", a.keyframe_every, "--window", a.window,
                  "--fov", fov, "--poses", true_model, *a.import_args.split())  # fmt: skip
    return dst


def aligned_test_views(sim: Path, imp: Path, dst: Path) -> Path:
    """A copy of the imported dataset whose test views are the simulation's true ones, mapped into the
    estimated frame by the inverse of the similarity that aligns the estimated trajectory with the truth."""
    truth, est = load_dataset(sim), load_dataset(imp)
    s, rot, t = umeyama(est.trajectory.poses[:, :3, 3], truth.trajectory.poses[:, :3, 3])
    if not dst.exists():
        shutil.copytree(imp, dst)
        shutil.rmtree(dst / "test")
        shutil.copytree(sim / "test", dst / "test")
        data = json.loads((sim / TRANSFORMS_TEST).read_text())
        head = json.loads((imp / TRANSFORMS_TEST).read_text())
        for frame in data["frames"]:
            pose = np.asarray(frame["transform_matrix"])
            mapped = np.eye(4)
            mapped[:3, :3] = rot.T @ pose[:3, :3]
            mapped[:3, 3] = rot.T @ (pose[:3, 3] - t) / s
            frame["transform_matrix"] = mapped.tolist()
        head["frames"] = data["frames"]
        (dst / TRANSFORMS_TEST).write_text(json.dumps(head))
    return dst


def test_psnr(dataset: Path, run: Path, iters: int) -> float:
    if not (run / "metrics.json").exists():
        spikenerf("train", dataset, "--method", "nerf-recon", "--iters", iters, "--out", run)
        spikenerf("eval", run)
    return float(json.loads((run / "metrics.json").read_text())["psnr"])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--scenes", default="analytic-blocks,analytic-orbs")
    p.add_argument("--width", type=int, default=400)
    p.add_argument("--height", type=int, default=250)
    p.add_argument("--frames", type=int, default=1000)
    p.add_argument("--spp", type=int, default=0, help="render samples per pixel (0: the simulator's default)")
    p.add_argument(
        "--elevation-sweep", type=float, default=0.0,
        help="simulate --elevation-sweep: peak-to-peak elevation change over the path (0: a flat orbit); "
        "the folders get a -sweepDEG suffix",
    )  # fmt: skip
    p.add_argument("--keyframe-every", type=int, default=20)
    p.add_argument("--window", type=int, default=21, help="TFP window of the keyframes")
    p.add_argument("--fov-only", action="store_true", help="skip the self-calibrated imports")
    p.add_argument("--train-iters", type=int, default=0)
    p.add_argument("--tag", default="", help="suffix of the import folders (a variant of the settings)")
    p.add_argument("--import-args", default="", help="extra `spikenerf import` flags, e.g. '--no-final-ba'")
    p.add_argument(
        "--truth-import", action="store_true",
        help="also import each recording with COLMAP's model given the true poses (IMPORT-truth): the same "
        "pipeline with exact keyframe poses, for bench_refine's --imported IMPORT-truth",
    )  # fmt: skip
    a = p.parse_args()
    rows = []
    for scene in a.scenes.split(","):
        sim = simulate(scene, a.out, a)
        rec = raw_recording(sim, a.out)
        true_fov = math.degrees(load_dataset(sim).intrinsics.camera_angle_x)
        for fov in (true_fov,) if a.fov_only else (true_fov, None):
            try:
                imp, seconds = import_(rec, a.out, a, fov)
            except subprocess.CalledProcessError:
                rows.append({"scene": scene + sweep_tag(a), "fov": fov is not None, "registered": "failed"})
                continue
            row = {
                "scene": scene + sweep_tag(a),
                "fov": fov is not None,
                **errors(sim, imp),
                **box_fit(sim, imp),
                **truth_reprojection(sim, imp),
                "import_s": seconds,
            }
            if a.train_iters and fov:
                aligned = aligned_test_views(sim, imp, a.out / f"{imp.name}-testaligned")
                runs = a.out / f"run-{scene}{sweep_tag(a)}"
                row["psnr_exact"] = test_psnr(sim, Path(f"{runs}-exact"), a.train_iters)
                row["psnr_estimated"] = test_psnr(aligned, Path(f"{runs}-estimated"), a.train_iters)
            if a.truth_import and fov:
                truth_imp = truth_import(sim, imp, rec, a, fov)
                row["truth_import"] = None if truth_imp is None else truth_imp.name
            rows.append(row)
            print(json.dumps(row), flush=True)
    tag = f"-{a.tag}" if a.tag else ""
    (a.out / f"results-w{a.window}{tag}{sweep_tag(a)}.json").write_text(json.dumps(rows, indent=1))
    head = "| scene | focal | registered | rot mean° | rot max° | ATE/r keys | ATE/r all | ATE all | ref. |"
    print(head + " ratio | box max |x| | extremes outside | axes off° | reproj. px, COLMAP / true poses |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        if r["registered"] == "failed":
            print(f"| {r['scene']} | {'--fov' if r['fov'] else 'estimated'} | failed | | | | | | | |")
            continue
        ratio = r["ate_all_over_radius"] / r["ate_all_reference_over_radius"]
        print(
            f"| {r['scene']} | {'--fov' if r['fov'] else 'estimated'} | {r['registered']} | "
            f"{r['rot_mean_deg']:.2f} | {r['rot_max_deg']:.2f} | {r['ate_keys_over_radius']:.4f} | "
            f"{r['ate_all_over_radius']:.4f} | {r['ate_all']:.4f} | "
            f"{r['ate_all_reference_over_radius']:.4f} | {ratio:.1f}× | "
            f"{r.get('box_max_coord', np.nan):.2f} | "
            f"{r.get('box_outside', '—')}/{r.get('box_extremes', '—')} | "
            f"{r.get('axes_off_deg', np.nan):.2f} | "
            f"{r.get('reproj_estimated_px', np.nan):.3f} / {r.get('reproj_true_px', np.nan):.3f} |"
        )


if __name__ == "__main__":
    main()
