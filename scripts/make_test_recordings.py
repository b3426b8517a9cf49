#!/usr/bin/env python3
"""Writes the test recordings of datasets/tests/data/recordings/ with writers
that are not the project's: `rosbags` (rosbag2 sqlite3 and MCAP folders,
rosbag2 file and message compression, ROS 1 bags with plain, bz2 and lz4
chunks) and `mcap-ros2-support` (bare MCAP files with lz4 and zstd chunks, a
CDR serialiser of its own). Every recording holds the same one second of
generated data: a 10 Hz LIDAR, a 30 Hz camera 13 ms behind it, a 200 Hz IMU,
50 Hz odometry, camera_info, /tf_static and a PoseStamped ground truth. The
values written go to expected.json, which the tests compare with what the
project's readers decode, value for value.

Run by hand, never in CI:
    python3 -m venv /tmp/rosvenv && /tmp/rosvenv/bin/pip install rosbags mcap-ros2-support pillow
    /tmp/rosvenv/bin/python scripts/make_test_recordings.py datasets/tests/data/recordings
"""

import io
import json
import math
import random
import shutil
import struct
import sys
import zlib
from pathlib import Path

import numpy as np
from mcap.writer import CompressionType
from mcap_ros2.writer import Writer as Mcap2Writer
from PIL import Image as PilImage
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.rosbag2 import StoragePlugin, Writer as Ros2Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

T0 = 1_700_000_000_000_000_000  # ns
RNG = random.Random(20261201)
ROS2 = get_typestore(Stores.ROS2_HUMBLE)
ROS1 = get_typestore(Stores.ROS1_NOETIC)
# Noetic's store has no tf2_msgs; its TFMessage is this one line.
ROS1.register(get_types_from_msg('geometry_msgs/TransformStamped[] transforms', 'tf2_msgs/msg/TFMessage'))

# PointField datatypes.
INT8, UINT8, INT16, UINT16, INT32, UINT32, FLOAT32, FLOAT64 = range(1, 9)
FMT = {INT8: 'b', UINT8: 'B', INT16: 'h', UINT16: 'H', INT32: 'i', UINT32: 'I', FLOAT32: 'f', FLOAT64: 'd'}

# Two cloud layouts: Ouster-like (float32 x/y/z, intensity, ring, `t` in ns,
# padding, organised 2 x 8 with row padding, a NaN point) and a big-endian
# float64 one (uint8 intensity, Velodyne-like `time` in float32 seconds).
LAYOUTS = {
    'ouster32': dict(
        fields=[('x', 0, FLOAT32), ('y', 4, FLOAT32), ('z', 8, FLOAT32), ('intensity', 16, FLOAT32),
                ('ring', 20, UINT16), ('t', 24, UINT32)],
        point_step=32, height=2, width=8, row_pad=16, big_endian=False, time='t'),
    'velodyne64be': dict(
        fields=[('x', 0, FLOAT64), ('y', 8, FLOAT64), ('z', 16, FLOAT64), ('intensity', 24, UINT8),
                ('time', 28, FLOAT32)],
        point_step=40, height=1, width=12, row_pad=0, big_endian=True, time='time'),
}


def ns_to_stamp(ns):
    return ns // 1_000_000_000, ns % 1_000_000_000


