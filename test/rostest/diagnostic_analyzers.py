#!/usr/bin/env python3
"""rostest: config/diagnostic_analyzers.yaml groups the head's own diagnostics
(diagnostic_analyzers.test). The statuses the running nodelets publish on /diagnostics are matched
against the file's GenericAnalyzer `contains` patterns as diagnostic_aggregator matches them (a
status belongs to an analyzer when its name contains one of the patterns): each status of the
head falls into exactly one group, the one of its role. (Debian's diagnostic_aggregator ships no
analyzer plugin description, so the aggregator itself cannot run here.)"""
import os
import threading
import unittest

import rospkg
import rospy
import yaml
from diagnostic_msgs.msg import DiagnosticArray

PKG = 'embedded_calibration_stereo'
# The group each task belongs to (the task: the part of the status name after ": ").
EXPECTED = {'camera_driver': 'Camera and light', 'calibration_health': 'Calibration',
            'online_calibrator': 'Calibration', 'pattern_tracker': 'Calibration', 'separator': 'Depth',
            'rectifier': 'Depth', 'disparity': 'Depth'}


def analyzers():
    path = os.path.join(rospkg.RosPack().get_path(PKG), 'config', 'diagnostic_analyzers.yaml')
    with open(path) as f:
        group = yaml.safe_load(f)['analyzers']['stereo_head']
    assert group['type'] == 'diagnostic_aggregator/AnalyzerGroup', group['type']
    return {a['path']: a['contains'] for a in group['analyzers'].values()
            if a['type'] == 'diagnostic_aggregator/GenericAnalyzer'}


class DiagnosticAnalyzers(unittest.TestCase):
    def test_each_status_of_the_head_falls_in_the_group_of_its_role(self):
        names, seen = set(), threading.Event()

        def on_diagnostics(msg):
            names.update(s.name for s in msg.status)
            if {n.split(': ')[-1] for n in names} >= set(EXPECTED):
                seen.set()

        rospy.Subscriber('/diagnostics', DiagnosticArray, on_diagnostics, queue_size=50)
        self.assertTrue(seen.wait(60.0), 'statuses seen: %s' % sorted(names))
        groups = analyzers()
        for name in sorted(names):
            task = name.split(': ')[-1]
            if task not in EXPECTED:
                continue
            matched = [path for path, patterns in groups.items() if any(p in name for p in patterns)]
            self.assertEqual(matched, [EXPECTED[task]], 'status %r' % name)


if __name__ == '__main__':
    import rostest
    rospy.init_node('diagnostic_analyzers_test')
    rostest.rosrun(PKG, 'diagnostic_analyzers', DiagnosticAnalyzers)
