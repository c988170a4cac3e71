"""Adversarial floods for bench/soak, sent to the demo graph (namespace /stereo) from the probe.

Each kind reproduces in Python what one of the head's rostests sends:
  calibration_mode ahead   graph_stamps: modes stamped 0.5-1.9 s ahead of the driver's frames,
                           random light/settled flags, 5 s at 30 Hz then 5 s at 200 Hz
  calibration_mode live    graph_stamps: the same at the driver's latest frame stamp
  set_camera_info          calibration_refusals: principal points far off the image on both
                           cameras (must be refused), then driver_calibration: cx' changed on
                           the left alone (must be staged, then discarded, never published)
  window observations      calibrator_window_flood: the tracker's latest window observation at
                           30 Hz, each stamped 1 ms after the previous one, 5 s of exact copies
                           (the calibrator must drop them: they teach nothing new) then 5 s with
                           every corner moved by 0.05 px of noise (new content: solved, paced)
  recalibrate              one calibration/recalibrate call, as a user would make it
"""
import copy
import os
import random
import re
import threading
import time

import rospy
from embedded_calibration_stereo.msg import CalibrationMode, CalibrationStatus, StereoPatternObservation
from embedded_calibration_stereo.srv import Recalibrate
from sensor_msgs.msg import CameraInfo
from sensor_msgs.srv import SetCameraInfo

NS = '/stereo'
PAIR_TIMEOUT_S = 10.0  # the driver's pair_timeout_s (default): a staged half pair is discarded after it


class ManagerLog:
    """The nodelet manager's output (output="screen": roslaunch.log in the run's folder)."""

    def __init__(self, out):
        self.path = os.path.join(out, 'roslaunch.log')

    def mark(self):
        try:
            return os.path.getsize(self.path)
        except OSError:
            return 0

    def lines_since(self, mark, word):
        with open(self.path, errors='replace') as f:
            f.seek(mark)
            return [re.sub(r'\x1b\[[0-9;]*m', '', line).strip() for line in f if word in line]


class Head:
    """What the probe receives from the head, and the publishers of the floods."""

    def __init__(self, out):
        self.lock = threading.Lock()
        self.logs = ManagerLog(out)
        self.me = rospy.get_name()
        self.start = None    # wall time of t = 0 (the first disparity frame)
        self.disparity = 0   # frames received
        self.bins = {}       # second since start -> disparity frames received in it
        self.solved = self.accepted = 0
        self.accepted_at = []  # t of each calibration accepted
        self.mode = None     # the driver's latest calibration_mode (a template)
        self.info = {}       # side -> latest CameraInfo (the pair in force)
        self.window = None   # the tracker's latest window observation
        self.off_image = 0   # camera_info frames with a principal point outside the image
        self.staged_cx = None  # the left cx' sent alone: no frame may carry it
        self.half_pairs = 0    # left camera_info frames that carried it
        self.mode_pub = rospy.Publisher(NS + '/calibration_mode', CalibrationMode, queue_size=200)
        self.window_pub = rospy.Publisher(NS + '/calibration/window_observations', StereoPatternObservation,
                                          queue_size=30)
        rospy.Subscriber(NS + '/disparity', rospy.AnyMsg, self._on_disparity, queue_size=5)
        rospy.Subscriber(NS + '/calibration/status', CalibrationStatus, self._on_status, queue_size=10)
        rospy.Subscriber(NS + '/calibration_mode', CalibrationMode, self._on_mode, queue_size=10)
        rospy.Subscriber(NS + '/calibration/window_observations', StereoPatternObservation, self._on_window,
                         queue_size=2)
        for side in ('left', 'right'):
            rospy.Subscriber('%s/%s/camera_info' % (NS, side), CameraInfo, self._on_info, side, queue_size=10)

    def _mine(self, msg):
        return msg._connection_header.get('callerid') == self.me

    def _on_disparity(self, _):
        now = time.time()
        with self.lock:
            self.disparity += 1
            if self.start is not None:
                second = int(now - self.start)
                self.bins[second] = self.bins.get(second, 0) + 1

    def _on_status(self, msg):
        with self.lock:
            self.solved += 1
            self.accepted += int(msg.accepted)
            if msg.accepted and self.start is not None:
                self.accepted_at.append(time.time() - self.start)

    def _on_mode(self, msg):
        if not self._mine(msg):
            with self.lock:
                self.mode = msg

    def _on_window(self, msg):
        if not self._mine(msg):
            with self.lock:
                self.window = msg

    def _on_info(self, msg, side):
        outside = not (0 <= msg.K[2] <= msg.width and 0 <= msg.K[5] <= msg.height and
                       0 <= msg.P[2] <= msg.width and 0 <= msg.P[6] <= msg.height)
        with self.lock:
            self.info[side] = msg
            self.off_image += int(outside)
            if side == 'left' and self.staged_cx is not None and abs(msg.P[2] - self.staged_cx) < 1e-6:
                self.half_pairs += 1

    def now(self):
        """(t, disparity frames so far)."""
        with self.lock:
            return time.time() - self.start, self.disparity

    def latest(self, name):
        with self.lock:
            return getattr(self, name)


