#!/usr/bin/env python3
"""rostest: the bring-up check on simulator bags (bringup_check.test).

render_scenario_bag makes a clean bag of the still simulated head (7 s at 15 fps, a light burst
every 3 s); copies of it carry one defect each, made here:
- cameras 10 ms apart: the right images and camera_infos stamped 10 ms later;
- a light three frames slow: every calibration_mode says what it said three frames later (so the
  images show each switch three frames after the driver's command);
- a board covered: the left camera's board 2 (where the bag's ground truth puts its corners, a
  square and a half wider) shows, in every frame, that region of the last light-off frame;
- saturated frames: every image's grey levels times 2.5, clipped at 255.
bringup_check must say READY on the clean bag and, on each defect bag, NOT READY naming that
defect alone with its figure.
"""
import os
import re
import shutil
import subprocess
import tempfile
import unittest

import numpy as np
import rosbag
import rospkg
import rospy

PKG = 'embedded_calibration_stereo'
NS = '/stereo'
COVERED_BOARD = 2


def tool(name):
    """The built tool of this package (devel space), as rosrun would find it."""
    for prefix in os.environ.get('CMAKE_PREFIX_PATH', '').split(':'):
        path = os.path.join(prefix, 'lib', PKG, name)
        if os.path.isfile(path):
            return path
    raise RuntimeError('%s not found on CMAKE_PREFIX_PATH' % name)


def image_array(msg):
    return np.frombuffer(msg.data, dtype=np.uint8).reshape(msg.height, msg.step)


def with_array(msg, array):
    msg.data = array.astype(np.uint8).tobytes()
    return msg


def rewrite(source, target, change):
    """Copies the driver's topics of `source` into `target`, each message through change(topic,
    msg, t), which returns (msg, t) or None to drop it."""
    with rosbag.Bag(source) as inp, rosbag.Bag(target, 'w') as out:
        for topic, msg, t in inp.read_messages():
            if '/ground_truth/' in topic or topic == '/tf':
                continue
            changed = change(topic, msg, t)
            if changed is not None:
                out.write(topic, changed[0], changed[1])


def restamp_right(offset_s):
    def change(topic, msg, t):
        if topic.startswith(NS + '/right/'):
            msg.header.stamp += rospy.Duration.from_sec(offset_s)
            t = msg.header.stamp
        return msg, t
    return change


def slow_light(source, frames):
    with rosbag.Bag(source) as inp:
        modes = [m for _, m, _ in inp.read_messages(topics=[NS + '/calibration_mode'])]
    later = {m.header.stamp: modes[min(i + frames, len(modes) - 1)] for i, m in enumerate(modes)}

    def change(topic, msg, t):
        if topic == NS + '/calibration_mode':
            msg.light_on, msg.settled = later[msg.header.stamp].light_on, later[msg.header.stamp].settled
        return msg, t
    return change


