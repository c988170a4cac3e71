#!/usr/bin/env python3
"""Watches a running head (the demo) for a set time, drives the simulated rig through a drift
script (a 5 % zoom step, a slow thermal rotation of the right camera, a knock), prints a progress
line every two seconds and writes the results folder at the end: calibration YAMLs, status,
calibration-error timeline (CSV and PNG plot with the drift events), image and disparity
snapshots, an overview picture (a light-on frame, its separated scene and its disparity side by
side), the calibration health (state in the progress lines and under the plot, lit frames while
GOOD, how long each drift event took to be seen and corrected), and a final report saying whether
the calibration after the drift meets the accuracy targets for depth against ground truth.

The accuracy is given in the terms a depth user feels (docs/core.md, "Stereo accuracy"): after
rectifying with the published calibration, the vertical misalignment of true correspondences and
their disparity bias (px RMS over the field of view), and the depth error at 1, 2, 5 and 10 m
(%), true (against the simulator's truth, computed by the stereo_accuracy tool) and predicted
(by the calibrator from its solve's covariance, calibration/status).

Usage: demo_monitor.py --duration S --out DIR [--ns stereo] [--zoom-at S] [--accuracy-tool PATH]
Times count from the first camera frame.
"""
import argparse
import math
import os
import shutil
import struct
import subprocess
import sys
import threading
import time
import zlib

import numpy as np
import rospy
from sensor_msgs.msg import CameraInfo, Image
from stereo_msgs.msg import DisparityImage
from embedded_calibration_stereo.msg import CalibrationHealth, CalibrationMode, CalibrationStatus
from embedded_calibration_stereo.srv import SetRigDrift, SetRigDriftRequest

# The calibrator's accuracy targets, per error key of calibration_errors().
BOUNDS = {
    "fx_pct": (0.05, "%"), "fy_pct": (0.05, "%"), "cx_px": (0.3, "px"), "cy_px": (0.3, "px"),
    "k1": (0.005, ""), "baseline_pct": (0.1, "%"), "rotation_deg": (0.01, "deg"),
}
ERROR_KEYS = list(BOUNDS)

# The accuracy targets for depth of the published calibration after the drift.
ACCURACY_BOUNDS = {
    "misalignment_px": (0.05, "px"), "bias_px": (0.05, "px"), "depth_10m_pct": (0.7, "%"),
    "fx_pct": (0.05, "%"), "baseline_pct": (0.1, "%"),
}
DEPTHS_M = (1, 2, 5, 10)


class AccuracyTool:
    """The stereo_accuracy tool as a child process: one request line per evaluation."""

    def __init__(self, path):
        self.process = None
        self.problem = None
        if not path or not os.access(path, os.X_OK):
            self.problem = "stereo_accuracy tool not found (%s)" % (path or "not given")
            return
        self.process = subprocess.Popen([path], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                        universal_newlines=True, bufsize=1)

    def evaluate(self, estimate, truth):
        """estimate, truth: (left, right) CameraInfo. Returns a dict of true figures or None."""
        if self.process is None or None in estimate or None in truth:
            return None
        numbers = [estimate[0].width, estimate[0].height]
        for info in tuple(estimate) + tuple(truth):
            d = list(info.D[:5]) + [0.0] * (5 - len(info.D[:5]))
            numbers += list(info.K) + d + list(info.R) + list(info.P)
        try:
            self.process.stdin.write(" ".join("%.17g" % v for v in numbers) + "\n")
            answer = self.process.stdout.readline().split()
        except (BrokenPipeError, OSError) as e:
            self.problem, self.process = "stereo_accuracy stopped: %s" % e, None
            return None
        if not answer or answer[0] != "ok":
            self.problem = "stereo_accuracy: %s" % " ".join(answer)
            return None
        v = [float(x) for x in answer[1:]]
        figures = {"misalignment_px": v[0], "misalignment_max_px": v[1], "bias_px": v[2], "bias_max_px": v[3]}
        for depth, value in zip(DEPTHS_M, v[4:8]):
            figures["depth_%dm_pct" % depth] = value
        return figures

    def close(self):
        if self.process is not None:
            self.process.stdin.close()
            self.process.wait()


HEALTH_STATES = ["UNKNOWN", "GOOD", "DEGRADED", "BAD"]  # CalibrationHealth.state


def health_name(health):
    return HEALTH_STATES[health.state] if health is not None and health.state < 4 else "-"

def predicted_figures(status):
    """The calibrator's predicted figures of a CalibrationStatus (None without a prediction)."""
    if status is None or not status.accepted or status.predicted_misalignment_rms_px <= 0:
        return None
    figures = {"misalignment_px": status.predicted_misalignment_rms_px,
               "bias_px": status.predicted_disparity_bias_rms_px}
    for depth, value in zip(status.predicted_depths_m, status.predicted_depth_error_pct):
        figures["depth_%dm_pct" % int(round(depth))] = value
    return figures


def format_accuracy(true, predicted):
    def part(key, unit):
        text = "%.3f" % true[key]
        if predicted and key in predicted:
            text += " (pred %.3f)" % predicted[key]
        return text + unit
    return "misalign %s  bias %s  depth err 1/2/5/10 m %s %%" % (
        part("misalignment_px", " px"), part("bias_px", " px"),
        "/".join("%.2f" % true["depth_%dm_pct" % d] for d in DEPTHS_M))


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