class Flood:
    """One flood: its phases (label, t0, t1, disparity frames), what the head answered, and the
    checks of those answers (ok, what) for the summary."""

    def __init__(self, kind, head):
        self.kind, self.head = kind, head
        self.phases = []
        self.answers = []
        self.checks = []
        self.log_mark = head.logs.mark()

    def check(self, ok, what):
        self.checks.append((bool(ok), what))

    def phase(self, label, run):
        t0, n0 = self.head.now()
        run()
        t1, n1 = self.head.now()
        self.phases.append((label, t0, t1, n1 - n0))

    @property
    def start(self):
        return self.phases[0][1] if self.phases else float('nan')

    @property
    def end(self):
        return self.phases[-1][2] if self.phases else float('nan')

    def rate(self):
        seconds = sum(t1 - t0 for _, t0, t1, _ in self.phases)
        return sum(n for *_, n in self.phases) / seconds if seconds > 0 else float('nan')

    def logged(self, word, what):
        """Answers with the manager's log lines naming `word` since the flood began."""
        lines = self.head.logs.lines_since(self.log_mark, word)
        if lines:
            self.answers.append('%s: %d line(s), e.g. %s' % (what, len(lines), lines[0][:220]))
        else:
            self.answers.append('%s: none' % what)
        return lines


def paced(hz, seconds, stop, send):
    """Calls send() `hz` times a second for `seconds` (pacing a publisher); returns the count."""
    sent, next_t = 0, time.time()
    until = next_t + seconds
    while time.time() < until and not stop.is_set():
        send()
        sent += 1
        next_t += 1.0 / hz
        time.sleep(max(0.0, next_t - time.time()))
    return sent


def modes_flood(head, stop, kind, offset_s):
    """calibration_mode at 30 then 200 Hz, stamped offset_s() after the driver's latest frame."""
    flood, rng = Flood(kind, head), random.Random(7)

    def send():
        template = head.latest('mode')
        mode = CalibrationMode(header=copy.copy(template.header), calibration_epoch=template.calibration_epoch,
                               light_on=rng.random() < 0.5, settled=rng.random() < 0.5)
        mode.header.stamp = head.latest('info')['left'].header.stamp + rospy.Duration(offset_s(rng))
        head.mode_pub.publish(mode)

    for hz in (30, 200):
        flood.phase('%d Hz' % hz, lambda: flood.answers.append('%d sent at %d Hz' % (paced(hz, 5.0, stop, send), hz)))
    time.sleep(3.0)  # the warnings are throttled to one per 5 s: the last one comes within 3 s
    lines = flood.logged('calibration_mode', 'manager log lines naming calibration_mode')
    flood.check(lines, 'a warning naming calibration_mode in the log')
    return flood


def modes_ahead(head, stop):
    return modes_flood(head, stop, 'calibration_mode ahead', lambda rng: rng.uniform(0.5, 1.9))


def modes_live(head, stop):
    return modes_flood(head, stop, 'calibration_mode live', lambda rng: 0.0)


def off_image(info, index_pairs, shift):
    """A copy of `info` with K and P elements (index in K, index in P) moved by `shift` px."""
    bad = copy.deepcopy(info)
    bad.K, bad.P = list(bad.K), list(bad.P)
    for k, p in index_pairs:
        bad.K[k] += shift
        bad.P[p] += shift
    return bad


def camera_info_flood(head, stop):
    """Principal points far off the image on both cameras, then cx' changed on the left alone."""
    flood = Flood('set_camera_info', head)
    proxies = {side: rospy.ServiceProxy('%s/%s/set_camera_info' % (NS, side), SetCameraInfo, persistent=True)
               for side in ('left', 'right')}
    in_force = dict(head.latest('info'))
    cases = [("cy' and cy +100000 px", [(5, 6)], 100000.0), ("cx' and cx +5000 px", [(2, 2)], 5000.0)]
    answers = {}  # (case, side, success, message) -> calls

    def call(side, info):
        try:
            response = proxies[side](info)
            return response.success, response.status_message
        except (rospy.ServiceException, rospy.ROSException) as e:
            return None, 'call failed: %s' % e

    def refused_flood():
        until = time.time() + 8.0
        while time.time() < until and not stop.is_set():
            for name, index_pairs, shift in cases:
                for side in ('left', 'right'):
                    key = (name, side) + call(side, off_image(in_force[side], index_pairs, shift))
                    answers[key] = answers.get(key, 0) + 1
            time.sleep(0.05)  # about 40 calls a second, answered one by one

    flood.phase('off the image', refused_flood)
    flood.logged('set_camera_info refused', 'manager log lines on the refusals')
    for (name, side, success, message), calls in sorted(answers.items(), key=str):
        flood.answers.append('%s, %s: %d call(s), success %s: %s' % (name, side, calls, success, message))
    refused = sum(n for (_, _, success, _), n in answers.items() if success is False)
    flood.check(refused == sum(answers.values()) > 0,
                '%d of %d calibrations off the image refused' % (refused, sum(answers.values())))
    half = copy.deepcopy(head.latest('info')['left'])
    half.P = list(half.P)
    half.P[2] += 4.0
    with head.lock:
        head.staged_cx = half.P[2]
    answer = call('left', half)  # right after the flood: within the 3 s left out after it
    flood.answers.append("cx' +4 px on the left alone: success %s: %s" % tuple(answer))
    flood.check(answer[0] and answer[1].startswith('staged:'), 'the half pair staged')
    time.sleep(PAIR_TIMEOUT_S + 2.0)  # the driver discards it after pair_timeout_s
    lines = flood.logged('discarded', 'manager log lines on the staged half pair')
    flood.check(lines, 'the half pair discarded')
    return flood