def board_mask(source, board_id, shape):
    """The left camera's board from the bag's ground truth: its outer corners' quadrilateral,
    widened about its centre by a square and a half on each side."""
    with rosbag.Bag(source) as inp:
        for _, obs, _ in inp.read_messages(topics=[NS + '/ground_truth/observations']):
            for board in obs.left:
                if board.board_id != board_id:
                    continue
                ids = list(board.corner_ids)
                cols = 8
                rows = (max(ids) // cols) + 1
                corners = [ids.index(i) for i in (0, cols - 1, rows * cols - 1, (rows - 1) * cols)]
                quad = np.array([[board.u[i], board.v[i]] for i in corners])
                centre = quad.mean(axis=0)
                quad = centre + (quad - centre) * np.array([(cols - 1 + 3.0) / (cols - 1), (rows - 1 + 3.0) / (rows - 1)])
                ys, xs = np.mgrid[0:shape[0], 0:shape[1]]
                inside = np.ones(shape, dtype=bool)
                for a, b in zip(quad, np.roll(quad, -1, axis=0)):
                    cross = (b[0] - a[0]) * (ys - a[1]) - (b[1] - a[1]) * (xs - a[0])
                    inside &= cross >= 0
                if not inside.any():  # the other winding
                    inside = np.ones(shape, dtype=bool)
                    for a, b in zip(quad, np.roll(quad, -1, axis=0)):
                        inside &= (b[0] - a[0]) * (ys - a[1]) - (b[1] - a[1]) * (xs - a[0]) <= 0
                return inside
    raise RuntimeError('board %d not in the ground truth' % board_id)


def cover_board(source, board_id):
    with rosbag.Bag(source) as inp:
        first = next(m for _, m, _ in inp.read_messages(topics=[NS + '/left/image_raw']))
        modes = {m.header.stamp: m for _, m, _ in inp.read_messages(topics=[NS + '/calibration_mode'])}
        # The frames before the first unlit one (a bag may start lit) get the first unlit one's.
        first_unlit = next(image_array(m).copy() for _, m, _ in inp.read_messages(topics=[NS + '/left/image_raw'])
                           if not modes[m.header.stamp].light_on and modes[m.header.stamp].settled)
    mask = board_mask(source, board_id, (first.height, first.step))
    last_unlit = {'image': first_unlit}

    def change(topic, msg, t):
        if topic != NS + '/left/image_raw':
            return msg, t
        image = image_array(msg).copy()
        mode = modes[msg.header.stamp]
        if not mode.light_on and mode.settled:
            last_unlit['image'] = image.copy()
        else:
            image[mask] = last_unlit['image'][mask]
        return with_array(msg, image), t
    return change


def saturate(gain):
    def change(topic, msg, t):
        if topic.endswith('/image_raw'):
            msg = with_array(msg, np.minimum(image_array(msg).astype(np.float32) * gain, 255.0))
        return msg, t
    return change


class BringupCheck(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.dir = tempfile.mkdtemp(prefix='ecs_bringup_')
        source = rospkg.RosPack().get_path(PKG)
        cls.config = os.path.join(source, 'config', 'sim_rig.yaml')
        cls.clean = os.path.join(cls.dir, 'clean.bag')
        subprocess.run([tool('render_scenario_bag'), '--config', cls.config, '--out', cls.clean, '--seconds', '7',
                        '--fps', '15', '--period', '3', '--start', '1000'], check=True, capture_output=True, timeout=120)

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.dir, ignore_errors=True)

    def check(self, bag, *options):
        result = subprocess.run([tool('bringup_check'), '--bag', bag, '--device-config', self.config] + list(options),
                                capture_output=True, text=True, timeout=120)
        print(result.stdout + result.stderr)
        reasons = re.findall(r'^  - (.*)$', result.stdout, re.M)
        return result.returncode, result.stdout, reasons

    def defect(self, name, change):
        path = os.path.join(self.dir, name + '.bag')
        rewrite(self.clean, path, change)
        return self.check(path)

    def test_clean_bag_is_ready(self):
        code, out, reasons = self.check(self.clean)
        self.assertEqual(code, 0, out)
        self.assertIn('Verdict: READY', out)
        self.assertEqual(reasons, [])

    def test_clean_bag_without_the_drivers_modes_is_ready(self):
        # As behind a driver of yours: the images alone, the light's timing from them.
        code, out, reasons = self.check(self.clean, '--mode', '')
        self.assertEqual(code, 0, out)
        self.assertIn('no calibration_mode in the bag', out)
        self.assertEqual(reasons, [])

    def test_cameras_10_ms_apart(self):
        code, out, reasons = self.defect('apart', restamp_right(0.010))
        self.assertEqual(code, 1, out)
        self.assertEqual(len(reasons), 1, out)
        self.assertIn("the right image's stamp is 10.0 ms from the left's", reasons[0])

    def test_light_three_frames_slow(self):
        _, clean_out, _ = self.check(self.clean)
        clean_lag = int(re.search(r'changes 0, fully on (\d+) frames after it', clean_out).group(1))
        code, out, reasons = self.defect('slow_light', slow_light(self.clean, 3))
        self.assertEqual(code, 1, out)
        self.assertEqual(len(reasons), 1, out)
        self.assertIn('the light starts to change 3 frames after its command and is fully on %d frames after it'
                      % (clean_lag + 3), reasons[0])
        self.assertRegex(out, r'commanded at frame \d+: changes 3, ')

    def test_board_covered(self):
        code, out, reasons = self.defect('covered', cover_board(self.clean, COVERED_BOARD))
        self.assertEqual(code, 1, out)
        self.assertEqual(len(reasons), 1, out)
        self.assertRegex(reasons[0], r'^board %d in the left camera: contrast \d+\.\d grey levels' % COVERED_BOARD)

    def test_saturated_frames(self):
        code, out, reasons = self.defect('saturated', saturate(2.5))
        self.assertEqual(code, 1, out)
        self.assertTrue(reasons, out)
        for reason, camera in zip(reasons, ('left', 'right')):
            self.assertRegex(reason, r"^\d+\.\d % of the boards' pixels are clipped .* of the " + camera + " camera")


if __name__ == '__main__':
    import rostest
    rostest.rosrun(PKG, 'bringup_check', BringupCheck)
