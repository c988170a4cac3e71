#!/usr/bin/env python3
"""Measuring side of bench/pipeline (run by it, against a running master).

  live   --duration S --warmup S       frames per second and latency of /stereo/disparity while
         [--manager-pid PID]            the whole simulated head runs; also reads /diagnostics;
         [--drift-at F]                 with a manager pid, its CPU time per frame (all threads)
                                        and resident memory; with --drift-at, a 3 % zoom at that
                                        fraction of the window (the head calibrates on demand),
                                        and the light and the commits that followed.

Prints one JSON object on stdout. (The replay of part 3 is bench/nodelets/replay_feeder.cpp.)

Disparity is received as rospy.AnyMsg (not deserialised: the probe stays cheap); its header stamp
is read from the first bytes of the serialised message (Header: seq, stamp.secs, stamp.nsecs).
"""
import argparse
import json
import os
import statistics
import struct
import threading
import time

import rospy


def stamp_of(raw):
    _, secs, nsecs = struct.unpack_from('<III', raw._buff, 0)
    return secs * 1000000000 + nsecs  # ns


def percentile(values, q):
    v = sorted(values)
    return v[min(len(v) - 1, int(q * len(v)))] if v else float('nan')


def summary_ms(values_s):
    ms = [1e3 * v for v in values_s]
    return {'p50': percentile(ms, 0.5), 'p95': percentile(ms, 0.95), 'max': max(ms) if ms else float('nan'),
            'n': len(ms)}


class DiagnosticsLog:
    """Latest and per-report key/values of the statuses of /diagnostics, by status name."""

    def __init__(self):
        from diagnostic_msgs.msg import DiagnosticArray
        self.lock = threading.Lock()
        self.reports = {}  # name -> [ {key: value} ]
        self.sub = rospy.Subscriber('/diagnostics', DiagnosticArray, self.cb, queue_size=50)

    def cb(self, msg):
        with self.lock:
            for s in msg.status:
                self.reports.setdefault(s.name, []).append({kv.key: kv.value for kv in s.values})

    def clear(self):
        with self.lock:
            self.reports.clear()

    def find(self, prefix):
        with self.lock:
            for name, reports in self.reports.items():
                if name.startswith(prefix):
                    return list(reports)
        return []


def numbers(reports, key):
    out = []
    for r in reports:
        try:
            out.append(float(r[key]))
        except (KeyError, ValueError):
            pass
    return out


def process_cpu_s(pid):
    """utime + stime of a process (all its threads), seconds."""
    fields = open('/proc/%d/stat' % pid).read().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def process_memory_mb(pid):
    """Resident memory now and at its peak, MB."""
    values = {}
    for line in open('/proc/%d/status' % pid):
        key, _, rest = line.partition(':')
        if key in ('VmRSS', 'VmHWM'):
            values[key] = int(rest.split()[0]) / 1024.0
    return values.get('VmRSS', float('nan')), values.get('VmHWM', float('nan'))


def process_figures(pid, cpu_start, cpu_end, frames, seconds):
    """CPU per disparity frame, cores used and memory of one process over the measurement."""
    if cpu_start is None:
        return None
    rss, peak = process_memory_mb(pid)
    return {
        'cpu_ms_per_disparity_frame': 1e3 * (cpu_end - cpu_start) / max(1, frames),
        'cores_used': (cpu_end - cpu_start) / seconds,
        'rss_mb': rss,
        'peak_rss_mb': peak,
    }


class HeadEvents:
    """Light-on frames (calibration_mode) and accepted calibrations (calibration/status)."""
    def __init__(self):
        from embedded_calibration_stereo.msg import CalibrationMode, CalibrationStatus
        self.lock = threading.Lock()
        self.modes = []     # (wall, light_on)
        self.commits = []   # wall
        rospy.Subscriber('/stereo/calibration_mode', CalibrationMode, self.mode, queue_size=100)
        rospy.Subscriber('/stereo/calibration/status', CalibrationStatus, self.status, queue_size=10)

    def mode(self, msg):
        with self.lock:
            self.modes.append((time.time(), msg.light_on))

    def status(self, msg):
        if msg.accepted:
            with self.lock:
                self.commits.append(time.time())

    def since(self, start, end):
        with self.lock:
            modes = [m for m in self.modes if start <= m[0] <= end]
            commits = [c for c in self.commits if start <= c <= end]
        return modes, commits