def make_data():
    """The one second of data every recording holds."""
    scans = []
    for k in range(10):
        stamp = T0 + k * 100_000_000
        points = []
        for i in range(24):
            r = RNG.uniform(1.0, 8.0)
            a = RNG.uniform(-math.pi, math.pi)
            points.append(dict(x=r * math.cos(a), y=r * math.sin(a), z=RNG.uniform(-1.0, 2.0),
                               intensity=float(RNG.randint(0, 255)), ring=i % 16,
                               dt_ns=int(i * 100_000_000 / 24)))
        scans.append(dict(stamp=stamp, points=points))
    images = []
    for k in range(30):
        stamp = T0 + 13_000_000 + k * 33_333_333
        pixels = [[[RNG.randint(0, 255) for _ in range(3)] for _ in range(32)] for _ in range(24)]
        images.append(dict(stamp=stamp, pixels=pixels))
    imu = [dict(stamp=T0 + k * 5_000_000,
                gyro=[RNG.gauss(0, 0.01), RNG.gauss(0, 0.01), RNG.gauss(0.1, 0.01)],
                accel=[RNG.gauss(0, 0.05), RNG.gauss(0, 0.05), RNG.gauss(9.80665, 0.05)]) for k in range(200)]
    odom = [dict(stamp=T0 + k * 20_000_000, x=0.5 * k * 0.02, y=0.001 * k, yaw=0.1 * k * 0.02,
                 v=0.5 + RNG.gauss(0, 0.01), omega=0.1 + RNG.gauss(0, 0.001)) for k in range(50)]
    truth = [dict(stamp=s['stamp'], position=[0.05 * k, 0.002 * k, 0.0],
                  orientation=[0.0, 0.0, math.sin(0.005 * k), math.cos(0.005 * k)]) for k, s in enumerate(scans)]
    tf_static = [
        dict(parent='base_link', child='lidar_link', translation=[0.1, 0.0, 0.4], rotation=[0.0, 0.0, 0.0, 1.0]),
        dict(parent='base_link', child='camera_optical_frame', translation=[0.15, 0.02, 0.3],
             rotation=[-0.5, 0.5, -0.5, 0.5]),
        dict(parent='base_link', child='imu_link', translation=[0.0, 0.0, 0.1],
             rotation=[0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4)]),
    ]
    camera = dict(width=32, height=24, k=[40.0, 0.0, 15.5, 0.0, 41.0, 11.5, 0.0, 0.0, 1.0])
    return dict(scans=scans, images=images, imu=imu, odom=odom, truth=truth, tf_static=tf_static, camera=camera)


def cloud_bytes(points, layout, nan_first):
    """The data of a PointCloud2 and the decoded points expected from it."""
    end = '>' if layout['big_endian'] else '<'
    h, w, step = layout['height'], layout['width'], layout['point_step']
    row_step = w * step + layout['row_pad']
    data = bytearray(h * row_step)
    expected = []
    for n in range(h * w):
        p = points[n]
        row, col = divmod(n, w)
        base = row * row_step + col * step
        values = dict(x=p['x'], y=p['y'], z=p['z'], intensity=p['intensity'], ring=p['ring'],
                      t=p['dt_ns'], time=p['dt_ns'] * 1e-9)
        if nan_first and n == 0:
            values['x'] = float('nan')
        for name, offset, kind in layout['fields']:
            v = values[name] if kind in (FLOAT32, FLOAT64) else int(values[name])
            struct.pack_into(end + FMT[kind], data, base + offset, v)
        if not (nan_first and n == 0):
            # What float32 storage makes of the values.
            f32 = lambda v: struct.unpack('f', struct.pack('f', v))[0]
            expected.append(dict(xyz=[f32(values['x']), f32(values['y']), f32(values['z'])],
                                 intensity=f32(values['intensity']), time=p['dt_ns'] * 1e-9))
    fields = [dict(name=n, offset=o, datatype=k, count=1) for n, o, k in layout['fields']]
    return bytes(data), row_step, fields, expected


def png_bytes(pixels, mode):
    """A PNG written with zlib alone (the decoded pixels are exact)."""
    h, w = len(pixels), len(pixels[0])
    raw = b''.join(b'\0' + bytes(v for px in row for v in (px if mode == 'rgb' else px[:1])) for row in pixels)
    def chunk(tag, body):
        return struct.pack('>I', len(body)) + tag + body + struct.pack('>I', zlib.crc32(tag + body) & 0xffffffff)
    color = 2 if mode == 'rgb' else 0
    return (b'\x89PNG\r\n\x1a\n' + chunk(b'IHDR', struct.pack('>IIBBBBB', w, h, 8, color, 0, 0, 0))
            + chunk(b'IDAT', zlib.compress(raw)) + chunk(b'IEND', b''))


def jpeg_bytes(pixels):
    im = PilImage.fromarray(np.array(pixels, dtype=np.uint8), 'RGB')
    out = io.BytesIO()
    im.save(out, format='JPEG', quality=95)
    return out.getvalue()


