"""Frames of spinning LiDARs as their drivers write them, cut from simulated drives.

Writes into OUT (default ``lidar_frames``):

- ``pandar64/000000.pcd``: a Hesai Pandar64 frame, binary_compressed PCD with x, y, z, intensity
  (0-255) and an absolute ``timestamp``, no ring field, the points shuffled; its front camera's
  image ``pandar64/images/000000.jpg`` and calibration ``pandar64/front.json`` (K, Brown-Conrady
  distortion, the LiDAR-to-camera extrinsic ``T_camera_lidar``);
- ``os1/os1_000001.las``: an Ouster OS1-128 frame, LAS 1.4 with ``gps_time`` and a ``ring``
  field numbered from the lowest beam up.

Each frame is put back into the sensor's own frame point by point (by the sensor's pose when the
point was measured). Usage (docs/import.md)::

    .venv/bin/python docs/examples/lidar_frames.py lidar_frames
    .venv/bin/guardrail import lidar lidar_frames/pandar64/000000.pcd --sensor pandar64 \\
        --camera lidar_frames/pandar64/front.json --images lidar_frames/pandar64/images \\
        --out drives/pandar64
    .venv/bin/guardrail import lidar lidar_frames/os1/os1_000001.las --out drives/os1

The tests (tests/importers/test_import_lidar.py) import these frames.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import laspy
import numpy as np
import open3d as o3d

from guardrail_core.formats.drive import Drive, load_drive
from guardrail_core.geom.frames import invert_transform
from guardrail_core.synth.scene import load_scene_spec
from guardrail_core.synth.simulate import SimulationOptions, simulate_drive


def simulate(sensor: str, out: Path) -> Drive:
    """The test street, scanned by the preset ``sensor``, a frame every 20 m."""
    spec = load_scene_spec("test_straight")
    spec["scanner"] = {"kind": "multibeam", "sensor": sensor, "frame_every_m": 20}
    options = SimulationOptions(image_every_m=8.0, image_size=(480, 360))
    simulate_drive(spec, out, seed=11, options=options, progress=False)
    return load_drive(out)


def sensor_frame(drive: Drive, frame: int, seed: int) -> dict[str, np.ndarray]:
    """Frame ``frame`` of a simulated drive in the sensor's frame (each point by the sensor's
    pose when it was measured), shuffled: xyz, time, intensity, ring (0 = highest beam), class."""
    rows = drive.scanner.rings + 1
    mine = np.flatnonzero(drive.points.rotation // rows == frame)
    mine = mine[np.random.default_rng(seed).permutation(len(mine))]
    t = drive.points.gps_time[mine]
    rotation, position = drive.trajectory.poses(t)
    mount = drive.scanner.T_vehicle_scanner
    r_ws = rotation @ mount[:3, :3]
    origin = position + rotation @ mount[:3, 3]
    # On the drive's 0.1 mm grid (its LAS scale), so that a point's copy finds it exactly.
    xyz = np.round(np.einsum("nji,nj->ni", r_ws, drive.points.xyz[mine] - origin), 4)
    assert drive.truth is not None
    return {
        "xyz": xyz,
        "time": t,
        "intensity": drive.points.intensity[mine],
        "ring": drive.points.rotation[mine] % rows,
        "class": drive.truth.point_class[mine],
        "t_mid": np.median(t),
    }


def T_world_sensor(drive: Drive, t: float) -> np.ndarray:
    """(4, 4) the sensor's pose at GPS time ``t``."""
    return drive.trajectory.T_world_vehicle(t) @ drive.scanner.T_vehicle_scanner


def write_pandar64_frame(root: Path) -> dict:
    """A Pandar64 frame into ``root`` as a binary_compressed PCD (x, y, z, intensity 0-255,
    absolute timestamp; no ring), its front camera's image and a calibration JSON with the
    camera's distortion and its LiDAR-to-camera extrinsic; returns what was written and the
    frame's truth (:func:`sensor_frame`)."""
    drive = simulate("pandar64", root / "sim")
    frame = sensor_frame(drive, 0, seed=1)
    cloud = o3d.t.geometry.PointCloud()
    cloud.point.positions = o3d.core.Tensor(frame["xyz"].astype(np.float32))
    cloud.point.intensity = o3d.core.Tensor(
        (frame["intensity"] / 257.0)[:, None].astype(np.float32)
    )
    cloud.point.timestamp = o3d.core.Tensor(frame["time"][:, None])
    pcd = root / "000000.pcd"
    assert o3d.t.io.write_point_cloud(str(pcd), cloud, write_ascii=False, compressed=True)
    # The front image nearest the frame, and the camera's pose on the sensor at that moment.
    image = min(
        (r for r in drive.images if r.camera == "front"),
        key=lambda r: abs(r.gps_time - frame["t_mid"]),
    )
    camera = drive.cameras["front"]
    T_sensor_camera = invert_transform(T_world_sensor(drive, frame["t_mid"])) @ image.T_world_camera
    calibration = {
        "camera_name": "front",
        "camera_matrix": camera.K.tolist(),
        "distortion_model": "plumb_bob",
        "distortion_coefficients": camera.dist.tolist(),
        "image_width": camera.width,
        "image_height": camera.height,
        "T_camera_lidar": invert_transform(T_sensor_camera).tolist(),
    }
    (root / "front.json").write_text(json.dumps(calibration, indent=1))
    images = root / "images"
    images.mkdir(parents=True)
    (images / "000000.jpg").write_bytes((drive.root / image.file).read_bytes())
    return {"root": root, "pcd": pcd, "frame": frame, "camera": calibration}


def write_os1_frame(root: Path) -> dict:
    """An OS1-128 frame into ``root`` as LAS 1.4 with gps_time and a ring field numbered from
    the lowest beam up (as Velodyne drivers number them); returns its path and truth."""
    drive = simulate("os1-128", root / "sim")
    frame = sensor_frame(drive, 1, seed=2)
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = [1e-4] * 3
    header.offsets = [0.0] * 3
    header.add_extra_dim(laspy.ExtraBytesParams(name="ring", type=np.uint16))
    las = laspy.LasData(header)
    las.x, las.y, las.z = frame["xyz"].T
    las.gps_time = frame["time"]
    las.intensity = frame["intensity"]
    las.ring = (drive.scanner.rings - 1 - frame["ring"]).astype(np.uint16)
    path = root / "os1_000001.las"
    las.write(path)
    return {"root": root, "las": path, "frame": frame}


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description="Write example frames of two spinning LiDARs.")
    parser.add_argument("out", nargs="?", default="lidar_frames", help="folder to write into")
    out = Path(parser.parse_args(argv).out)
    write_pandar64_frame(out / "pandar64")
    write_os1_frame(out / "os1")
    print(f"wrote a Pandar64 PCD frame with its camera and an OS1-128 LAS frame into {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
