#!/usr/bin/env python3
"""Runs the tools a user would try first on an RGB-D folder (TUM RGB-D's
layout, or 7-Scenes' frame-N files: the two `localize run --sequence` reads)
and scores them beside a `localize run` of the same folder.

Peers, each on the clouds of the depth images (0.2-4 m, as the project's
run takes them) in time order:
  kiss-icp       KISS-ICP's own pipeline (voxel 4 cm: its max range / 100)
  o3d-icp        Open3D frame-to-frame point-to-plane ICP (2 cm voxels,
                 5 cm correspondence gate, from the identity as its tutorial)
  o3d-rgbd       Open3D RGB-D odometry (hybrid photometric + depth term),
                 only where colour and depth are registered (TUM)

Each trajectory is written in the run's world (the depth camera's body frame
at the first frame, x forward, z up) as TUM files under OUT, and scored with
`localize eval` against RUN/groundtruth.txt, unaligned and SE3-aligned, beside
RUN/trajectory.txt. Not part of the build or CI; in a venv outside the repo:

    python3 -m venv ~/peers && ~/peers/bin/pip install kiss-icp open3d
    localize run --sequence FOLDER --out RUN
    ~/peers/bin/python scripts/rgbd_peers.py FOLDER --run RUN --out OUT
"""

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

# The depth camera's optical frame (x right, y down, z forward) from its
# body frame (x forward, y left, z up): as localize/src/input/rgbd_sequence.rs.
OPTICAL_FROM_BODY = np.array([[0, -1, 0, 0], [0, 0, -1, 0], [1, 0, 0, 0], [0, 0, 0, 1]], dtype=float)
TUM_CAMERAS = {"freiburg1": (517.3, 516.5, 318.6, 255.3), "freiburg2": (520.9, 521.0, 325.1, 249.7),
               "freiburg3": (535.4, 539.2, 320.1, 247.6)}


def read_list(path):
    rows = [l.split() for l in path.read_text().splitlines() if l.strip() and not l.startswith("#")]
    return [(float(r[0]), path.parent / r[1]) for r in rows]


def read_frames(folder):
    """(stamps, depth paths, colour paths, intrinsics fx fy cx cy, units a metre, registered)."""
    if (folder / "depth.txt").is_file():
        depth, rgb = read_list(folder / "depth.txt"), read_list(folder / "rgb.txt")
        rgb_stamps = np.array([t for t, _ in rgb])
        colour = [rgb[int(np.argmin(abs(rgb_stamps - t)))][1] for t, _ in depth]
        yaml = sorted(folder.glob("*.yaml"))
        if yaml:
            values = {}
            for line in yaml[0].read_text().splitlines():
                key, _, value = line.partition(":")
                try:
                    values[key.strip()] = float(value)
                except ValueError:
                    pass
            k = tuple(values[f"Camera.{n}"] for n in ("fx", "fy", "cx", "cy"))
            units = values.get("DepthMapFactor", 5000.0)
        else:
            name = str(folder.resolve())
            k = next(v for n, v in TUM_CAMERAS.items() if n in name)
            units = 5000.0
        return [t for t, _ in depth], [p for _, p in depth], colour, k, units, True
    frames = folder / "frames" if (folder / "frames").is_dir() else folder
    depth = sorted(frames.glob("frame-*.depth.png"))
    numbers = [int(p.name[len("frame-"):-len(".depth.png")]) for p in depth]
    colour = [p.with_name(p.name.replace(".depth.png", ".color.jpg")) for p in depth]
    intrinsics = folder / "camera-intrinsics.txt"
    m = np.loadtxt(intrinsics) if intrinsics.is_file() else np.array([[585, 0, 320], [0, 585, 240], [0, 0, 1.0]])
    return [n / 30.0 for n in numbers], depth, colour, (m[0, 0], m[1, 1], m[0, 2], m[1, 2]), 1000.0, False


def cloud(path, k, units, near=0.2, far=4.0):
    import open3d as o3d
    depth = np.asarray(o3d.io.read_image(str(path)), dtype=np.float64) / units
    v, u = np.nonzero((depth >= near) & (depth <= far))
    z = depth[v, u]
    fx, fy, cx, cy = k
    return np.stack([(u - cx) / fx * z, (v - cy) / fy * z, z], axis=1)


def kiss_icp(frames, k, units):
    from kiss_icp.config import load_config
    from kiss_icp.kiss_icp import KissICP
    config = load_config(None)
    config.data.max_range, config.data.min_range, config.data.deskew = 4.0, 0.2, False
    config.mapping.voxel_size = 4.0 / 100.0
    peer, poses = KissICP(config), []
    for path in frames:
        peer.register_frame(cloud(path, k, units), np.array([]))
        poses.append(np.array(peer.last_pose))
    return poses


def o3d_icp(frames, k, units):
    import open3d as o3d
    reg = o3d.pipelines.registration
    previous, pose, poses = None, np.eye(4), []
    for path in frames:
        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud(path, k, units))).voxel_down_sample(0.02)
        pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.08, max_nn=30))
        if previous is not None:
            result = reg.registration_icp(pcd, previous, 0.05, np.eye(4), reg.TransformationEstimationPointToPlane(),
                                          reg.ICPConvergenceCriteria(max_iteration=50))
            pose = pose @ result.transformation
        poses.append(pose.copy())
        previous = pcd
    return poses


