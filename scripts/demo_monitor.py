#!/usr/bin/env python3
"""Watches a running head (the demo) for a set time: prints a progress line every two seconds
and writes the results folder (calibration YAMLs, status, image snapshots) at the end.

Usage: demo_monitor.py --duration S --out DIR [--ns stereo]
"""
import argparse
import math
import os
import struct
import sys
import threading
import time
import zlib

import rospy
from sensor_msgs.msg import CameraInfo, Image
from embedded_calibration_stereo.msg import CalibrationMode


def write_png(path, width, height, channels, data):
    """Minimal PNG writer (8-bit grey or RGB) so the demo needs no imaging library."""
    color = {1: 0, 3: 2}[channels]
    stride = width * channels
    raw = b"".join(b"\x00" + data[y * stride:(y + 1) * stride] for y in range(height))

    def chunk(tag, payload):
        return (struct.pack(">I", len(payload)) + tag + payload +
                struct.pack(">I", zlib.crc32(tag + payload) & 0xFFFFFFFF))

    tmp = path + ".tmp"
    with open(tmp, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n")
        f.write(chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, color, 0, 0, 0)))
        f.write(chunk(b"IDAT", zlib.compress(raw, 6)))
        f.write(chunk(b"IEND", b""))
    os.replace(tmp, path)


def camera_yaml(info, name):
    """camera_calibration_parsers' YAML layout, readable by camera_info_manager."""
    def matrix(rows, cols, values):
        return ("  rows: %d\n  cols: %d\n  data: [%s]\n" %
                (rows, cols, ", ".join("%.10g" % v for v in values)))
    return ("image_width: %d\nimage_height: %d\ncamera_name: %s\n" % (info.width, info.height, name) +
            "camera_matrix:\n" + matrix(3, 3, info.K) +
            "distortion_model: %s\n" % (info.distortion_model or "plumb_bob") +
            "distortion_coefficients:\n" + matrix(1, len(info.D), info.D) +
            "rectification_matrix:\n" + matrix(3, 3, info.R) +
            "projection_matrix:\n" + matrix(3, 4, info.P))


class Monitor:
    """Callbacks run on rospy's subscriber threads; the main thread reads under self.lock."""

    def __init__(self, ns):
        self.lock = threading.Lock()
        self.frames = 0
        self.light_on_frames = 0
        self.mode = None
        self.latest = {}
        self.first_image_time = None
        self.last_image_time = None
        self.last_image = None
        self.last_light_on_image = None
        self.settled_light_on_stamps = set()  # stamps of settled light-on frames (bounded)
        self.pending_images = {}  # stamp -> image, until its calibration_mode arrives
        sub = lambda topic, cls, key: rospy.Subscriber(
            ns + "/" + topic, cls, lambda m: self.store(key, m), queue_size=2)
        self.subs = [
            sub("left/camera_info", CameraInfo, "left"),
            sub("right/camera_info", CameraInfo, "right"),
            sub("ground_truth/left/camera_info", CameraInfo, "gt_left"),
            sub("ground_truth/right/camera_info", CameraInfo, "gt_right"),
            rospy.Subscriber(ns + "/calibration_mode", CalibrationMode, self.on_mode, queue_size=10),
            rospy.Subscriber(ns + "/left/image_raw", Image, self.on_image, queue_size=2,
                             buff_size=2 ** 24),
        ]

    def store(self, key, msg):
        with self.lock:
            self.latest[key] = msg

    def on_mode(self, msg):
        with self.lock:
            self.mode = msg
            if msg.light_on:
                self.light_on_frames += 1
            if msg.light_on and msg.settled:
                image = self.pending_images.pop(msg.header.stamp, None)
                if image is not None:
                    self.last_light_on_image = image
                else:
                    self.settled_light_on_stamps.add(msg.header.stamp)
                    if len(self.settled_light_on_stamps) > 100:
                        self.settled_light_on_stamps.pop()

    def on_image(self, msg):
        now = time.time()
        with self.lock:
            self.frames += 1
            self.first_image_time = self.first_image_time or now
            self.last_image_time = now
            self.last_image = msg
            # The image and its calibration_mode share a stamp but arrive in either order.
            if msg.header.stamp in self.settled_light_on_stamps:
                self.settled_light_on_stamps.discard(msg.header.stamp)
                self.last_light_on_image = msg
            else:
                self.pending_images = {msg.header.stamp: msg}

    def focal_error_percent(self, side):
        est, gt = self.latest.get(side), self.latest.get("gt_" + side)
        if est is None or gt is None or gt.K[0] == 0 or est.K[0] == 0:
            return float("nan")
        return 100.0 * abs(est.K[0] - gt.K[0]) / gt.K[0]


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--duration", type=float, default=60.0)
    parser.add_argument("--out", required=True)
    parser.add_argument("--ns", default="stereo")
    args = parser.parse_args(rospy.myargv()[1:])
    rospy.init_node("demo_monitor", anonymous=True)
    os.makedirs(args.out, exist_ok=True)
    mon = Monitor("/" + args.ns.strip("/"))

    start = time.time()
    last_frames, last_t = 0, start
    while not rospy.is_shutdown() and time.time() - start < args.duration:
        time.sleep(2.0)  # progress cadence only; nothing waits on this for correctness
        now = time.time()
        with mon.lock:
            frames = mon.frames
            mode = mon.mode
            err_l, err_r = mon.focal_error_percent("left"), mon.focal_error_percent("right")
        fps = (frames - last_frames) / (now - last_t)
        last_frames, last_t = frames, now
        print("[%5.1f s] %5.1f fps  light %s  epoch %s  fx error vs truth L %.3f%% R %.3f%%" % (
            now - start, fps, "on " if mode and mode.light_on else "off",
            mode.calibration_epoch if mode else "-", err_l, err_r), flush=True)

    with mon.lock:
        latest = dict(mon.latest)
        images = {"left_snapshot.png": mon.last_image,
                  "left_snapshot_light_on.png": mon.last_light_on_image}
        frames, light_frames = mon.frames, mon.light_on_frames
        mode = mon.mode
        span = (mon.last_image_time or 0) - (mon.first_image_time or 0)
    for key in ("left", "right", "gt_left", "gt_right"):
        if key in latest:
            name = key.replace("gt_", "ground_truth_")
            with open(os.path.join(args.out, name + ".yaml"), "w") as f:
                f.write(camera_yaml(latest[key], name))
    for file_name, image in images.items():
        if image is None or image.encoding not in ("mono8", "bgr8", "rgb8"):
            continue
        channels = 1 if image.encoding == "mono8" else 3
        data = bytes(image.data)
        if channels == 3 and image.encoding == "bgr8":
            data = b"".join(data[i + 2:i + 3] + data[i + 1:i + 2] + data[i:i + 1]
                            for i in range(0, len(data), 3))
        write_png(os.path.join(args.out, file_name), image.width, image.height, channels, data)
    # Mean over the time images flowed, so start-up does not count against the rate.
    mean_fps = (frames - 1) / span if frames > 1 and span > 0 else 0.0
    with open(os.path.join(args.out, "status.yaml"), "w") as f:
        f.write("duration_s: %.1f\nframes: %d\nmean_fps: %.2f\nlight_on_frames: %d\n"
                "calibration_epoch: %s\n" % (time.time() - start, frames, mean_fps, light_frames,
                                             mode.calibration_epoch if mode else "null"))
    print("demo: %d frames, mean %.1f fps, %d with the light on; results in %s" % (
        frames, mean_fps, light_frames, args.out), flush=True)
    return 0 if frames > 0 else 1


if __name__ == "__main__":
    sys.exit(main())
