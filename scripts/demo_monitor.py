#!/usr/bin/env python3
"""Watches a running head (the demo) for a set time: prints a progress line every two seconds,
injects a drift into the simulated rig (a 5 % zoom and a 0.3 deg rotation of the right camera)
and writes the results folder (calibration YAMLs, status, calibration-error timeline, image and
disparity snapshots) at the end.

Usage: demo_monitor.py --duration S --out DIR [--ns stereo] [--drift-at S]
"""
import argparse
import math
import os
import struct
import sys
import threading
import time
import zlib

import numpy as np
import rospy
from sensor_msgs.msg import CameraInfo, Image
from stereo_msgs.msg import DisparityImage
from embedded_calibration_stereo.msg import CalibrationMode, CalibrationStatus
from embedded_calibration_stereo.srv import SetRigDrift, SetRigDriftRequest


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


def colourise_disparity(msg):
    """DisparityImage -> RGB bytes (jet-like ramp, near = red, invalid = black)."""
    d = np.frombuffer(bytes(msg.image.data), dtype=np.float32).reshape(msg.image.height, msg.image.width)
    valid = np.isfinite(d) & (d >= msg.min_disparity)
    t = np.clip((d - msg.min_disparity) / max(msg.max_disparity - msg.min_disparity, 1e-6), 0, 1)
    rgb = np.stack([np.clip(1.5 - np.abs(4 * t - 3), 0, 1),
                    np.clip(1.5 - np.abs(4 * t - 2), 0, 1),
                    np.clip(1.5 - np.abs(4 * t - 1), 0, 1)], axis=-1)
    rgb[~valid] = 0
    return (rgb * 255).astype(np.uint8).tobytes(), float(valid.mean())