def o3d_rgbd(frames, colours, k, units):
    import open3d as o3d
    fx, fy, cx, cy = k
    intrinsic = o3d.camera.PinholeCameraIntrinsic(640, 480, fx, fy, cx, cy)
    option = o3d.pipelines.odometry.OdometryOption()
    option.depth_max, option.depth_min = 4.0, 0.2

    def rgbd(i):
        return o3d.geometry.RGBDImage.create_from_color_and_depth(
            o3d.io.read_image(str(colours[i])), o3d.io.read_image(str(frames[i])), depth_scale=units,
            depth_trunc=4.0, convert_rgb_to_intensity=True)

    pose, poses, previous = np.eye(4), [np.eye(4)], rgbd(0)
    for i in range(1, len(frames)):
        current = rgbd(i)
        ok, motion, _ = o3d.pipelines.odometry.compute_rgbd_odometry(
            current, previous, intrinsic, np.eye(4), o3d.pipelines.odometry.RGBDOdometryJacobianFromHybridTerm(),
            option)
        # A failed pair keeps the previous pose (as a user's loop would).
        if ok:
            pose = pose @ motion
        poses.append(pose.copy())
        previous = current
    return poses


def quaternion(r):
    w = np.sqrt(max(0.0, 1 + r[0, 0] + r[1, 1] + r[2, 2])) / 2
    x = np.copysign(np.sqrt(max(0.0, 1 + r[0, 0] - r[1, 1] - r[2, 2])) / 2, r[2, 1] - r[1, 2])
    y = np.copysign(np.sqrt(max(0.0, 1 - r[0, 0] + r[1, 1] - r[2, 2])) / 2, r[0, 2] - r[2, 0])
    z = np.copysign(np.sqrt(max(0.0, 1 - r[0, 0] - r[1, 1] + r[2, 2])) / 2, r[1, 0] - r[0, 1])
    return x, y, z, w


def write_tum(path, stamps, optical_poses):
    """Optical-frame poses from the first frame, as body-frame poses."""
    body_from_optical = np.linalg.inv(OPTICAL_FROM_BODY)
    with path.open("w") as f:
        f.write("# timestamp tx ty tz qx qy qz qw\n")
        for t, p in zip(stamps, optical_poses):
            m = body_from_optical @ p @ OPTICAL_FROM_BODY
            x, y, z, w = quaternion(m[:3, :3])
            f.write(f"{t:.6f} {m[0, 3]:.9f} {m[1, 3]:.9f} {m[2, 3]:.9f} {x:.9f} {y:.9f} {z:.9f} {w:.9f}\n")


def score(localize, truth, estimate):
    out = {}
    for align in ("none", "se3"):
        text = subprocess.run([localize, "eval", "--gt", str(truth), "--est", str(estimate), "--align", align,
                               "--json"], check=True, capture_output=True, text=True).stdout
        out[align] = json.loads(text)["ate_rmse"]
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folder", type=Path, help="a TUM RGB-D or 7-Scenes folder")
    parser.add_argument("--run", type=Path, required=True, help="a `localize run --sequence FOLDER` output")
    parser.add_argument("--out", type=Path, required=True, help="where the peers' trajectories go")
    parser.add_argument("--peers", default="kiss-icp,o3d-icp,o3d-rgbd")
    parser.add_argument("--localize", default="target/release/localize")
    args = parser.parse_args()
    truth = args.run / "groundtruth.txt"
    if not truth.is_file():
        sys.exit(f"{truth}: missing (run `localize run --sequence {args.folder} --out {args.run}` first)")
    stamps, frames, colours, k, units, registered = read_frames(args.folder)
    args.out.mkdir(parents=True, exist_ok=True)
    rows = [("corner-fusion (localize run)", args.run / "trajectory.txt", None)]
    for name in [p.strip() for p in args.peers.split(",")]:
        if name == "o3d-rgbd" and not registered:
            print(f"{name}: skipped, colour and depth are not registered in this folder")
            continue
        started = time.time()
        poses = {"kiss-icp": lambda: kiss_icp(frames, k, units), "o3d-icp": lambda: o3d_icp(frames, k, units),
                 "o3d-rgbd": lambda: o3d_rgbd(frames, colours, k, units)}[name]()
        seconds = time.time() - started
        path = args.out / f"{name}.txt"
        write_tum(path, stamps, poses)
        rows.append((name, path, 1000 * seconds / len(frames)))
    print(f"| {args.folder.name}: method | ATE unaligned (m) | ATE SE3-aligned (m) | ms per frame |")
    print("| --- | --- | --- | --- |")
    for name, path, ms in rows:
        s = score(args.localize, truth, path)
        print(f"| {name} | {s['none']:.4f} | {s['se3']:.4f} | {'-' if ms is None else f'{ms:.0f}'} |")


if __name__ == "__main__":
    main()