def image_rgb_or_grey(image):
    """sensor_msgs/Image (mono8, bgr8, rgb8) -> (H, W) grey or (H, W, 3) RGB uint8 array, or None."""
    if image is None or image.encoding not in ("mono8", "bgr8", "rgb8"):
        return None
    channels = 1 if image.encoding == "mono8" else 3
    pixels = np.frombuffer(bytes(image.data), np.uint8).reshape(image.height, image.step)
    pixels = pixels[:, :image.width * channels].reshape(image.height, image.width, channels)
    if image.encoding == "bgr8":
        pixels = pixels[:, :, ::-1]
    return np.ascontiguousarray(pixels[:, :, 0] if channels == 1 else pixels)


def plot_overview(path, raw, scene, disparity, same_stamp, width_px=1200):
    """Side by side and labelled: a light-on frame, its separated scene and a colourised
    disparity, about width_px wide. False when matplotlib is missing."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    rgb, _ = colourise_disparity(disparity)
    panels = [
        (image_rgb_or_grey(raw), "light on: the six boards over the scene (left/image_raw)"),
        (image_rgb_or_grey(scene), "separated scene (left/image_scene)"),
        (np.frombuffer(rgb, np.uint8).reshape(disparity.image.height, disparity.image.width, 3),
         "disparity %s (red near, blue far, black invalid)" % ("of this frame" if same_stamp else "(latest)")),
    ]
    dpi = 100.0
    width_in = width_px / dpi
    panel_h = (width_in / 3.0) * raw.height / float(raw.width)
    fig, axes = plt.subplots(1, 3, figsize=(width_in, panel_h + 0.35), dpi=dpi)
    for ax, (pixels, title) in zip(axes, panels):
        if pixels.ndim == 2:
            ax.imshow(pixels, cmap="gray", vmin=0, vmax=255, interpolation="antialiased")
        else:
            ax.imshow(pixels, interpolation="antialiased")
        ax.set_title(title, fontsize=8.5)
        ax.axis("off")
    fig.subplots_adjust(left=0.003, right=0.997, bottom=0.005, top=panel_h / (panel_h + 0.35) - 0.01,
                        wspace=0.015)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return True


def _rotation(values):
    return np.array(values, dtype=float).reshape(3, 3)


def stereo_geometry(left, right):
    """right_from_left rotation and baseline (m) of a rectified CameraInfo pair (Bouguet R, P):
    p_rect = R1 p_left, p_rect = R2 p_right, so right_from_left = R2^T R1."""
    rotation = _rotation(right.R).T @ _rotation(left.R)
    t_rect = np.array([right.P[3] / right.P[0], right.P[7] / right.P[5], right.P[11]])
    return rotation, float(np.linalg.norm(t_rect))


def calibration_errors(est, gt):
    """Errors of a published CameraInfo pair against the truth, worst of both cameras:
    fx, fy (%), cx, cy (px), k1 (absolute), baseline (%), stereo rotation (deg)."""
    if any(m is None for m in est + gt) or gt[0].K[0] == 0 or est[1].P[0] == 0 or gt[1].P[0] == 0:
        return None
    pairs = list(zip(est, gt))
    errors = {
        "fx_pct": max(100.0 * abs(e.K[0] - g.K[0]) / g.K[0] for e, g in pairs),
        "fy_pct": max(100.0 * abs(e.K[4] - g.K[4]) / g.K[4] for e, g in pairs),
        "cx_px": max(abs(e.K[2] - g.K[2]) for e, g in pairs),
        "cy_px": max(abs(e.K[5] - g.K[5]) for e, g in pairs),
        "k1": max(abs((e.D[0] if e.D else 0.0) - (g.D[0] if g.D else 0.0)) for e, g in pairs),
    }
    r_est, b_est = stereo_geometry(*est)
    r_gt, b_gt = stereo_geometry(*gt)
    errors["baseline_pct"] = 100.0 * abs(b_est - b_gt) / b_gt
    cos_angle = np.clip((np.trace(r_est @ r_gt.T) - 1.0) / 2.0, -1.0, 1.0)
    errors["rotation_deg"] = math.degrees(math.acos(cos_angle))
    return errors


def format_errors(errors):
    errors = {k: (v if abs(v) >= 1e-9 else 0.0) for k, v in errors.items()}  # no 1e-14 noise
    unit = lambda k: BOUNDS[k][1] if BOUNDS[k][1] in ("%", "") else " " + BOUNDS[k][1]
    return "  ".join("%s %.3g%s" % (k.rsplit("_", 1)[0] if BOUNDS[k][1] else k, errors[k], unit(k))
                     for k in ERROR_KEYS)


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


class DriftScript:
    """The demo's drift events on the sim/set_drift service (absolute requests: each call
    replaces the previous drift state except the knock, which is added once). The thermal
    rotation and the knock follow the zoom (zoom_at s, default a third of the run) at fixed
    fractions of the run: the demo calibrates on demand (when calibration/health leaves GOOD),
    so runs of 60 s see a light window after the knock. An event fires only while the light is
    off, so no calibration window mixes two rigs. Runs on the main thread only."""

    THERMAL_RATE_DEG_PER_S = 0.01
    ZOOM = 1.05

    def __init__(self, ns, duration, zoom_at, fps):
        self.service = ns + "/sim/set_drift"
        # The simulator turns the camera by its own clock (frame count / fps), which falls behind
        # the wall clock when frames are rendered slower than fps: the rotation held at the end of
        # the ramp is the one the simulator reached, counted in its frames.
        self.fps = fps
        thermal_start = zoom_at + 0.2 * duration
        thermal_stop = zoom_at + 0.35 * duration
        self.pending = [
            (zoom_at, "zoom", "5 % zoom step (both cameras)", self._zoom),
            (thermal_start, "thermal start", "thermal rotation of the right camera starts, %.3f deg/s"
             % self.THERMAL_RATE_DEG_PER_S, self._thermal_start),
            (thermal_stop, "thermal stop", "", self._thermal_stop),
            (zoom_at + 0.45 * duration, "knock", "knock: 0.07 deg and 1 mm extrinsic change", self._knock),
        ]
        self.fired = []  # (t, short name)
        self.thermal_started_at_frame = None
        self.held_rotation_deg = 0.0  # right-camera rotation (y) reached when the ramp stopped

    def _zoom(self, frame):
        return SetRigDriftRequest(focal_scale=self.ZOOM)

    def _thermal_start(self, frame):
        self.thermal_started_at_frame = frame
        return SetRigDriftRequest(focal_scale=self.ZOOM, thermal_rate_deg_per_s=self.THERMAL_RATE_DEG_PER_S)

    def _thermal_stop(self, frame):
        # Holds the rotation reached (y axis, as the thermal drift turns), rate back to zero.
        self.held_rotation_deg = self.THERMAL_RATE_DEG_PER_S * (frame - self.thermal_started_at_frame) / self.fps
        return self._held()

    def _held(self):
        return SetRigDriftRequest(focal_scale=self.ZOOM, right_rotation_deg=[0.0, self.held_rotation_deg, 0.0])

    def _knock(self, frame):
        request = self._held()
        request.knock_rotation_deg = [0.04, -0.03, 0.05]
        request.knock_translation_m = [0.0008, 0.0003, -0.0005]
        return request

    def last_event_time(self):
        return self.fired[-1][0] if self.fired else None

    def step(self, t, light_on, frame):
        """Fires the next due event (due by the wall clock t; `frame`: the driver's frames so
        far); returns its progress line or None."""
        if not self.pending or t < self.pending[0][0] or light_on:
            return None
        _, name, description, make = self.pending.pop(0)
        request = make(frame)
        try:
            rospy.wait_for_service(self.service, 5.0)
            answer = rospy.ServiceProxy(self.service, SetRigDrift)(request)
            outcome = "ok" if answer.success else "refused: " + answer.message
        except (rospy.ROSException, rospy.ServiceException) as e:
            outcome = "failed: %s" % e
        self.fired.append((t, name))
        if name == "thermal stop":
            description = "thermal rotation stops (%.3f deg reached)" % self.held_rotation_deg
        return "[%5.1f s] DRIFT: %s (%s)" % (t, description, outcome)


class Monitor:
    """Callbacks run on rospy's subscriber threads; the main thread reads under self.lock."""

    def __init__(self, ns):
        self.lock = threading.Lock()
        self.frames = 0
        self.modes = 0  # calibration_mode messages: one per driver frame
        self.light_on_frames = 0
        self.mode = None
        self.latest = {}
        self.first_image_time = None
        self.last_image_time = None
        self.last_image = None
        self.last_light_off_image = None  # the scene alone
        self.last_light_on_image = None   # settled: the boards over the scene
        # The image and its calibration_mode share a stamp but arrive in either order: each
        # waits here (a few, bounded) for its partner.
        self.unpaired_images = {}
        self.unpaired_modes = {}
        self.disparities = 0
        self.last_disparity = None
        # For the overview picture: the settled light-on raw frames, the Separator's scenes and
        # the disparities of the last few stamps, and the newest light-on frame whose scene was
        # separated (not passed through), with the disparity of its stamp once it has arrived.
        self.recent_light_on = {}
        self.recent_scenes = {}
        self.recent_disparities = {}
        self.separated = None  # (raw, scene, disparity or None), one stamp
        # Separation against the truth: each settled light-on frame's image_scene against the
        # simulator's true scene of its stamp: (wall time, PSNR dB, passed through raw).
        self.recent_truth_scenes = {}
        self.separation = []
        self.scored_stamps = set()
        # The same for settled light-off frames (passed through): the noise floor of the score.
        self.recent_light_off = {}
        self.floor = []
        # calibration/health: frames (and lit frames) counted under the newest verdict, and
        # every change of state (wall time, message).
        self.health = None
        self.frames_by_health = {}  # state name -> [frames, lit frames]
        self.health_changes = []
        # Runs of light-on frames (wall time of the first, length): calibration bursts are the
        # runs longer than a verification flash.
        self.light_runs = []
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
            rospy.Subscriber(ns + "/left/image_scene", Image, self.on_scene, queue_size=4,
                             buff_size=2 ** 24),
            rospy.Subscriber(ns + "/ground_truth/left/image_scene", Image, self.on_truth_scene, queue_size=4,
                             buff_size=2 ** 24),
            sub("calibration/status", CalibrationStatus, "status"),
            rospy.Subscriber(ns + "/calibration/health", CalibrationHealth, self.on_health, queue_size=10),
        ]

    def store(self, key, msg):
        with self.lock:
            self.latest[key] = msg

    def on_health(self, msg):
        with self.lock:
            if self.health is None or msg.state != self.health.state:
                self.health_changes.append((time.time(), msg))
            self.health = msg

    def classify(self, image, mode):
        """Called with self.lock held, for an image and the calibration_mode of its stamp."""
        if not mode.light_on:
            self.last_light_off_image = image
            if mode.settled:
                self.recent_light_off[image.header.stamp] = image
                self.keep_last(self.recent_light_off)
                self.score_floor(image.header.stamp)
        elif mode.settled:
            self.last_light_on_image = image
            self.recent_light_on[image.header.stamp] = image
            self.keep_last(self.recent_light_on)
            self.match_separated(image.header.stamp)

    def match_separated(self, stamp):
        """Called with self.lock held when a piece of the frame of `stamp` arrived: keeps the
        newest settled light-on frame whose scene differs from it (the Separator separated it
        rather than passing it through), preferring one whose disparity arrived too."""
        raw, scene = self.recent_light_on.get(stamp), self.recent_scenes.get(stamp)
        self.score_separation(stamp)
        if raw is None or scene is None or scene.data == raw.data:
            return
        disparity = self.recent_disparities.get(stamp)
        current = self.separated
        if current is None or (stamp >= current[0].header.stamp and
                               (disparity is not None or current[2] is None)):
            self.separated = (raw, scene, disparity)

    def score_separation(self, stamp):
        """Called with self.lock held: scores a settled light-on frame's image_scene against the
        true scene once both have arrived (the truth only scores, it never reaches the head)."""
        raw, scene = self.recent_light_on.get(stamp), self.recent_scenes.get(stamp)
        truth = self.recent_truth_scenes.get(stamp)
        if raw is None or scene is None or truth is None or stamp in self.scored_stamps:
            return
        if scene.encoding != truth.encoding or len(scene.data) != len(truth.data):
            return
        self.scored_stamps.add(stamp)
        self.separation.append((time.time(), psnr(scene.data, truth.data), scene.data == raw.data))

    def score_floor(self, stamp):
        """Called with self.lock held: a settled light-off frame against the true scene."""
        raw, truth = self.recent_light_off.get(stamp), self.recent_truth_scenes.get(stamp)
        if raw is None or truth is None or len(raw.data) != len(truth.data):
            return
        del self.recent_light_off[stamp]
        self.floor.append(psnr(raw.data, truth.data))

    def on_truth_scene(self, msg):
        with self.lock:
            self.recent_truth_scenes[msg.header.stamp] = msg
            self.keep_last(self.recent_truth_scenes)
            self.score_separation(msg.header.stamp)
            self.score_floor(msg.header.stamp)

    def on_scene(self, msg):
        with self.lock:
            self.recent_scenes[msg.header.stamp] = msg
            self.keep_last(self.recent_scenes)
            self.match_separated(msg.header.stamp)

    @staticmethod
    def keep_last(unpaired, limit=10):
        while len(unpaired) > limit:
            unpaired.pop(next(iter(unpaired)))

    def on_mode(self, msg):
        with self.lock:
            previous = self.mode
            self.mode = msg
            self.modes += 1
            if msg.light_on:
                self.light_on_frames += 1
                if previous is None or not previous.light_on:
                    self.light_runs.append([time.time(), 0])
                self.light_runs[-1][1] += 1
            counts = self.frames_by_health.setdefault(health_name(self.health), [0, 0])
            counts[0] += 1
            counts[1] += 1 if msg.light_on else 0
            image = self.unpaired_images.pop(msg.header.stamp, None)
            if image is not None:
                self.classify(image, msg)
            else:
                self.unpaired_modes[msg.header.stamp] = msg
                self.keep_last(self.unpaired_modes)

    def on_image(self, msg):
        now = time.time()
        with self.lock:
            self.frames += 1
            self.first_image_time = self.first_image_time or now
            self.last_image_time = now
            self.last_image = msg
            mode = self.unpaired_modes.pop(msg.header.stamp, None)
            if mode is not None:
                self.classify(msg, mode)
            else:
                self.unpaired_images[msg.header.stamp] = msg
                self.keep_last(self.unpaired_images)

    def on_disparity(self, msg):
        with self.lock:
            self.disparities += 1
            self.last_disparity = msg
            self.recent_disparities[msg.header.stamp] = msg
            self.keep_last(self.recent_disparities, limit=4)
            self.match_separated(msg.header.stamp)

    def errors(self):
        """Called with self.lock held."""
        get = self.latest.get
        return calibration_errors((get("left"), get("right")), (get("gt_left"), get("gt_right")))

    def infos(self):
        """Called with self.lock held: (published, truth) CameraInfo pairs."""
        get = self.latest.get
        return (get("left"), get("right")), (get("gt_left"), get("gt_right"))


