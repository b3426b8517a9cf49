#!/usr/bin/env python3
"""Runs the LIDAR odometry systems a user would try first, KISS-ICP and
GenZ-ICP, on the sequences of a `localize benchmark` folder (or on one
sequence folder), so that the benchmark table gains their columns.

Each sequence's scans (`sequence/cloud/*.pcd`, in name order, which is time
order) go to each system with their per-point times, as its own pipeline
would feed them. The LIDAR-frame poses are turned into robot poses with the
sequence's `calib.json` and started at the ground truth's first pose, the
same world frame the fused trajectory uses, and written as TUM files to
`peers/kiss-icp.txt` and `peers/genz-icp.txt` beside the sequence. Run
`localize benchmark` again with the same flags afterwards: it reuses the
data and reads these files.

Not part of the build or of CI. Install the peers in a virtual environment
outside the repository:

    python3 -m venv ~/peers && ~/peers/bin/pip install kiss-icp genz-icp
    ~/peers/bin/python scripts/lidar_peers.py bench-out [--max-range 20]
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

PCD_TYPES = {("F", 4): "<f4", ("F", 8): "<f8", ("U", 1): "u1", ("U", 2): "<u2", ("U", 4): "<u4",
             ("I", 1): "i1", ("I", 2): "<i2", ("I", 4): "<i4"}


def read_pcd(path):
    """xyz (N x 3, float64) and per-point times (N) of a binary or ascii PCD."""
    data = path.read_bytes()
    header, offset = {}, 0
    while True:
        end = data.index(b"\n", offset)
        line = data[offset:end].decode("ascii").strip()
        offset = end + 1
        if not line or line.startswith("#"):
            continue
        key, *rest = line.split()
        header[key] = rest
        if key == "DATA":
            break
    names, sizes, types = header["FIELDS"], [int(s) for s in header["SIZE"]], header["TYPE"]
    counts = [int(c) for c in header.get("COUNT", ["1"] * len(names))]
    points = int(header["POINTS"][0])
    kind = header["DATA"][0]
    if kind == "binary":
        fields = [(n, PCD_TYPES[(t, s)]) if c == 1 else (n, PCD_TYPES[(t, s)], (c,))
                  for n, s, t, c in zip(names, sizes, types, counts)]
        records = np.frombuffer(data, dtype=np.dtype(fields), count=points, offset=offset)
        column = lambda n: np.asarray(records[n], dtype=np.float64).reshape(points, -1)[:, 0]
    elif kind == "ascii":
        table = np.loadtxt(data[offset:].decode("ascii").splitlines(), ndmin=2)
        index = np.cumsum([0] + counts[:-1])
        column = lambda n: table[:, index[names.index(n)]]
    else:
        sys.exit(f"{path}: DATA {kind} is not supported here")
    xyz = np.stack([column("x"), column("y"), column("z")], axis=1)
    times = column("time") if "time" in names else np.zeros(len(xyz))
    keep = np.isfinite(xyz).all(axis=1)
    return xyz[keep], times[keep]


def read_tum(path):
    rows = [l.split() for l in path.read_text().splitlines() if l.strip() and not l.startswith("#")]
    return np.array([[float(v) for v in r] for r in rows])


def pose_matrix(t, q):
    x, y, z, w = q
    r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = r, t
    return m


def quaternion(r):
    """(x, y, z, w) of a rotation matrix."""
    w = np.sqrt(max(0.0, 1 + r[0, 0] + r[1, 1] + r[2, 2])) / 2
    x = np.sqrt(max(0.0, 1 + r[0, 0] - r[1, 1] - r[2, 2])) / 2
    y = np.sqrt(max(0.0, 1 - r[0, 0] + r[1, 1] - r[2, 2])) / 2
    z = np.sqrt(max(0.0, 1 - r[0, 0] - r[1, 1] + r[2, 2])) / 2
    x = np.copysign(x, r[2, 1] - r[1, 2])
    y = np.copysign(y, r[0, 2] - r[2, 0])
    z = np.copysign(z, r[1, 0] - r[0, 1])
    return x, y, z, w


def slerp(a, b, f):
    """Interpolates two 4x4 poses: translation linearly, rotation on the sphere."""
    qa, qb = np.array(quaternion(a[:3, :3])), np.array(quaternion(b[:3, :3]))
    if qa @ qb < 0:
        qb = -qb
    angle = np.arccos(min(1.0, abs(qa @ qb)))
    if angle < 1e-9:
        q = qa
    else:
        q = (np.sin((1 - f) * angle) * qa + np.sin(f * angle) * qb) / np.sin(angle)
    return pose_matrix((1 - f) * a[:3, 3] + f * b[:3, 3], q / np.linalg.norm(q))


def pose_at(stamps, poses, t):
    """The pose at time t between the two samples around it."""
    k = int(np.searchsorted(stamps, t))
    k = min(max(k, 1), len(stamps) - 1)
    f = (t - stamps[k - 1]) / (stamps[k] - stamps[k - 1])
    return slerp(poses[k - 1], poses[k], f)


def make_peer(name, max_range):
    if name == "kiss-icp":
        from kiss_icp.config import load_config
        from kiss_icp.kiss_icp import KissICP
        config = load_config(None)
        config.data.max_range = max_range
        config.mapping.voxel_size = max_range / 100.0
        return KissICP(config)
    if name == "genz-icp":
        from genz_icp.config import load_config
        from genz_icp.genz_icp import GenZICP
        config = load_config(None)
        config.data.max_range = max_range
        config.data.deskew = True
        config.mapping.voxel_size = max_range / 100.0
        return GenZICP(config)
    sys.exit(f"unknown peer {name}")


def run_peer(name, sequence, max_range):
    clouds = sorted((sequence / "cloud").glob("*.pcd"))
    if not clouds:
        sys.exit(f"{sequence}: no cloud/*.pcd")
    calib = json.loads((sequence / "calib.json").read_text())
    robot_from_lidar = np.array(calib["robot_from_lidar"])
    truth = read_tum(sequence / "groundtruth.txt")
    truth_stamps = truth[:, 0]
    truth_poses = [pose_matrix(r[1:4], r[4:8]) for r in truth]
    peer = make_peer(name, max_range)
    stamps, mids, lidar_poses, started = [], [], [], time.time()
    for path in clouds:
        xyz, times = read_pcd(path)
        # Scans taken at once (the paper's setting) have no times to deskew with.
        peer.register_frame(xyz, times if times.max(initial=0.0) > times.min(initial=0.0) else np.array([]))
        stamp = float(path.stem)
        # Both systems deskew a sweep to the middle of its point times and
        # report the pose there.
        stamps.append(stamp)
        mids.append(stamp + (0.5 * (times.min() + times.max()) if len(times) else 0.0))
        lidar_poses.append(np.array(peer.last_pose))
    seconds = time.time() - started
    # The peer's world is the robot's pose at its first pose time; its poses
    # are taken back to the scan stamps, which the ground truth uses.
    world_from_robot0 = pose_at(truth_stamps, truth_poses, mids[0])
    robot_poses = [world_from_robot0 @ robot_from_lidar @ p @ np.linalg.inv(robot_from_lidar) for p in lidar_poses]
    rows = [(t, pose_at(np.array(mids), robot_poses, t)) for t in stamps if mids[0] <= t <= mids[-1]]
    out = sequence.parent / "peers" / f"{name}.txt"
    out.parent.mkdir(exist_ok=True)
    tmp = out.with_suffix(".tmp")
    with tmp.open("w") as f:
        f.write("# timestamp tx ty tz qx qy qz qw\n")
        for stamp, m in rows:
            x, y, z, w = quaternion(m[:3, :3])
            f.write(f"{stamp:.9f} {m[0, 3]:.9f} {m[1, 3]:.9f} {m[2, 3]:.9f} {x:.9f} {y:.9f} {z:.9f} {w:.9f}\n")
    tmp.replace(out)
    print(f"{out}: {len(rows)} poses, {1000 * seconds / len(stamps):.1f} ms per scan")


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folder", type=Path, help="a `localize benchmark --out` folder, or one sequence folder")
    parser.add_argument("--max-range", type=float, default=20.0, help="metres; the voxel size is 1/100 of it")
    parser.add_argument("--peers", default="kiss-icp,genz-icp")
    args = parser.parse_args()
    if (args.folder / "cloud").is_dir():
        sequences = [args.folder]
    else:
        sequences = sorted(args.folder.glob("building-*/speed-*/sequence"))
    if not sequences:
        sys.exit(f"{args.folder}: no sequence folders (run `localize benchmark --out {args.folder}` first)")
    for sequence in sequences:
        for name in args.peers.split(","):
            run_peer(name.strip(), sequence, args.max_range)


if __name__ == "__main__":
    main()