def calibration_errors(est, gt):
    """fx error (%) of each camera and baseline error (%) of a published pair vs the truth."""
    if est[0] is None or est[1] is None or gt[0] is None or gt[1] is None or gt[0].K[0] == 0:
        return None
    fx = [100.0 * abs(e.K[0] - g.K[0]) / g.K[0] for e, g in zip(est, gt)]
    baseline = lambda right: -right.P[3] / right.P[0] if right.P[0] else float("nan")
    b_err = 100.0 * abs(baseline(est[1]) - baseline(gt[1])) / baseline(gt[1])
    return fx[0], fx[1], b_err


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
            rospy.Subscriber(ns + "/disparity", DisparityImage, self.on_disparity, queue_size=2,
                             buff_size=2 ** 24),
            sub("calibration/status", CalibrationStatus, "status"),
        ]
        self.disparities = 0
        self.last_disparity = None
        self.light_off_since = None  # wall time of the last light on -> off switch

    def store(self, key, msg):
        with self.lock:
            self.latest[key] = msg

    def on_mode(self, msg):
        with self.lock:
            if self.mode is not None and self.mode.light_on and not msg.light_on:
                self.light_off_since = time.time()
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

    def on_disparity(self, msg):
        with self.lock:
            self.disparities += 1
            self.last_disparity = msg

    def errors(self):
        """Called with self.lock held."""
        get = self.latest.get
        return calibration_errors((get("left"), get("right")), (get("gt_left"), get("gt_right")))


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--duration", type=float, default=60.0)
    parser.add_argument("--out", required=True)
    parser.add_argument("--ns", default="stereo")
    parser.add_argument("--drift-at", type=float, default=None,
                        help="seconds after start of the drift (default: 3 s after the first light "
                             "window that ends after a quarter of the run)")
    args = parser.parse_args(rospy.myargv()[1:])
    rospy.init_node("demo_monitor", anonymous=True)
    os.makedirs(args.out, exist_ok=True)
    mon = Monitor("/" + args.ns.strip("/"))

    drift_at = args.drift_at  # None: chosen between two light windows, so its effect shows
    drifted = False
    timeline = []  # (t, fx error L %, fx error R %, baseline error %, epoch)
    start = time.time()
    last_frames, last_disp, last_t = 0, 0, start
    while not rospy.is_shutdown() and time.time() - start < args.duration:
        time.sleep(0.25)  # progress cadence only; nothing waits on this for correctness
        now = time.time()
        if drift_at is None:
            with mon.lock:
                off_since = mon.light_off_since
            if off_since is not None and off_since - start >= args.duration / 4.0:
                drift_at = off_since - start + 3.0
        if not drifted and drift_at is not None and now - start >= drift_at:
            drifted = True
            try:
                service = "/" + args.ns.strip("/") + "/sim/set_drift"
                rospy.wait_for_service(service, 5.0)
                request = SetRigDriftRequest(focal_scale=1.05, right_rotation_deg=[0.0, 0.3, 0.0])
                answer = rospy.ServiceProxy(service, SetRigDrift)(request)
                print("[%5.1f s] DRIFT: 5 %% zoom and 0.3 deg right-camera rotation (%s)" % (
                    now - start, "ok" if answer.success else answer.message), flush=True)
            except (rospy.ROSException, rospy.ServiceException) as e:
                print("demo: could not drift the rig: %s" % e, flush=True)
        if now - last_t < 2.0:
            continue
        with mon.lock:
            frames, disparities = mon.frames, mon.disparities
            mode = mon.mode
            errors = mon.errors()
        fps = (frames - last_frames) / (now - last_t)
        dps = (disparities - last_disp) / (now - last_t)
        last_frames, last_disp, last_t = frames, disparities, now
        epoch = mode.calibration_epoch if mode else -1
        if errors:
            timeline.append((now - start,) + errors + (epoch,))
        print("[%5.1f s] %5.1f fps  disparity %5.1f Hz  light %s  epoch %s  calibration error vs truth:"
              " fx L %s R %s baseline %s" % (
                  now - start, fps, dps, "on " if mode and mode.light_on else "off",
                  epoch if mode else "-",
                  *(("%.3f%%" % e) if errors else "-" for e in (errors or (0, 0, 0)))), flush=True)

    with mon.lock:
        disparity = mon.last_disparity
        disparities = mon.disparities
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
    if disparity is not None:
        rgb, valid_fraction = colourise_disparity(disparity)
        write_png(os.path.join(args.out, "disparity.png"), disparity.image.width,
                  disparity.image.height, 3, rgb)
    with open(os.path.join(args.out, "calibration_error.csv"), "w") as f:
        f.write("time_s,fx_error_left_percent,fx_error_right_percent,baseline_error_percent,epoch\n")
        for row in timeline:
            f.write("%.1f,%.4f,%.4f,%.4f,%d\n" % row)
    # Mean over the time images flowed, so start-up does not count against the rate.
    mean_fps = (frames - 1) / span if frames > 1 and span > 0 else 0.0
    status = latest.get("status")
    drift_at = drift_at if drifted else float("nan")
    before = [r for r in timeline if drifted and r[0] < drift_at]
    after = [r for r in timeline if drifted and r[0] >= drift_at]
    worst_after = max((max(r[1:4]) for r in after), default=float("nan"))
    final = timeline[-1] if timeline else None
    with open(os.path.join(args.out, "status.yaml"), "w") as f:
        f.write("duration_s: %.1f\nframes: %d\nmean_fps: %.2f\nlight_on_frames: %d\n"
                "disparity_images: %d\ncalibration_epoch: %s\ndrift_at_s: %.1f\n"
                "worst_error_after_drift_percent: %.4f\n" % (
                    time.time() - start, frames, mean_fps, light_frames, disparities,
                    mode.calibration_epoch if mode else "null", drift_at, worst_after))
        if final:
            f.write("final_fx_error_left_percent: %.4f\nfinal_fx_error_right_percent: %.4f\n"
                    "final_baseline_error_percent: %.4f\n" % final[1:4])
        if status is not None:
            f.write("last_calibration_status:\n  epoch: %d\n  accepted: %s\n  reason: \"%s\"\n"
                    "  frames_used: %d\n  rms_left_px: %.4f\n  rms_right_px: %.4f\n"
                    "  solve_ms: %.1f\n" % (status.epoch, str(status.accepted).lower(),
                                             status.reason.replace('"', "'"), status.frames_used,
                                             status.rms_left_px, status.rms_right_px, status.solve_ms))
    print("demo: %d frames, mean %.1f fps, %d disparity images, %d frames with the light on" % (
        frames, mean_fps, disparities, light_frames), flush=True)
    if before:
        print("demo: calibration error before the drift: fx L %.3f%% R %.3f%% baseline %.3f%%" % before[-1][1:4])
    if after:
        print("demo: worst error after the drift: %.3f%%; final: fx L %.3f%% R %.3f%% baseline %.3f%% (epoch %d)" % (
            (worst_after,) + final[1:5]), flush=True)
    print("demo: results in %s" % args.out, flush=True)
    return 0 if frames > 0 else 1


if __name__ == "__main__":
    sys.exit(main())
