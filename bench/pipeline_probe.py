#!/usr/bin/env python3
"""Measuring side of bench/pipeline (run by it, against a running master).

  live   --duration S --warmup S       frames per second and latency of /stereo/disparity while
                                        the whole simulated head runs; also reads /diagnostics.
  replay --bag FILE --in-flight N      closed-loop replay of the recorded raw images + camera_info
                                        into /stereo, rectify + disparity throughput.
Prints one JSON object on stdout.

Disparity is received as rospy.AnyMsg (not deserialised: the probe stays cheap); its header stamp
is read from the first bytes of the serialised message (Header: seq, stamp.secs, stamp.nsecs).
"""
import argparse
import json
import statistics
import struct
import sys
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


def live(args):
    rospy.init_node('bench_pipeline_probe', anonymous=True)
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
    time.sleep(args.duration)
    end = time.time()
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
        'loadavg_start': float(load_start),
        'loadavg_end': float(open('/proc/loadavg').read().split()[0]),
    }
    print(json.dumps(result))


def replay(args):
    import rosbag
    from sensor_msgs.msg import CameraInfo, Image
    rospy.init_node('bench_replay_probe', anonymous=True)
    # The bag's stereo frames, complete ones only, in stamp order (loaded before timing).
    frames = {}
    topics = ['/stereo/left/image_raw', '/stereo/right/image_raw', '/stereo/left/camera_info',
              '/stereo/right/camera_info']
    with rosbag.Bag(args.bag) as bag:
        for topic, msg, _ in bag.read_messages(topics=topics):
            frames.setdefault(msg.header.stamp.to_nsec(), {})[topic] = msg
    stamps = sorted(s for s, f in frames.items() if len(f) == 4)
    pubs = {t: rospy.Publisher(t, Image if 'image' in t else CameraInfo, queue_size=args.in_flight + 2)
            for t in topics}
    cond = threading.Condition()
    received = {}  # stamp ns -> wall arrival

    def cb(raw):
        now = time.time()
        with cond:
            received[stamp_of(raw)] = now
            cond.notify_all()

    sub = rospy.Subscriber('/stereo/disparity', rospy.AnyMsg, cb, queue_size=10, buff_size=1 << 24, tcp_nodelay=True)
    diagnostics = DiagnosticsLog()  # ours only: the stock nodelets publish none
    deadline = time.time() + 30
    while time.time() < deadline and (sub.get_num_connections() == 0 or
                                      any(p.get_num_connections() == 0 for p in pubs.values())):
        time.sleep(0.05)  # connections: no event to wait on
    if sub.get_num_connections() == 0:
        sys.exit('replay: the pipeline did not connect')
    time.sleep(0.5)  # the lazy nodelets subscribe their inputs in a chain: let it settle

    sent = {}  # stamp -> wall time published
    in_flight = []
    measured_from = None
    warmup = args.warmup_frames
    for i, stamp in enumerate(stamps):
        with cond:
            while True:
                in_flight = [s for s in in_flight if s not in received]
                # Dropped by the pipeline (counted below): older than a frame already answered
                # (both pipelines answer in stamp order: their ExactTime synchronisers discard
                # older incomplete frames), or unanswered after the timeout.
                newest = max(received) if received else -1
                now = time.time()
                expired = [s for s in in_flight if s < newest or now - sent[s] > args.timeout]
                for s in expired:
                    in_flight.remove(s)
                if len(in_flight) < args.in_flight:
                    break
                cond.wait(0.01)
        if i == warmup:
            measured_from = time.time()
        frame = frames[stamp]
        for t in topics[2:] + topics[:2]:  # camera_info first
            pubs[t].publish(frame[t])
        sent[stamp] = time.time()
        in_flight.append(stamp)
    with cond:
        cond.wait_for(lambda: all(s in received for s in in_flight), timeout=args.timeout)
    measured = [s for s in stamps[warmup:] if s in received]
    end = max(received[s] for s in measured) if measured else time.time()
    latencies = [received[s] - sent[s] for s in measured]
    print(json.dumps({
        'frames_offered': len(stamps) - warmup,
        'disparity_frames': len(measured),
        'dropped': len(stamps) - warmup - len(measured),
        'seconds': end - measured_from,
        'fps': len(measured) / (end - measured_from),
        'latency_ms': summary_ms(latencies),
        'in_flight': args.in_flight,
        'frame_time_ms': {name: statistics.median(numbers(diagnostics.find('stereo/%s:' % name),
                                                          'frame time mean (ms)') or [float('nan')])
                          for name in ('rectifier', 'disparity')},
        'loadavg': float(open('/proc/loadavg').read().split()[0]),
    }))


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest='mode', required=True)
    p = sub.add_parser('live')
    p.add_argument('--duration', type=float, default=20.0)
    p.add_argument('--warmup', type=float, default=10.0)
    p = sub.add_parser('replay')
    p.add_argument('--bag', required=True)
    p.add_argument('--in-flight', type=int, default=2)
    p.add_argument('--warmup-frames', type=int, default=10)
    p.add_argument('--timeout', type=float, default=1.0)
    args = parser.parse_args(rospy.myargv()[1:])
    live(args) if args.mode == 'live' else replay(args)


if __name__ == '__main__':
    main()
