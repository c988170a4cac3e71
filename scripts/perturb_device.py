#!/usr/bin/env python3
"""Writes a head's nominal description as a drawing gives it: a scenario file (config/*.yaml)
whose cameras, stereo extrinsics and board placement are moved off the simulated truth by a
manufacturing tolerance, drawn uniformly with a seed. The simulator keeps rendering the truth
(sim_config); the head is given this file as its device_config, for a cold start.

Tolerances (half-widths): per camera fx, fy 2 %, cx, cy 8 px, k1 0.03; the stereo rotation 0.5 deg
per axis; the baseline 2 mm; each board 1 mm per axis and 0.3 deg per axis.

Usage: perturb_device.py CONFIG OUT [--seed N]; prints what it changed.
"""
import argparse
import re
import sys

import numpy as np
import yaml

FOCAL, CENTRE, K1 = 0.02, 8.0, 0.03
ROTATION_DEG, BASELINE_M = 0.5, 0.002
BOARD_M, BOARD_DEG = 0.001, 0.3


def fmt(values):
    return "[" + ", ".join("%.7g" % v for v in values) + "]"


def perturb(text, seed):
    """The perturbed file's text and a list of what changed (sentences)."""
    # OpenCV's files start with "%YAML:1.0", which PyYAML does not read.
    config = yaml.safe_load(re.sub(r"^%YAML:1\.0", "", text))
    rng = np.random.default_rng(seed)
    u = lambda n=None: rng.uniform(-1.0, 1.0, n)
    changes = []
    lines = text.split("\n")
    section = None
    camera = None
    board = 0
    for i, line in enumerate(lines):
        top = re.match(r"^([a-z_]+):", line)
        if top:
            section, camera = top.group(1), None
        if section != "rig" and section != "device":
            continue
        side = re.match(r"^  (left|right):\s*$", line)
        if side and section == "rig":
            camera = config["rig"][side.group(1)]
            camera["_name"] = side.group(1)
            continue
        key = re.match(r"^(\s+)(fx|fy|cx|cy|distortion): (.*?)(\s*#.*)?$", line)
        if key and camera is not None:
            indent, name = key.group(1), key.group(2)
            if name in ("fx", "fy"):
                value = camera[name] * (1.0 + FOCAL * u())
                changes.append("%s %s %.2f -> %.2f (%+.2f %%)" % (camera["_name"], name, camera[name], value,
                                                                  100 * (value / camera[name] - 1)))
                lines[i] = "%s%s: %.4f" % (indent, name, value)
            elif name in ("cx", "cy"):
                value = camera[name] + CENTRE * u()
                changes.append("%s %s %.2f -> %.2f" % (camera["_name"], name, camera[name], value))
                lines[i] = "%s%s: %.4f" % (indent, name, value)
            else:
                d = list(camera["distortion"])
                d[0] += K1 * u()
                changes.append("%s k1 %.4f -> %.4f" % (camera["_name"], camera["distortion"][0], d[0]))
                lines[i] = "%sdistortion: %s" % (indent, fmt(d))
            continue
        rotation = re.match(r"^(\s+)rotation_deg: \[(.*)\]\s*$", line)
        if rotation and section == "rig":
            r = np.array(config["rig"]["right_from_left"]["rotation_deg"], float)
            new = r + ROTATION_DEG * u(3)
            changes.append("stereo rotation %s -> %s deg" % (fmt(r), fmt(new)))
            lines[i] = "%srotation_deg: %s" % (rotation.group(1), fmt(new))
            continue
        translation = re.match(r"^(\s+)translation_m: \[(.*)\]\s*$", line)
        if translation and section == "rig":
            t = np.array(config["rig"]["right_from_left"]["translation_m"], float)
            baseline = np.linalg.norm(t)
            new = t * (baseline + BASELINE_M * u()) / baseline
            changes.append("baseline %.4f -> %.4f m" % (baseline, np.linalg.norm(new)))
            lines[i] = "%stranslation_m: %s" % (translation.group(1), fmt(new))
            continue
        entry = re.match(r"^(\s+)- \{cols: .*pose: \{rotation_deg:", line)
        if entry and section == "device":
            b = config["device"]["boards"][board]
            rot = np.array(b["pose"]["rotation_deg"], float) + BOARD_DEG * u(3)
            tra = np.array(b["pose"]["translation_m"], float) + BOARD_M * u(3)
            lines[i] = "%s- {cols: %d, rows: %d, square_m: %s, pose: {rotation_deg: %s, translation_m: %s}}" % (
                entry.group(1), b["cols"], b["rows"], b["square_m"], fmt(rot), fmt(tra))
            changes.append("board %d moved by %s mm, turned by %s deg" % (
                board, fmt(1000 * (tra - np.array(b["pose"]["translation_m"]))),
                fmt(rot - np.array(b["pose"]["rotation_deg"]))))
            board += 1
    return "\n".join(lines), changes


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("config")
    parser.add_argument("out")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    with open(args.config) as f:
        text = f.read()
    out, changes = perturb(text, args.seed)
    expected = 2 * 5 + 2 + 3  # per camera fx fy cx cy k1; rotation, baseline; at least 3 boards
    if len(changes) < expected:
        sys.exit("perturb_device: %s has not the layout expected (%d changes, expected >= %d)" % (
            args.config, len(changes), expected))
    header = "%%YAML:1.0\n# A nominal description off the truth of %s (seed %d, scripts/perturb_device.py):\n" % (
        args.config, args.seed) + "".join("#   %s\n" % c for c in changes)
    with open(args.out, "w") as f:
        f.write(header + re.sub(r"^%YAML:1\.0\n", "", out))
    for c in changes:
        print(c)


if __name__ == "__main__":
    main()