def window_flood(head, stop):
    """Exact copies of the tracker's latest window observation, then noisy ones, at 30 Hz."""
    flood = Flood('window observations', head)
    if head.latest('window') is None:
        flood.answers.append('skipped: the tracker has published no window observation yet')
        flood.check(False, 'a window observation to copy')
        return flood
    last, rng = [rospy.Time()], random.Random(11)

    def send(noise_px):
        # Each 1 ms after the previous one (and after the tracker's latest window): a new stamp,
        # still far before the tracker's next window, which is not dropped.
        msg = copy.deepcopy(head.latest('window'))
        msg.header.stamp = max(msg.header.stamp, last[0]) + rospy.Duration(0.001)
        last[0] = msg.header.stamp
        for board in (msg.left + msg.right) if noise_px > 0 else []:
            board.u = [u + rng.gauss(0.0, noise_px) for u in board.u]
            board.v = [v + rng.gauss(0.0, noise_px) for v in board.v]
        head.window_pub.publish(msg)

    for label, noise_px in (('exact copies', 0.0), ('noisy copies', 0.05)):
        solved0, accepted0 = head.latest('solved'), head.latest('accepted')
        flood.phase(label, lambda: flood.answers.append('%d %s sent' % (
            paced(30, 5.0, stop, lambda: send(noise_px)), label)))
        time.sleep(2.0 if noise_px == 0 else 3.0)  # the solves started during the phase end
        solved, accepted = head.latest('solved') - solved0, head.latest('accepted') - accepted0
        flood.answers.append('%s: calibrations solved during them and after: %d (%d accepted)' % (
            label, solved, accepted))
        if noise_px == 0:  # copies teach nothing new: none may be solved, let alone committed
            flood.check(solved == 0, 'exact copies of one window: %d solved (expected: none)' % solved)
        else:
            flood.check(solved <= 5 + 3 + 1, 'noisy copies: %d solved in about 8 s (paced: at most one a second '
                        'and two waiting)' % solved)
    flood.logged('a copy of one seen before', 'manager log lines on dropped copies')
    flood.logged('dropped unsolved', 'manager log lines on solves dropped by the pacing')
    return flood


def recalibrate(head, stop):
    """One calibration/recalibrate call, as a user would make it (docs/nodelets.md)."""
    flood = Flood('recalibrate', head)
    proxy = rospy.ServiceProxy(NS + '/calibration/recalibrate', Recalibrate)

    def call():
        try:
            r = proxy(frames=10, timeout_s=10.0, dry_run=False)
            flood.answers.append('success %s: %s' % (r.success, r.message))
            flood.check(r.success, 'recalibrate succeeded')
        except (rospy.ServiceException, rospy.ROSException) as e:
            flood.answers.append('call failed: %s' % e)
            flood.check(False, 'recalibrate answered')

    flood.phase('call', call)
    return flood


# recalibrate before the window observations: the tracker publishes them only after a light burst,
# and on demand the head may not have had one since the start.
KINDS = [modes_ahead, modes_live, camera_info_flood, recalibrate, window_flood]
FIRST_RECALIBRATION_S = 30.0
LONGEST_S = 25.0  # the longest kind (set_camera_info: 8 s, then pair_timeout_s + 2 s)


class Schedule(threading.Thread):
    """A flood every `every` s from t = `every`, cycling through KINDS, none past `end_s`."""

    def __init__(self, head, every, end_s):
        super().__init__(daemon=True)
        self.head, self.every, self.end_s = head, every, end_s
        self.stop = threading.Event()
        self.done = []  # finished floods, in order

    def run(self):
        # A user's first forced recalibration, early: the head's first calibration (and the memory
        # it takes) falls within the minutes before memory is judged.
        if not self.stop.wait(max(0.0, FIRST_RECALIBRATION_S - self.head.now()[0])):
            self.done.append(recalibrate(self.head, self.stop))
        at, k = self.every, 0
        while at + LONGEST_S <= self.end_s and not self.stop.wait(max(0.0, at - self.head.now()[0])):
            self.done.append(KINDS[k % len(KINDS)](self.head, self.stop))
            k += 1
            at = max(at + self.every, self.head.now()[0])  # a flood that overran delays the next
