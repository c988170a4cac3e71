#!/usr/bin/env python3
"""rostest: no launch file a user runs teaches, learns or calibrates from the simulator's truth.

The simulator's truth (ground_truth/ topics) scores the head and never helps it. Every launch
file in launch/ is loaded as roslaunch would load it (roslaunch.config, includes resolved), with
its default arguments and with the simulated backend where it has one, and:
- no parameter whose name ends in `ground_truth` (teach_from_ground_truth and the like) is true;
- no node subscribes a ground_truth/ topic through a remap, or is given one as a parameter.
record.launch may record the truth (ground_truth:=true): recording is not teaching, and its
default records none. Tests of single components set the test-only parameters themselves.
"""
import glob
import os
import sys
import unittest

import roslaunch.config
import rospkg

PKG = 'embedded_calibration_stereo'
ROOT = rospkg.RosPack().get_path(PKG)

# The arguments a launch file needs or a user typically gives; each file also loads with the
# simulated backend where it has one.
REQUIRED = {'replay.launch': ['bag:=/tmp/none.bag']}
VARIANTS = {
    'embedded_stereo.launch': [[], ['camera_backend:=sim'], ['camera_backend:=sim', 'window_tracking:=true']],
    'demo.launch': [[], ['scenario:=sim_rig'], ['scenario:=handheld_photo']],
    'external_driver.launch': [[], ['window_tracking:=true']],
}


def load(path, args):
    return roslaunch.config.load_config_default([(path, args)], None, verbose=False)


def truth_uses(config):
    """What in a loaded launch configuration takes the truth: a list of sentences."""
    found = []
    for name, param in sorted(config.params.items()):
        if name.rstrip('/').endswith('ground_truth') and param.value is True:
            found.append('parameter %s is true' % name)
        if isinstance(param.value, str) and 'ground_truth/' in param.value:
            found.append('parameter %s names %s' % (name, param.value))
    for node in config.nodes:
        for source, target in node.remap_args:
            if 'ground_truth' in target:
                found.append('node %s remaps %s to %s' % (node.name, source, target))
    return found


class ProductLaunchFilesTakeNoTruth(unittest.TestCase):
    def test_every_launch_file(self):
        files = sorted(glob.glob(os.path.join(ROOT, 'launch', '*.launch')))
        self.assertGreaterEqual(len(files), 10, 'launch files not found under %s' % ROOT)
        checked = 0
        for path in files:
            name = os.path.basename(path)
            for variant in VARIANTS.get(name, [[]]):
                args = REQUIRED.get(name, []) + variant
                config = load(path, args)
                uses = truth_uses(config)
                self.assertEqual(uses, [], '%s %s: %s' % (name, ' '.join(args), '; '.join(uses)))
                checked += 1
        print('%d launch configurations of %d files checked: none takes the truth' % (checked, len(files)))

    def test_the_check_finds_a_truth_parameter(self):
        """The check itself: the test-only parameter set on the demo's tracker is found."""
        config = load(os.path.join(ROOT, 'launch', 'demo.launch'), [])
        for name in config.params:
            if name.endswith('/pattern_tracker/teach_from'):
                config.params[name.replace('teach_from', 'teach_from_ground_truth')] = \
                    roslaunch.core.Param(name.replace('teach_from', 'teach_from_ground_truth'), True)
                break
        else:
            self.fail('demo.launch has no pattern_tracker/teach_from parameter')
        self.assertEqual(len(truth_uses(config)), 1)


if __name__ == '__main__':
    import rostest
    rostest.rosrun(PKG, 'product_launch_truth', ProductLaunchFilesTakeNoTruth, sys.argv)