def image_fields(pixels, encoding):
    """Image data with 4 bytes of row padding, and the RGB (or grey) pixels expected."""
    h, w = len(pixels), len(pixels[0])
    bpp = {'mono8': 1, 'bgr8': 3, 'rgb8': 3}[encoding]
    step = w * bpp + 4
    data = bytearray(h * step)
    for y in range(h):
        for x in range(w):
            r, g, b = pixels[y][x]
            at = y * step + x * bpp
            if encoding == 'mono8':
                data[at] = r
            elif encoding == 'bgr8':
                data[at:at + 3] = bytes([b, g, r])
            else:
                data[at:at + 3] = bytes([r, g, b])
    expected = [[px[0]] if encoding == 'mono8' else px for row in pixels for px in row]
    return bytes(data), step, expected


def messages(data, layout_name, image_kind, ros1):
    """(topic, msgtype, stamp, fields dict) in time order; fields as plain dicts."""
    layout = LAYOUTS[layout_name]
    out = []
    expected = {'layout': layout_name, 'image': image_kind, 'topics': {}}
    def header(stamp, frame):
        sec, nsec = ns_to_stamp(stamp)
        h = dict(stamp=dict(sec=sec, nanosec=nsec), frame_id=frame)
        if ros1:
            h['seq'] = 0
        return h
    def expect(topic, value):
        expected['topics'].setdefault(topic, []).append(value)
    static = [dict(header=header(T0, t['parent']), child_frame_id=t['child'],
                   transform=dict(translation=dict(zip('xyz', t['translation'])),
                                  rotation=dict(zip('xyzw', t['rotation'])))) for t in data['tf_static']]
    out.append(('/tf_static', 'tf2_msgs/msg/TFMessage', T0, dict(transforms=static)))
    expect('/tf_static', dict(stamp=T0, transforms=data['tf_static']))
    for k, scan in enumerate(data['scans']):
        raw, row_step, fields, points = cloud_bytes(scan['points'], layout, nan_first=(k == 0))
        out.append(('/points', 'sensor_msgs/msg/PointCloud2', scan['stamp'], dict(
            header=header(scan['stamp'], 'lidar_link'), height=layout['height'], width=layout['width'],
            fields=fields, is_bigendian=layout['big_endian'], point_step=layout['point_step'],
            row_step=row_step, data=raw, is_dense=(k != 0))))
        expect('/points', dict(stamp=scan['stamp'], frame='lidar_link', points=points, dropped=1 if k == 0 else 0))
    cam = data['camera']
    for image in data['images']:
        stamp = image['stamp']
        if image_kind in ('mono8', 'bgr8'):
            raw, step, pixels = image_fields(image['pixels'], image_kind)
            out.append(('/camera/image_raw', 'sensor_msgs/msg/Image', stamp, dict(
                header=header(stamp, 'camera_optical_frame'), height=cam['height'], width=cam['width'],
                encoding=image_kind, is_bigendian=0, step=step, data=raw)))
            expect('/camera/image_raw', dict(stamp=stamp, pixels=pixels))
        else:
            raw = png_bytes(image['pixels'], 'rgb') if image_kind == 'png' else jpeg_bytes(image['pixels'])
            out.append(('/camera/image_raw/compressed', 'sensor_msgs/msg/CompressedImage', stamp, dict(
                header=header(stamp, 'camera_optical_frame'), format=f'rgb8; {image_kind} compressed bgr8',
                data=raw)))
            expect('/camera/image_raw/compressed', dict(stamp=stamp, pixels=[px for row in image['pixels'] for px in row]))
        k_ = cam['k']
        info = dict(header=header(stamp, 'camera_optical_frame'), height=cam['height'], width=cam['width'],
                    distortion_model='plumb_bob', k=k_, r=[1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0],
                    p=[k_[0], 0, k_[2], 0, 0, k_[4], k_[5], 0, 0, 0, 1.0, 0], binning_x=0, binning_y=0,
                    roi=dict(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))
        info['D' if ros1 else 'd'] = [0.0] * 5
        out.append(('/camera/camera_info', 'sensor_msgs/msg/CameraInfo', stamp, info))
        expect('/camera/camera_info', dict(stamp=stamp, k=k_))
    for s in data['imu']:
        out.append(('/imu', 'sensor_msgs/msg/Imu', s['stamp'], dict(
            header=header(s['stamp'], 'imu_link'), orientation=dict(x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=[-1.0] + [0.0] * 8, angular_velocity=dict(zip('xyz', s['gyro'])),
            angular_velocity_covariance=[0.0] * 9, linear_acceleration=dict(zip('xyz', s['accel'])),
            linear_acceleration_covariance=[0.0] * 9)))
        expect('/imu', s)
    for s in data['odom']:
        q = [0.0, 0.0, math.sin(s['yaw'] / 2), math.cos(s['yaw'] / 2)]
        out.append(('/odom', 'nav_msgs/msg/Odometry', s['stamp'], dict(
            header=header(s['stamp'], 'odom'), child_frame_id='base_link',
            pose=dict(pose=dict(position=dict(x=s['x'], y=s['y'], z=0.0), orientation=dict(zip('xyzw', q))),
                      covariance=[0.0] * 36),
            twist=dict(twist=dict(linear=dict(x=s['v'], y=0.0, z=0.0), angular=dict(x=0.0, y=0.0, z=s['omega'])),
                       covariance=[0.0] * 36))))
        expect('/odom', s)
    for s in data['truth']:
        out.append(('/ground_truth', 'geometry_msgs/msg/PoseStamped', s['stamp'], dict(
            header=header(s['stamp'], 'map'),
            pose=dict(position=dict(zip('xyz', s['position'])), orientation=dict(zip('xyzw', s['orientation']))))))
        expect('/ground_truth', s)
    out.sort(key=lambda m: m[2])
    return out, expected


def to_message(store, msgtype, value):
    """A rosbags message object from plain values, by the type's field definitions."""
    _, fields = store.fielddefs[msgtype]
    kwargs = {}
    for name, (node, desc) in fields:
        # ROS 1 spells CameraInfo's matrices D, K, R, P.
        v = value[name] if name in value else value[name.lower()]
        if node == 2:
            kwargs[name] = to_message(store, desc, v)
        elif node == 1:
            kwargs[name] = v
        else:
            (inner_node, inner_desc), _ = desc
            if inner_node == 2:
                kwargs[name] = [to_message(store, inner_desc, x) for x in v]
            elif inner_desc[0] == 'string':
                kwargs[name] = list(v)
            elif isinstance(v, (bytes, bytearray)):
                kwargs[name] = np.frombuffer(bytes(v), dtype=np.uint8)
            else:
                kwargs[name] = np.array(v, dtype=inner_desc[0])
    return store.types[msgtype](**kwargs)


def write_rosbag2(path, msgs, storage, compression=None):
    writer = Ros2Writer(path, version=8, storage_plugin=storage)
    if compression:
        writer.set_compression(compression, CompressionFormat.ZSTD)
    with writer:
        connections = {}
        for topic, msgtype, stamp, value in msgs:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=ROS2)
            raw = ROS2.serialize_cdr(to_message(ROS2, msgtype, value), msgtype)
            writer.write(connections[topic], stamp, raw)


