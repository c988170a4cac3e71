#!/usr/bin/env python3
"""rostest: the package installs and runs like a ROS package (package_install.test).

- catkin_lint -W2 finds no problem in the package.
- `cmake --install` of the test's workspace (what `catkin_make install` does) fills its install
  space; a shell that sources only that install space finds the package there, its nodelets'
  plugin description, its launch files (roslaunch --nodes on the whole head), and runs the
  installed driver.launch on the simulator (its own master): calibration_mode comes.
"""
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import unittest

import rospkg

PKG = 'embedded_calibration_stereo'


def workspace():
    """The catkin workspace of this test: the parent of the devel space on CMAKE_PREFIX_PATH
    that has a build folder."""
    for prefix in os.environ.get('CMAKE_PREFIX_PATH', '').split(':'):
        ws = os.path.dirname(prefix.rstrip('/'))
        if prefix.rstrip('/').endswith('/devel') and os.path.isfile(os.path.join(ws, 'build', 'CMakeCache.txt')):
            return ws
    return None


def in_install_space(ws, script, timeout_s):
    """Runs `script` in bash with only the install space sourced (a clean environment)."""
    env = {'HOME': os.environ.get('HOME', '/tmp'), 'PATH': '/usr/bin:/bin',
           'ROS_HOME': tempfile.mkdtemp(prefix='ecs_install_ros_home_')}
    command = 'set -e; source "%s/install/setup.bash"; %s' % (ws, script)
    return subprocess.run(['bash', '-c', command], env=env, capture_output=True, text=True, timeout=timeout_s)


def free_port():
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


class PackageInstall(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.ws = workspace()
        cls.source = rospkg.RosPack().get_path(PKG)

    def test_catkin_lint_finds_nothing(self):
        result = subprocess.run(['catkin_lint', '-W2', self.source], capture_output=True, text=True, timeout=120)
        self.assertIn('found 0 problems', result.stdout + result.stderr, result.stdout + result.stderr)

    def test_the_install_space_runs_the_head(self):
        self.assertIsNotNone(self.ws, 'no workspace with a build folder on CMAKE_PREFIX_PATH')
        shutil.rmtree(os.path.join(self.ws, 'install'), ignore_errors=True)  # nothing left from an earlier install
        install = subprocess.run(['cmake', '--install', os.path.join(self.ws, 'build')], capture_output=True,
                                 text=True, timeout=300)
        self.assertEqual(install.returncode, 0, install.stdout[-2000:] + install.stderr[-2000:])
        share = os.path.join(self.ws, 'install', 'share', PKG)
        found = in_install_space(self.ws, 'rospack find %s; rospack plugins --attrib=plugin nodelet; '
                                 'roslaunch --nodes %s embedded_stereo.launch camera_backend:=sim' % (PKG, PKG), 60)
        self.assertEqual(found.returncode, 0, found.stdout + found.stderr)
        lines = found.stdout.split('\n')
        self.assertEqual(lines[0], share, 'the package is not found in the install space')
        self.assertIn('%s %s/nodelet_plugins.xml' % (PKG, share), found.stdout)
        for node in ('/stereo/camera_driver', '/stereo/online_calibrator', '/stereo/calibration_health',
                     '/stereo/disparity'):
            self.assertIn(node, lines)
        # The installed driver on the simulator, on a master of its own: its frames come.
        port = free_port()
        run = in_install_space(self.ws, (
            'export ROS_MASTER_URI=http://127.0.0.1:%d; '
            'roslaunch -p %d %s driver.launch fps:=10 calibration_period_s:=0 '
            'left_camera_info_url:=file://$ROS_HOME/l.yaml right_camera_info_url:=file://$ROS_HOME/r.yaml '
            '> $ROS_HOME/launch.log 2>&1 & launch=$!; '
            'for i in $(seq 150); do rostopic list > /dev/null 2>&1 && break; sleep 0.2; done; '  # the master starting
            'timeout 60 rostopic echo -n 1 /stereo/calibration_mode/calibration_epoch; status=$?; '
            'kill -INT $launch; wait $launch || true; '
            '[ $status -eq 0 ] || tail -20 $ROS_HOME/launch.log; exit $status') % (port, port, PKG), 120)
        self.assertEqual(run.returncode, 0, 'no calibration_mode from the installed driver:\n' + run.stdout + run.stderr)


if __name__ == '__main__':
    import rostest
    rostest.rosrun(PKG, 'package_install', PackageInstall)