def zoom(scale):
    from embedded_calibration_stereo.srv import SetRigDrift, SetRigDriftRequest
    rospy.wait_for_service('/stereo/sim/set_drift', 10.0)
    rospy.ServiceProxy('/stereo/sim/set_drift', SetRigDrift)(SetRigDriftRequest(focal_scale=scale))
    return time.time()


def live(args):
    rospy.init_node('bench_pipeline_probe', anonymous=True)
    events = HeadEvents()
    arrivals = []  # (wall arrival, stamp ns)
    lock = threading.Lock()

    def cb(raw):
        now = time.time()
        with lock:
            arrivals.append((now, stamp_of(raw)))

    diagnostics = DiagnosticsLog()
    rospy.Subscriber('/stereo/disparity', rospy.AnyMsg, cb, queue_size=10, buff_size=1 << 24, tcp_nodelay=True)
    time.sleep(args.warmup)  # tracker teach, first calibration window, maps: not measured
    with lock:
        arrivals.clear()
    diagnostics.clear()
    start = time.time()
    load_start = open('/proc/loadavg').read().split()[0]
    cpu_start = process_cpu_s(args.manager_pid) if args.manager_pid else None
    driver_cpu_start = process_cpu_s(args.driver_pid) if args.driver_pid else None
    drift_at = None
    if args.drift_at is not None:
        time.sleep(args.drift_at * args.duration)
        drift_at = zoom(1.03)
    time.sleep(max(0.0, start + args.duration - time.time()))
    end = time.time()
    cpu_end = process_cpu_s(args.manager_pid) if args.manager_pid else None
    driver_cpu_end = process_cpu_s(args.driver_pid) if args.driver_pid else None
    with lock:
        window = [a for a in arrivals if a[0] <= end]
    latencies = [a[0] - a[1] * 1e-9 for a in window]
    gaps = [b[0] - a[0] for a, b in zip(window, window[1:])]
    disparity = [r for r in diagnostics.find('stereo/disparity:')]
    driver = diagnostics.find('stereo/camera_driver:')
    result = {
        'seconds': end - start,
        'disparity_frames': len(window),
        'fps': len(window) / (end - start),
        'longest_gap_ms': 1e3 * max(gaps) if gaps else float('nan'),
        'latency_at_probe_ms': summary_ms(latencies),
        'disparity_diag': {
            'publish_latency_p50_ms_median': statistics.median(numbers(disparity, 'latency p50 (ms)') or [float('nan')]),
            'publish_latency_p95_ms_max': max(numbers(disparity, 'latency p95 (ms)') or [float('nan')]),
            'publish_latency_max_ms': max(numbers(disparity, 'latency max (ms)') or [float('nan')]),
            'frame_time_mean_ms_median': statistics.median(numbers(disparity, 'frame time mean (ms)') or [float('nan')]),
            'algorithm': disparity[-1].get('algorithm', '?') if disparity else '?',
        },
        'driver_fps_median': statistics.median(numbers(driver, 'frame rate (fps)') or [float('nan')]),
        'input_copies': {name: (diagnostics.find('stereo/%s:' % name) or [{}])[-1].get('input copies', '?')
                         for name in ('separator', 'rectifier', 'disparity')},
        'manager': process_figures(args.manager_pid, cpu_start, cpu_end, len(window), end - start),
        'driver': process_figures(args.driver_pid, driver_cpu_start, driver_cpu_end, len(window), end - start),
        'loadavg_start': float(load_start),
        'loadavg_end': float(open('/proc/loadavg').read().split()[0]),
    }
    modes, commits = events.since(start, end)
    result['light'] = {'frames': len(modes), 'lit': sum(1 for m in modes if m[1])}
    result['drift'] = None if drift_at is None else {
        'at_s': drift_at - start,
        'first_commit_after_s': next((c - drift_at for c in commits if c > drift_at), None),
        'commits': len(commits),
    }
    print(json.dumps(result))


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest='mode', required=True)
    p = sub.add_parser('live')
    p.add_argument('--duration', type=float, default=20.0)
    p.add_argument('--warmup', type=float, default=10.0)
    p.add_argument('--manager-pid', type=int, default=0)
    p.add_argument('--driver-pid', type=int, default=0, help="the driver's own process, when it runs apart")
    p.add_argument('--drift-at', type=float, default=None)
    args = parser.parse_args(rospy.myargv()[1:])
    live(args)


if __name__ == '__main__':
    main()