def write_ros1(path, msgs, compression):
    writer = Ros1Writer(path)
    if compression:
        writer.set_compression(compression)
    with writer:
        connections = {}
        for topic, msgtype, stamp, value in msgs:
            if (topic, msgtype) not in connections:
                connections[topic, msgtype] = writer.add_connection(topic, msgtype, typestore=ROS1)
            raw = ROS1.serialize_ros1(to_message(ROS1, msgtype, value), msgtype)
            writer.write(connections[topic, msgtype], stamp, raw)


def write_two_types(out, data):
    """A damaged recording: /odom's Odometry published on /imu beside the IMU,
    one topic with two message types, which the readers must refuse."""
    msgs, _ = messages(data, 'ouster32', 'mono8', True)
    imu = [m for m in msgs if m[0] == '/imu'][:8]
    odom = [('/imu',) + m[1:] for m in msgs if m[0] == '/odom'][:4]
    write_ros1(out / 'ros1_two_types.bag', sorted(imu + odom, key=lambda m: m[2]), None)


def ros2_msgdef(msgtype):
    text, _ = ROS2.generate_msgdef(msgtype, ros_version=2)
    return text


def write_bare_mcap(path, msgs, compression):
    with open(path, 'wb') as f:
        writer = Mcap2Writer(f, chunk_size=4096, compression=compression)
        schemas = {}
        for seq, (topic, msgtype, stamp, value) in enumerate(msgs):
            if msgtype not in schemas:
                schemas[msgtype] = writer.register_msgdef(msgtype, ros2_msgdef(msgtype))
            writer.write_message(topic, schemas[msgtype], plain(value), log_time=stamp, publish_time=stamp, sequence=seq)
        writer.finish()


