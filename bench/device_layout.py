#!/usr/bin/python3
"""Device layout designer for the simulated head: from a high-level description of the virtual
boards (what the cameras see), computes the physical boards and the two effective mirror planes
in config/sim_rig.yaml's `device` format, checks that every board (with its white margin) lies
inside both images at the nominal focal length and after a 5 % zoom, and reports, per camera and
board, distance, tilt, apparent square size and image bounding box.

Used to measure what the calibrator's accuracy depends on (bench_calibrator --rig OUT.yaml):

  bench/device_layout.py --preset dense /tmp/dense.yaml
  bench_calibrator --rig /tmp/dense.yaml --trials 10 --zero-tangential 1 --frames 10 \
      --per-frame 0 --device-error-mm 0 --device-error-deg 0 --prior-deg 0.001 --prior-m 0.000001

Presets: `current` (close to config/sim_rig.yaml's layout), `depth` (the two copies at 1.0 and
1.4 m, 11x8 boards), `dense` (20x14 boards covering ~80 % of the image: not buildable, margins
and overlaps fail; it bounds what any layout of six boards can give). A JSON file of the same
shape as the presets can be given instead of --preset.

Geometry: copy 0's virtual boards are placed around C0 (offset, yaw, pitch in degrees); each
mirror plane is the perpendicular bisector between the device reference point D and a copy's
centre (C0, C1); the physical boards are copy 0 reflected back; copy 1 is the physical boards
reflected by plane 1 (so its boards are copy 0 rotated about the planes' intersection line).
Camera models are the sim's (config/sim_rig.yaml `rig`).
"""
import argparse
import json
import math
import os
import re
import sys

import numpy as np

CAM = {
 'left':  dict(fx=652.4, fy=651.3, cx=372.9, cy=243.4, d=[-0.2812, 0.0714, 0.00041, -0.00033, 0.0]),
 'right': dict(fx=648.7, fy=647.9, cx=379.6, cy=236.8, d=[-0.2768, 0.0691, -0.00028, 0.00036, 0.0]),
}
W, H = 752, 480

def rotvec_deg(v):
    v = np.asarray(v, float); a = np.linalg.norm(v) * math.pi / 180
    if a < 1e-15: return np.eye(3)
    k = v / np.linalg.norm(v); K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(a) * K + (1 - math.cos(a)) * K @ K

def to_rotvec_deg(R):
    a = math.acos(max(-1, min(1, (np.trace(R) - 1) / 2)))
    if a < 1e-12: return np.zeros(3)
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / (2 * math.sin(a))
    return v * a * 180 / math.pi

RFL = np.eye(4); RFL[:3, :3] = rotvec_deg([0.25, -0.45, 0.12]); RFL[:3, 3] = [-0.1203, 0.0009, -0.0006]

def project(cam, p, zoom=1.0):
    x, y = p[0] / p[2], p[1] / p[2]
    k1, k2, p1, p2, k3 = cam['d']; r2 = x * x + y * y
    rad = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 ** 3
    xd = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.array([cam['fx'] * zoom * xd + cam['cx'], cam['fy'] * zoom * yd + cam['cy']])

def reflection(n, d):
    n = np.asarray(n, float); n = n / np.linalg.norm(n)
    M = np.eye(4); M[:3, :3] = np.eye(3) - 2 * np.outer(n, n); M[:3, 3] = 2 * d * n
    return M