def plot_errors(path, timeline, events, epochs, health_steps=()):
    """PNG plot of each error against time (log scale), its accuracy target dashed, drift events as
    vertical lines and calibration commits (epoch changes) as dotted lines, and below them the
    calibration health state (health_steps: (t, state) at each change). False when matplotlib
    is missing."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    rows = [row for row in timeline if row[3] is not None]
    if not rows:
        return False
    t = np.array([row[0] for row in rows])
    # (title, [(key, source, label, colour, style)], target)
    depth_colours = ("tab:blue", "tab:orange", "tab:green", "tab:red")
    panels = [("vertical misalignment (px RMS)",
               [("misalignment_px", 3, "true", "tab:blue", "-"), ("misalignment_px", 4, "predicted", "tab:blue", ":")],
               ACCURACY_BOUNDS["misalignment_px"][0]),
              ("disparity bias (px RMS)",
               [("bias_px", 3, "true", "tab:purple", "-"), ("bias_px", 4, "predicted", "tab:purple", ":")],
               ACCURACY_BOUNDS["bias_px"][0]),
              ("depth error (% RMS)",
               [("depth_%dm_pct" % d, 3, "true at %d m" % d, c, "-") for d, c in zip(DEPTHS_M, depth_colours)] +
               [("depth_10m_pct", 4, "predicted at 10 m", "tab:red", ":")],
               ACCURACY_BOUNDS["depth_10m_pct"][0]),
              ("fx and baseline error (%)",
               [("fx_pct", 1, "fx (worse camera)", "tab:blue", "-"), ("baseline_pct", 1, "baseline", "tab:purple", "-")],
               ACCURACY_BOUNDS["fx_pct"][0])]
    fig, axes = plt.subplots(len(panels) + 1, 1, figsize=(12, 12), sharex=True,
                             gridspec_kw={"height_ratios": [3] * len(panels) + [1.5]})
    for ax, (title, curves, target) in zip(axes[:-1], panels):
        for key, source, label, colour, style in curves:
            values = np.array([row[source][key] if row[source] and key in row[source] else np.nan for row in rows])
            ax.semilogy(t, np.maximum(values, 1e-3), color=colour, linestyle=style, linewidth=1.5, label=label)
        ax.axhline(target, color="red", linestyle="--", linewidth=1, label="accuracy target")
        for i, (te, name) in enumerate(events):
            ax.axvline(te, color="black", linestyle="-.", linewidth=1.2, label="drift event" if i == 0 else None)
            if ax is axes[0]:
                ax.annotate(name, (te, 1.02 + 0.1 * (i % 2)), xycoords=("data", "axes fraction"),
                            ha="center", va="bottom", fontsize=9)
        for i, te in enumerate(epochs):
            ax.axvline(te, color="tab:green", linestyle=":", linewidth=1.2,
                       label="calibration committed" if i == 0 else None)
        ax.set_ylabel(title, fontsize=9)
        ax.grid(True, which="major", alpha=0.3)
        ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=8)
    ax = axes[-1]
    if health_steps:
        ts = [step[0] for step in health_steps] + [max(t[-1], health_steps[-1][0])]
        ax.stairs([step[1] for step in health_steps], ts, baseline=None, color="tab:orange", linewidth=2,
                  label="calibration health")
    for te, _ in events:
        ax.axvline(te, color="black", linestyle="-.", linewidth=1.2)
    for te in epochs:
        ax.axvline(te, color="tab:green", linestyle=":", linewidth=1.2)
    ax.set_yticks(range(len(HEALTH_STATES)))
    ax.set_yticklabels(HEALTH_STATES, fontsize=8)
    ax.set_ylim(-0.5, len(HEALTH_STATES) - 0.5)
    ax.set_ylabel("health", fontsize=9)
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=8)
    axes[-1].set_xlabel("time since the first frame (s)")
    fig.suptitle("Accuracy for depth of the published calibration\n"
                 "true (against the simulator's truth) and predicted by the calibrator; log scale, "
                 "below 1e-3 drawn at 1e-3", fontsize=11)
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 0.96))  # room for the two-line title
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return True


def within_targets(errors, accuracy):
    values = dict(accuracy, fx_pct=errors["fx_pct"], baseline_pct=errors["baseline_pct"])
    return all(values[key] <= bound for key, (bound, _) in ACCURACY_BOUNDS.items())


def cold_start_report(timeline, epochs, script):
    """A cold start: the error the head started with (its nominal description against the
    truth), its first commit and when it was first within the accuracy targets, before the first
    drift event."""
    first_event = script.fired[0][0] if script.fired else float("inf")
    measured = [(t, e, a) for t, e, _, a, _ in timeline if a is not None and t < first_event]
    if not measured:
        return ["cold start: no accuracy measured before the first drift event"]
    t0, e0, a0 = measured[0]
    within = next((t for t, e, a in measured if within_targets(e, a)), None)
    first_commit = next((t for t in epochs if t < first_event), None)
    return ["cold start: started at depth error at 10 m %.2f %%, fx %.3f %%, baseline %.3f %%, misalignment "
            "%.3f px; first commit at %s; within the accuracy targets from %s" % (
                a0["depth_10m_pct"], e0["fx_pct"], e0["baseline_pct"], a0["misalignment_px"],
                "%.1f s" % first_commit if first_commit is not None else "NONE before the first drift event",
                "%.1f s" % within if within is not None else "NEVER before the first drift event")]


def verdict(timeline, script, epochs, tool_problem=None):
    """Final errors against the accuracy targets; the calibration counts as 'after the drift' only if a
    commit came after the last drift event. Returns (lines, bounds_met)."""
    lines = []
    last_event = script.last_event_time()
    if script.pending:
        lines.append("not every drift event fired (run too short?): %s" %
                     ", ".join(event[1] for event in script.pending))
    if last_event is None or not timeline:
        return lines + ["no drift or no calibration error measured: nothing to judge"], False
    commits_after = [t for t in epochs if t > last_event]
    final_t, final, _, accuracy, predicted = timeline[-1]
    met = bool(commits_after) and not script.pending
    lines.append("calibration committed after the last drift event (%s at %.1f s): %s" % (
        script.fired[-1][1], last_event,
        ", ".join("%.1f s" % t for t in commits_after) if commits_after else "NONE"))
    if accuracy is None:
        return lines + ["no accuracy for depth measured (%s)" % (tool_problem or "no calibration")], False
    lines.append("final accuracy for depth of the published calibration (true vs ground truth; predicted by the "
                 "calibrator) and the targets:")
    values = dict(accuracy, fx_pct=final["fx_pct"], baseline_pct=final["baseline_pct"])
    for key, (bound, unit) in ACCURACY_BOUNDS.items():
        ok = values[key] <= bound
        met = met and ok
        pred = predicted.get(key) if predicted else None
        lines.append("  %-16s %9.4f %-3s %-18s target %-5g %s" % (
            key, values[key], unit, "(predicted %.4f)" % pred if pred is not None else "", bound,
            "ok" if ok else "EXCEEDED"))
    lines.append("  depth error at 1 / 2 / 5 / 10 m: %s %% true, %s %% predicted; misalignment max %.4f px, "
                 "bias max %.4f px" % (
                     " / ".join("%.3f" % accuracy["depth_%dm_pct" % d] for d in DEPTHS_M),
                     " / ".join("%.3f" % predicted["depth_%dm_pct" % d] for d in DEPTHS_M) if predicted else "-",
                     accuracy["misalignment_max_px"], accuracy["bias_max_px"]))
    lines.append("RESULT: calibration after the drift is %s" % (
        "WITHIN the accuracy targets for depth" if met else "NOT within the accuracy targets for depth"))
    return lines, met


# A run of more light-on frames than this is a calibration burst (a verification flash lights
# settle_frames + 1).
FLASH_FRAMES = 4


def health_report(mon, script, health_steps, epochs, t0):
    """Lines on calibration/health: the share of lit frames while GOOD, and for each drift event
    how long the health took to leave GOOD, to light a calibration burst, to commit and to come
    back."""
    with mon.lock:
        by_state = {k: list(v) for k, v in mon.frames_by_health.items()}
        bursts = [start - t0 for start, frames in mon.light_runs if frames > FLASH_FRAMES]
    if not health_steps:
        return ["calibration health: no calibration/health message received"]
    frames, lit = by_state.get("GOOD", [0, 0])
    lines = ["calibration health: %d frames while GOOD, %d of them lit (%.2f %%); frames per state: %s" % (
        frames, lit, 100.0 * lit / frames if frames else 0.0,
        ", ".join("%s %d (lit %d)" % (k, v[0], v[1]) for k, v in sorted(by_state.items())))]
    for i, (te, name) in enumerate(script.fired):
        end = script.fired[i + 1][0] if i + 1 < len(script.fired) else float("inf")
        before = [state for t, state in health_steps if t <= te]
        if before and before[-1] >= 2:
            lines.append("  %s at %.1f s: health was already %s" % (name, te, HEALTH_STATES[before[-1]]))
            continue
        left = next((t for t, state in health_steps if te <= t < end and state >= 2), None)
        if left is None:
            lines.append("  %s at %.1f s: health stayed GOOD until the next event" % (name, te))
            continue
        back = next((t for t, state in health_steps if t > left and state == 1), None)
        burst = next((t for t in bursts if t >= left - 0.5), None)
        commit = next((t for t in epochs if t > left), None)
        after = lambda t: "%.1f s after that" % (t - left) if t is not None and t < end else "not before the next event"
        lines.append("  %s at %.1f s: health left GOOD after %.1f s; calibration burst %s, commit %s, GOOD again %s" % (
            name, te, left - te, after(burst), after(commit),
            after(back) if back is not None else "never"))
    return lines


def psnr(a, b):
    """PSNR (dB) of two 8-bit images' bytes. Integer arithmetic: it runs on every settled frame,
    beside the head, and costs a twentieth of the same in floats."""
    d = np.frombuffer(a, np.uint8).astype(np.int32) - np.frombuffer(b, np.uint8)
    mse = float(np.einsum("i,i->", d, d, dtype=np.int64)) / max(d.size, 1)
    return 99.0 if mse == 0 else 10 * math.log10(255.0 ** 2 / mse)


def separation_report(mon):
    """How the Separator's scene compares with the simulator's true scene on the settled light-on
    frames: before its first template (passed through raw) and from then on."""
    scores = list(mon.separation)
    if not scores:
        return ["separation: no settled light-on frame was scored against the true scene"]
    first = next((i for i, (_, _, raw) in enumerate(scores) if not raw), None)
    if first is None:
        return ["separation: none of the %d settled light-on frames scored was separated" % len(scores)]
    after = [p for _, p, raw in scores[first:]]
    raw_after = sum(1 for _, _, raw in scores[first:] if raw)
    return ["separation: the scene of %d settled light-on frames against the true scene: %d passed through before "
            "the first separated one (%.1f s after the first light-on frame scored); from then on PSNR min %.1f dB, "
            "median %.1f dB, %.0f %% of them >= 35 dB, %d passed through" % (
                len(scores), first, scores[first][0] - scores[0][0], min(after), float(np.median(after)),
                100.0 * sum(1 for p in after if p >= 35.0) / len(after), raw_after)] + (
        ["separation: the settled light-off frames themselves against the true scene (the score's floor: sensor "
         "noise): PSNR median %.1f dB over %d frames" % (float(np.median(mon.floor)), len(mon.floor))]
        if mon.floor else [])


def write_results(out, mon, timeline, script, epochs, duration, report_lines, bounds_met, health_steps=()):
    with mon.lock:
        disparity = mon.last_disparity
        disparities = mon.disparities
        latest = dict(mon.latest)
        separated = mon.separated
        images = {"left_snapshot.png": mon.last_light_off_image or mon.last_image,
                  # the frame of the separated scene when there is one, so the two match
                  "left_snapshot_light_on.png": separated[0] if separated else mon.last_light_on_image,
                  "left_scene_light_on.png": separated[1] if separated else None}
        frames, light_frames = mon.frames, mon.light_on_frames
        health, by_health = mon.health, {k: list(v) for k, v in mon.frames_by_health.items()}
        mode = mon.mode
        span = (mon.last_image_time or 0) - (mon.first_image_time or 0)
    for key in ("left", "right", "gt_left", "gt_right"):
        if key in latest:
            name = key.replace("gt_", "ground_truth_")
            with open(os.path.join(out, name + ".yaml"), "w") as f:
                f.write(camera_yaml(latest[key], name))
    for file_name, image in images.items():
        pixels = image_rgb_or_grey(image)
        if pixels is None:
            continue
        channels = 1 if pixels.ndim == 2 else 3
        write_png(os.path.join(out, file_name), image.width, image.height, channels, pixels.tobytes())
    if disparity is not None:
        rgb, _ = colourise_disparity(disparity)
        write_png(os.path.join(out, "disparity.png"), disparity.image.width,
                  disparity.image.height, 3, rgb)
    overview = None  # why there is no overview.png, or None when there is one
    if separated is None:
        overview = "no light-on frame with a separated scene was received"
    elif separated[2] is None and disparity is None:
        overview = "no disparity image was received"
    elif not plot_overview(os.path.join(out, "overview.png"), separated[0], separated[1],
                           separated[2] if separated[2] is not None else disparity,
                           separated[2] is not None):
        overview = "python3-matplotlib is not installed"
    accuracy_keys = ["misalignment_px", "misalignment_max_px", "bias_px", "bias_max_px"] + [
        "depth_%dm_pct" % d for d in DEPTHS_M]
    predicted_keys = ["misalignment_px", "bias_px"] + ["depth_%dm_pct" % d for d in DEPTHS_M]
    with open(os.path.join(out, "calibration_error.csv"), "w") as f:
        f.write("time_s,epoch,%s,%s,%s\n" % (",".join(ERROR_KEYS), ",".join(accuracy_keys),
                                            ",".join("predicted_" + k for k in predicted_keys)))
        for t, errors, epoch, accuracy, predicted in timeline:
            f.write("%.2f,%d,%s,%s,%s\n" % (
                t, epoch, ",".join("%.6g" % errors[k] for k in ERROR_KEYS),
                ",".join("%.6g" % accuracy[k] if accuracy else "" for k in accuracy_keys),
                ",".join("%.6g" % predicted[k] if predicted and k in predicted else "" for k in predicted_keys)))
    with open(os.path.join(out, "drift_events.csv"), "w") as f:
        f.write("time_s,event\n" + "".join("%.2f,%s\n" % e for e in script.fired))
    plotted = timeline and plot_errors(os.path.join(out, "calibration_error.png"), timeline,
                                       script.fired, epochs, health_steps)
    # Mean over the time images flowed, so start-up does not count against the rate.
    mean_fps = (frames - 1) / span if frames > 1 and span > 0 else 0.0
    status = latest.get("status")
    final = timeline[-1][1] if timeline else None
    final_accuracy = timeline[-1][3] if timeline else None
    with open(os.path.join(out, "status.yaml"), "w") as f:
        f.write("duration_s: %.1f\nframes: %d\nmean_fps: %.2f\nlight_on_frames: %d\n"
                "disparity_images: %d\nmean_disparity_hz: %.2f\ncalibration_epoch: %s\n" % (
                    duration, frames, mean_fps, light_frames, disparities,
                    disparities / span if span > 0 else 0.0, mode.calibration_epoch if mode else "null"))
        f.write("drift_events:\n" + "".join("  - {time_s: %.1f, event: \"%s\"}\n" % e for e in script.fired))
        f.write("calibration_commits_s: [%s]\n" % ", ".join("%.1f" % t for t in epochs))
        if final:
            f.write("final_error:\n" + "".join("  %s: %.6g\n" % (k, final[k]) for k in ERROR_KEYS))
        if final_accuracy:
            f.write("final_accuracy:\n" + "".join("  %s: %.6g\n" % kv for kv in sorted(final_accuracy.items())))
        f.write("accuracy_targets:\n" + "".join("  %s: %g\n" % (k, v[0]) for k, v in ACCURACY_BOUNDS.items()))
        f.write("bounds_met_after_drift: %s\n" % str(bounds_met).lower())
        f.write("health:\n  final_state: %s\n  frames_by_state: {%s}\n  lit_frames_by_state: {%s}\n"
                "  changes: [%s]\n" % (
                    health_name(health), ", ".join("%s: %d" % (k, v[0]) for k, v in sorted(by_health.items())),
                    ", ".join("%s: %d" % (k, v[1]) for k, v in sorted(by_health.items())),
                    ", ".join("{time_s: %.1f, state: %s}" % (t, HEALTH_STATES[st]) for t, st in health_steps)))
        if status is not None:
            f.write("last_calibration_status:\n  epoch: %d\n  accepted: %s\n  reason: \"%s\"\n"
                    "  frames_used: %d\n  corners_used: %d\n  rms_left_px: %.4f\n  rms_right_px: %.4f\n"
                    "  epipolar_rms_px: %.4f\n  baseline_m: %.6f\n  baseline_stddev_m: %.6f\n"
                    "  rotation_stddev_deg: %.6f\n  solve_ms: %.1f\n" % (
                        status.epoch, str(status.accepted).lower(), status.reason.replace('"', "'"),
                        status.frames_used, status.corners_used, status.rms_left_px,
                        status.rms_right_px, status.epipolar_rms_px, status.baseline_m,
                        status.baseline_stddev_m, status.rotation_stddev_deg, status.solve_ms))
    summary = ["%d frames, mean %.1f fps, %d disparity images (%.1f Hz), %d frames with the light on, "
               "%d calibration commits" % (frames, mean_fps, disparities,
                                            disparities / span if span > 0 else 0.0, light_frames, len(epochs))]
    if not plotted:
        summary.append("no calibration_error.png: %s" % ("python3-matplotlib is not installed"
                                                          if timeline else "no error measured"))
    if overview:
        summary.append("no overview.png: %s" % overview)
    with open(os.path.join(out, "report.txt"), "w") as f:
        f.write("\n".join(summary + report_lines) + "\n")
    return summary, frames


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--duration", type=float, default=60.0, help="seconds from the first frame")
    parser.add_argument("--out", required=True)
    parser.add_argument("--ns", default="stereo")
    parser.add_argument("--zoom-at", type=float, default=None,
                        help="seconds of the zoom step (default: a third of the run); the thermal "
                             "rotation and the knock follow at fixed fractions of the run")
    parser.add_argument("--startup-timeout", type=float, default=120.0)
    parser.add_argument("--cold-start", action="store_true",
                        help="the head was given a nominal description off the truth: report its start")
    parser.add_argument("--accuracy-tool", default=shutil.which("stereo_accuracy"),
                        help="the stereo_accuracy executable (scripts/demo passes the built one)")
    args = parser.parse_args(rospy.myargv()[1:])
    rospy.init_node("demo_monitor", anonymous=True)
    os.makedirs(args.out, exist_ok=True)
    ns = "/" + args.ns.strip("/")
    mon = Monitor(ns)
    tool = AccuracyTool(args.accuracy_tool)
    if tool.problem:
        print("demo: %s: no accuracy for depth against the truth" % tool.problem, flush=True)

    wait_start = time.time()
    while not rospy.is_shutdown() and time.time() - wait_start < args.startup_timeout:
        with mon.lock:
            t0 = mon.first_image_time
        if t0 is not None:
            break
        time.sleep(0.1)  # start-up poll; the images' arrival is the event waited for
    if t0 is None:
        print("demo: no camera frame within %.0f s; see roslaunch.log" % args.startup_timeout, flush=True)
        return 1
    script = DriftScript(ns, args.duration,
                         args.zoom_at if args.zoom_at is not None else args.duration / 3.0,
                         float(rospy.get_param(ns + "/camera_driver/fps", 30.0)))
    timeline = []  # (t, errors dict, epoch, true accuracy dict or None, predicted accuracy dict or None)
    epochs = []  # times at which the calibration in force changed
    last_epoch, last_status, predicted = None, None, None
    health_steps = []  # (t, state) at each change of calibration/health
    health_seen = 0
    last_frames, last_disp, last_print = 0, 0, 0.0
    t = 0.0
    while not rospy.is_shutdown() and t < args.duration:
        time.sleep(0.25)  # sampling cadence only; nothing waits on this for correctness
        t = time.time() - t0
        with mon.lock:
            frames, disparities, mode, modes = mon.frames, mon.disparities, mon.mode, mon.modes
            errors, status = mon.errors(), mon.latest.get("status")
            published, truth = mon.infos()
            health, changes = mon.health, mon.health_changes[health_seen:]
        health_seen += len(changes)
        for wall, change in changes:
            th = max(0.0, wall - t0)
            health_steps.append((th, change.state))
            print("[%5.1f s] HEALTH %s (epoch %d)%s" % (th, health_name(change), change.epoch,
                                                       ": " + change.reason if change.reason else ""), flush=True)
        epoch = mode.calibration_epoch if mode else None  # None until the first frame
        if None not in (last_epoch, epoch) and epoch != last_epoch and (not epochs or t - epochs[-1] > 1.0):
            epochs.append(t)  # a commit changes the epoch twice (left, right): one mark
        last_epoch = epoch if epoch is not None else last_epoch
        if status is not None and status is not last_status:
            last_status = status
            print("[%5.1f s] CALIBRATION epoch %d %s, rms %.3f/%.3f px, %d frames, %.0f ms%s" % (
                t, status.epoch, "accepted" if status.accepted else "rejected", status.rms_left_px,
                status.rms_right_px, status.frames_used, status.solve_ms,
                "" if status.accepted else ": " + status.reason), flush=True)
        line = script.step(t, mode is None or mode.light_on, modes)
        if line:
            print(line, flush=True)
        if status is not None and status.accepted:
            predicted = predicted_figures(status)  # of the calibration committed last
        elif status is None:
            predicted = None
        accuracy = tool.evaluate(published, truth) if errors else None
        if errors:
            timeline.append((t, errors, -1 if epoch is None else epoch, accuracy, predicted))
        if t - last_print < 2.0:
            continue
        span = t - last_print
        fps, dps = (frames - last_frames) / span, (disparities - last_disp) / span
        last_frames, last_disp, last_print = frames, disparities, t
        print("[%5.1f s] %5.1f fps  disparity %5.1f Hz  light %s  epoch %s  health %-8s  vs truth: %s" % (
            t, fps, dps, "on " if mode and mode.light_on else "off", epoch if mode else "-", health_name(health),
            format_accuracy(accuracy, predicted) + "  fx %.3f%%  baseline %.3f%%" % (
                errors["fx_pct"], errors["baseline_pct"]) if accuracy else
            (format_errors(errors) if errors else "-")), flush=True)

    tool.close()
    report_lines, bounds_met = verdict(timeline, script, epochs, tool.problem)
    report_lines += health_report(mon, script, health_steps, epochs, t0)
    report_lines += separation_report(mon)
    if args.cold_start:
        report_lines += cold_start_report(timeline, epochs, script)
    summary, frames = write_results(args.out, mon, timeline, script, epochs, t, report_lines, bounds_met,
                                    health_steps)
    for line in summary + report_lines:
        print("demo: " + line, flush=True)
    return 0 if frames > 0 else 1


if __name__ == "__main__":
    sys.exit(main())