def plain(value):
    if isinstance(value, dict):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, list):
        return [plain(v) for v in value]
    return value


def main(out):
    out = Path(out)
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    data = make_data()
    plan = [
        # name, writer, layout, image
        ('rosbag2_mcap', 'ros2-mcap', 'ouster32', 'mono8'),
        ('rosbag2_sqlite3', 'ros2-sqlite3', 'velodyne64be', 'bgr8'),
        ('rosbag2_sqlite3_zstd_messages', 'ros2-sqlite3-message', 'ouster32', 'png'),
        ('rosbag2_mcap_zstd_files', 'ros2-mcap-file', 'velodyne64be', 'mono8'),
        ('bare_lz4.mcap', 'mcap-lz4', 'ouster32', 'png'),
        ('bare_zstd.mcap', 'mcap-zstd', 'velodyne64be', 'jpeg'),
        ('ros1_plain.bag', 'ros1', 'ouster32', 'bgr8'),
        ('ros1_lz4.bag', 'ros1-lz4', 'velodyne64be', 'mono8'),
        ('ros1_bz2.bag', 'ros1-bz2', 'ouster32', 'png'),
    ]
    manifest = dict(recordings={}, layouts={}, images=[dict(stamp=i['stamp'], pixels=[px for row in i['pixels'] for px in row]) for i in data['images']],
                    imu=data['imu'], odom=data['odom'], truth=data['truth'], tf_static=data['tf_static'],
                    camera=data['camera'], stamp0=T0,
                    # What Pillow (libjpeg) decodes the JPEG images to.
                    jpeg_pixels=[np.array(PilImage.open(io.BytesIO(jpeg_bytes(i['pixels']))).convert('RGB')).reshape(-1, 3).tolist()
                                 for i in data['images']])
    for name, how, layout, image in plan:
        ros1 = how.startswith('ros1')
        msgs, expected = messages(data, layout, image, ros1)
        path = out / name
        if how == 'ros2-mcap':
            write_rosbag2(path, msgs, StoragePlugin.MCAP)
        elif how == 'ros2-sqlite3':
            write_rosbag2(path, msgs, StoragePlugin.SQLITE3)
        elif how == 'ros2-sqlite3-message':
            write_rosbag2(path, msgs, StoragePlugin.SQLITE3, CompressionMode.MESSAGE)
        elif how == 'ros2-mcap-file':
            write_rosbag2(path, msgs, StoragePlugin.MCAP, CompressionMode.FILE)
        elif how == 'mcap-lz4':
            write_bare_mcap(path, msgs, CompressionType.LZ4)
        elif how == 'mcap-zstd':
            write_bare_mcap(path, msgs, CompressionType.ZSTD)
        else:
            fmt = {'ros1': None, 'ros1-lz4': Ros1Writer.CompressionFormat.LZ4,
                   'ros1-bz2': Ros1Writer.CompressionFormat.BZ2}[how]
            write_ros1(path, msgs, fmt)
        manifest['recordings'][name] = dict(layout=layout, image=image)
        manifest['layouts'][layout] = expected['topics']['/points']
    write_two_types(out, data)
    (out / 'expected.json').write_text(json.dumps(manifest, allow_nan=False, separators=(',', ':')))
    print(f'wrote {len(plan)} recordings to {out}')


if __name__ == '__main__':
    main(sys.argv[1] if len(sys.argv) > 1 else 'datasets/tests/data/recordings')