def bisector(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    n = (b - a) / np.linalg.norm(b - a)
    return n, float(n @ (a + b) / 2)

FLIP = np.diag([1.0, -1.0, 1.0, 1.0])

def design(spec):
    D = np.array(spec['D']); C0 = np.array(spec['C0']); C1 = np.array(spec['C1'])
    n0, d0 = bisector(D, C0); n1, d1 = bisector(D, C1)
    M0, M1 = reflection(n0, d0), reflection(n1, d1)
    boards = []
    for b in spec['boards']:
        cols, rows, s = b['cols'], b['rows'], b['square']
        R = rotvec_deg([0, b.get('yaw', 0), 0]) @ rotvec_deg([b.get('pitch', 0), 0, 0]) @ rotvec_deg([0, 0, b.get('roll', 0)])
        c = C0 + np.array(b['offset'])
        w, h = (cols - 1) * s, (rows - 1) * s
        t = c - R @ np.array([w / 2, -h / 2, 0])   # virtual (mirrored) board: local y negated
        virt = np.eye(4); virt[:3, :3] = R; virt[:3, 3] = t
        physical = M0 @ virt @ FLIP
        rig_from_device = np.eye(4); rig_from_device[:3, 3] = D
        dfb = np.linalg.inv(rig_from_device) @ physical
        boards.append(dict(cols=cols, rows=rows, square=s, dfb=dfb, physical=physical))
    return dict(D=D, planes=[(n0, d0), (n1, d1)], M=[M0, M1], boards=boards)

def virtual_corners(des, margin_squares=0.0):
    """Per copy, per board: corner points in the rig frame (and margin outline)."""
    out = []
    for ci, M in enumerate(des['M']):
        for bi, b in enumerate(des['boards']):
            V = M @ b['physical'] @ FLIP
            cols, rows, s = b['cols'], b['rows'], b['square']
            pts = []
            for j in range(rows):
                for i in range(cols):
                    pts.append((V @ np.array([i * s, -j * s, 0, 1]))[:3])
            m = margin_squares + 1.0   # outer edge of the black squares + margin
            outline = []
            for (u, v) in [(-m, -m), (cols - 1 + m, -m), (cols - 1 + m, rows - 1 + m), (-m, rows - 1 + m)]:
                outline.append((V @ np.array([u * s, -v * s, 0, 1]))[:3])
            normal = V[:3, 2]; centre = np.mean(pts, axis=0)
            tilt = math.degrees(math.acos(abs(normal @ centre) / np.linalg.norm(centre)))
            out.append(dict(copy=ci, board=bi, pts=np.array(pts), outline=np.array(outline), V=V, tilt=tilt, dist=np.linalg.norm(centre)))
    return out

def check(des, verbose=True):
    vbs = virtual_corners(des, margin_squares=1.0)
    worst = 1e9; area = {}
    for cam_name in ['left', 'right']:
        cam = CAM[cam_name]; boxes = []
        for vb in vbs:
            for zoom in [1.0, 1.05]:
                pts = vb['outline'] if cam_name == 'left' else [(RFL @ np.append(p, 1))[:3] for p in vb['outline']]
                px = np.array([project(cam, p, zoom) for p in pts])
                m = min(px[:, 0].min(), W - 1 - px[:, 0].max(), px[:, 1].min(), H - 1 - px[:, 1].max())
                worst = min(worst, m)
                if zoom == 1.0:
                    boxes.append((px[:, 0].min(), px[:, 0].max(), px[:, 1].min(), px[:, 1].max()))
            cp = vb['pts'] if cam_name == 'left' else np.array([(RFL @ np.append(p, 1))[:3] for p in vb['pts']])
            pc = np.array([project(cam, p) for p in cp])
            b = des['boards'][vb['board']]
            sq = np.median(np.linalg.norm(np.diff(pc.reshape(b['rows'], b['cols'], 2), axis=1), axis=2))
            if verbose:
                print(f"{cam_name} copy {vb['copy']} board {vb['board']}: dist {vb['dist']:.3f} m tilt {vb['tilt']:.1f} deg square {sq:.1f} px bbox u {pc[:,0].min():.0f}-{pc[:,0].max():.0f} v {pc[:,1].min():.0f}-{pc[:,1].max():.0f}")
        # overlap of outline boxes
        for i in range(len(boxes)):
            for j in range(i + 1, len(boxes)):
                a, b = boxes[i], boxes[j]
                if a[0] < b[1] and b[0] < a[1] and a[2] < b[3] and b[2] < a[3]:
                    print(f"  OVERLAP {cam_name}: {i} {j}")
        cov = sum((b[1] - b[0]) * (b[3] - b[2]) for b in boxes) / (W * H)
        area[cam_name] = cov
    print(f"worst margin {worst:.1f} px (nominal and 5% zoom), coverage {area}")
    return worst

def yaml_device(des):
    lines = ["device:", "  pose:  # rig_from_device: D, axes parallel to the rig's", "    rotation_deg: [0.0, 0.0, 0.0]",
             "    translation_m: [%.4f, %.4f, %.4f]" % tuple(des['D']), "  boards:"]
    for b in des['boards']:
        rv = to_rotvec_deg(b['dfb'][:3, :3]); t = b['dfb'][:3, 3]
        lines.append("    - {cols: %d, rows: %d, square_m: %.4f, pose: {rotation_deg: [%.4f, %.4f, %.4f], translation_m: [%.5f, %.5f, %.5f]}}"
                     % (b['cols'], b['rows'], b['square'], *rv, *t))
    lines.append("  copies:  # one chain per copy, device side first; planes n.x = d in the rig frame")
    for i, (n, d) in enumerate(des['planes']):
        lines.append("    - [{normal: [%.7f, %.7f, %.7f], distance_m: %.7f}]  # copy %d" % (*n, d, i))
    return "\n".join(lines) + "\n"

def load_yaml_device(path):
    txt = open(path).read()
    dev = txt[txt.index('\ndevice:'):txt.index('\n# The scene behind')]
    D = np.array([float(x) for x in re.search(r'translation_m: \[([^\]]*)\]', dev).group(1).split(',')])
    boards = []
    for m in re.finditer(r'cols: (\d+), rows: (\d+), square_m: ([\d.]+), pose: \{rotation_deg: \[([^\]]*)\], translation_m: \[([^\]]*)\]', dev):
        R = rotvec_deg([float(x) for x in m.group(4).split(',')]); t = np.array([float(x) for x in m.group(5).split(',')])
        dfb = np.eye(4); dfb[:3, :3] = R; dfb[:3, 3] = t
        rfd = np.eye(4); rfd[:3, 3] = D
        boards.append(dict(cols=int(m.group(1)), rows=int(m.group(2)), square=float(m.group(3)), dfb=dfb, physical=rfd @ dfb))
    planes = []
    for m in re.finditer(r'normal: \[([^\]]*)\], distance_m: ([-\d.]+)', dev):
        planes.append((np.array([float(x) for x in m.group(1).split(',')]), float(m.group(2))))
    return dict(D=D, planes=planes, M=[reflection(n, d) for n, d in planes], boards=boards)


def _boards(cols, rows, square, dx, yaw=(-35, 10, 35), pitch=20):
    return [{"cols": cols, "rows": rows, "square": square, "offset": [o, 0, 0], "yaw": y, "pitch": pitch}
            for o, y in zip((-dx, 0.0, dx), yaw)]


PRESETS = {
    "current": {"D": [0.06, -0.10, 0.0], "C0": [0.06, -0.21, 1.2], "C1": [0.06, 0.21, 1.2],
                "boards": _boards(8, 6, 0.034, 0.43)},
    "depth": {"D": [0.06, -0.10, 0.0], "C0": [0.06, -0.17, 1.0], "C1": [0.06, 0.24, 1.4],
              "boards": _boards(11, 8, 0.025, 0.36)},
    "dense": {"D": [0.06, -0.10, 0.0], "C0": [0.06, -0.22, 1.0], "C1": [0.06, 0.30, 1.4],
              "boards": _boards(20, 14, 0.0195, 0.46, yaw=(-25, 5, 25))},
}


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--preset", choices=sorted(PRESETS))
    parser.add_argument("--spec", help="JSON layout description instead of a preset")
    parser.add_argument("--check", help="only check the device of an existing sim_rig.yaml")
    parser.add_argument("--base", default=None, help="sim_rig.yaml to copy everything else from")
    parser.add_argument("out", nargs="?", help="output sim_rig.yaml")
    args = parser.parse_args()
    if args.check:
        check(load_yaml_device(args.check))
        return 0
    if not args.out or not (args.preset or args.spec):
        parser.error("give --preset or --spec, and an output file")
    spec = PRESETS[args.preset] if args.preset else json.load(open(args.spec))
    des = design(spec)
    check(des)
    here = os.path.dirname(os.path.abspath(__file__))
    base_path = args.base or os.path.join(here, "..", "config", "sim_rig.yaml")
    base = open(base_path).read()
    start = base.index("\ndevice:") + 1
    end = base.index("\n# The scene behind")
    with open(args.out, "w") as f:
        f.write(base[:start] + yaml_device(des) + base[end:])
    print("wrote", args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
