#!/usr/bin/env python3
"""rostest: the reference docs say what the code does (docs_match_code.test).

- Launch files: every argument a user can set (`<arg name=... default=...>`) is documented where
  its launch file is (docs/running.md, docs/external_driver.md), with the same default where the
  doc gives one in a table and the launch file a literal; every argument a doc table names
  exists in that launch file.
- Nodelets: every parameter a nodelet reads (ParameterReader calls and the readers built on it,
  the Disparity's dynamic_reconfigure file) is named in its section of docs/nodelets.md, and every
  name in a section's parameter table is read by that nodelet; every topic and service a nodelet
  advertises or subscribes is named in its section.
A renamed argument, parameter or topic left behind in the docs fails here.
"""
import os
import re
import sys
import unittest
import xml.etree.ElementTree as ET

import rospkg

PKG = 'embedded_calibration_stereo'
ROOT = os.environ.get('ECS_DOCS_ROOT') or rospkg.RosPack().get_path(PKG)


def read(path):
    with open(os.path.join(ROOT, path)) as f:
        return f.read()


def section(markdown, title, level='##'):
    """The text of a markdown section, from its heading to the next heading of its level."""
    match = re.search(r'^%s %s\b.*?(?=^%s |\Z)' % (level, re.escape(title), level), markdown, re.M | re.S)
    return match.group(0) if match else ''


def table_rows(text, first_header):
    """Rows (cells stripped) of the tables whose first header cell is `first_header`."""
    rows, inside = [], False
    for line in text.split('\n'):
        cells = [c.strip().replace('\0', '|') for c in line.replace('\\|', '\0').strip().strip('|').split('|')]
        if line.startswith('|') and cells[0].strip('`') == first_header:
            inside = True
        elif inside and line.startswith('|'):
            if not set(line) <= set('|-: '):
                rows.append(cells)
        else:
            inside = False
    return rows


def names_of(cell):
    """The names of a first cell: 'a, b' or '`a`, `b`' or 'a / b'."""
    return [n.strip().strip('`').strip() for n in re.split(r',|/ ', cell) if n.strip().strip('`').strip()]


def mentions(text, name):
    return re.search(r'(?<![A-Za-z0-9_])%s(?![A-Za-z0-9_])' % re.escape(name), text) is not None


# ---------------------------------------------------------------- launch files

def launch_args(launch):
    """{name: default} of the arguments a user can set (value= arguments are internal)."""
    root = ET.parse(os.path.join(ROOT, 'launch', launch)).getroot()
    return {a.get('name'): a.get('default') for a in root.findall('arg') if a.get('default') is not None}


def literal(value):
    return value is not None and '$(' not in value


def same_default(documented, actual):
    """A documented default matches the launch file's literal default (quotes, backticks and an
    explanation after it aside)."""
    doc = documented.replace('\\*', '*').strip().strip('`').strip()
    if actual == '':
        return doc.startswith(('""', "''", '"" ', '(empty)', '-')) or doc == ''
    return doc.split(' ')[0].strip('`"').rstrip(',;') == actual


# Where each launch file's arguments are documented: (file, section title or None for the whole file).
LAUNCH_DOCS = {
    'embedded_stereo.launch': ('docs/running.md', 'embedded_stereo.launch'),
    'external_driver.launch': ('docs/external_driver.md', None),
    'demo.launch': ('docs/running.md', 'The demo'),
    'record.launch': ('docs/running.md', 'Record and replay'),
    'replay.launch': ('docs/running.md', 'Record and replay'),
}
PIECES = ['driver.launch', 'tracker.launch', 'calibrator.launch', 'health.launch', 'separator.launch',
          'depth.launch']


def pieces_table():
    """{launch file: its row's text} of docs/running.md's table of the pieces."""
    text = section(read('docs/running.md'), 'Loading pieces into a running manager')
    return {row[0].strip('`'): row[1] for row in table_rows(text, 'launch file') if len(row) > 1}


# ---------------------------------------------------------------- nodelets

# ParameterReader's calls (read.get, .atLeast, .inRange, .choice, .required) and the readers built on
# them (readBytes, the calibrator's non_negative).
READER_CALL = re.compile(
    r'(?:\.(?:get|atLeast|inRange|choice|required)(?:<[^>]*>)?|\breadBytes|\bnon_negative)\(\s*(?:read,\s*)?"([a-z][a-z_0-9]*)"')
CFG_PARAM = re.compile(r'gen\.add\(\s*"([A-Za-z_0-9]+)"')
TOPIC_CALL = re.compile(
    r'(?:advertise(?:Camera|Service)?|subscribe|serviceClient)\s*(?:<[^;()]*?>)?\s*\(\s*(?:[a-z_]+,\s*)?"([^"]+)"')
NODELETS = {
    'CameraDriver': ['src/ros/driver_params.cpp', 'src/ros/light_backend.cpp:readLightBackendParams',
                     'src/nodelets/camera_driver.cpp'],
    'LightController': ['src/ros/light_controller_params.cpp', 'src/ros/light_backend.cpp:readLightBackendParams',
                        'src/ros/driver_params.cpp:readHealthSchedule', 'src/ros/driver_params.cpp:readBurstSchedule',
                        'src/nodelets/light_controller.cpp'],
    'PatternTracker': ['src/nodelets/pattern_tracker.cpp'],
    'OnlineCalibrator': ['src/ros/calibration_session.cpp', 'src/nodelets/online_calibrator.cpp'],
    'CalibrationHealth': ['src/ros/calibration_health_io.cpp', 'src/nodelets/calibration_health.cpp'],
    'Separator': ['src/nodelets/separator.cpp'],
    'Rectifier': ['src/nodelets/rectifier.cpp'],
    'Disparity': ['src/nodelets/disparity.cpp', 'cfg/Disparity.cfg'],
}
# Read by every nodelet through a shared helper (documented once, in "Stamps, service limits,
# persistence") or by diagnostic_updater.
SHARED_PARAMETERS = {'stamp_tolerance_s', 'diagnostic_period'}
# Parameters each nodelet reads through a shared helper (the stamp guard, the synchronised input).
HELPERS = {'src/ros/stamp_guard.cpp', 'src/ros/lazy_synced_input.cpp', 'src/ros/stereo_camera_input.cpp'}


def code_of(path):
    """A file's code without comments; 'file:function': that function's definition only."""
    path, _, function = path.partition(':')
    code = strip_comments(read(path))
    if function:
        start = re.search(r'^\S[^\n]*\b%s\([^;{]*\{' % re.escape(function), code, re.M)
        code = code[start.start():code.index('\n}', start.start())] if start else ''
    return code


def strip_comments(code):
    return re.sub(r'//[^\n]*|/\*.*?\*/', '', code, flags=re.S)


def parameters_read(files):
    names = set()
    for path in files:
        code = code_of(path)
        names |= set(CFG_PARAM.findall(code) if path.endswith('.cfg') else READER_CALL.findall(code))
    return names


def topics_used(files):
    names = set()
    for path in files:
        if path.endswith('.cpp') and 'nodelets' in path:
            names |= {n for n in TOPIC_CALL.findall(code_of(path)) if not n.startswith('/')}
    return names


class DocsMatchCode(unittest.TestCase):
    def test_launch_arguments_are_documented_with_their_defaults(self):
        problems = []
        for launch, (doc, title) in LAUNCH_DOCS.items():
            text = read(doc) if title is None else section(read(doc), title)
            self.assertTrue(text, '%s: no section %r' % (doc, title))
            args = launch_args(launch)
            for name, default in sorted(args.items()):
                if not mentions(text, name):
                    problems.append('%s: argument %s (default %r) is not documented in %s' % (
                        launch, name, default, doc))
            for row in table_rows(text, 'argument'):
                names = names_of(row[0])
                for i, name in enumerate(names):
                    if launch in ('record.launch', 'replay.launch') and name not in args:
                        continue  # one section documents both: the other file's argument
                    if name not in args and not any(name in launch_args(other) for other in LAUNCH_DOCS):
                        problems.append('%s documents argument %s, which %s does not have' % (doc, name, launch))
                        continue
                    if name not in args or len(row) < 2 or not literal(args[name]):
                        continue
                    defaults = [d.strip() for d in row[1].split(',')] if len(names) > 1 else [row[1]]
                    if len(defaults) == len(names) and not same_default(defaults[i], args[name]):
                        problems.append('%s: argument %s defaults to %r, %s says %r' % (
                            launch, name, args[name], doc, defaults[i]))
        self.assertEqual(problems, [], '\n' + '\n'.join(problems))

    def test_every_piece_launch_file_lists_its_arguments(self):
        rows, problems = pieces_table(), []
        for launch in PIECES:
            self.assertIn(launch, rows, 'docs/running.md: no row for %s' % launch)
            for name in sorted(launch_args(launch)):
                row = re.sub(r'left/right_([a-z_]+)', r'left_\1 right_\1', rows[launch])
                if not mentions(row, name):
                    problems.append('%s: argument %s is not in docs/running.md\'s table' % (launch, name))
        self.assertEqual(problems, [], '\n' + '\n'.join(problems))

    def test_nodelet_parameters_are_documented_and_exist(self):
        docs, problems = read('docs/nodelets.md'), []
        for nodelet, files in NODELETS.items():
            text = section(docs, nodelet)
            self.assertTrue(text, 'docs/nodelets.md: no section %s' % nodelet)
            read_names = parameters_read(files)
            for name in sorted(read_names - SHARED_PARAMETERS):
                if not mentions(text, name):
                    problems.append('%s reads parameter %s; docs/nodelets.md does not name it there' % (nodelet, name))
            for row in table_rows(text, 'parameter') + table_rows(text, 'parameter (dynamic_reconfigure)'):
                for name in names_of(row[0]):
                    if name not in read_names and name not in SHARED_PARAMETERS:
                        problems.append('docs/nodelets.md documents %s parameter %s, which it does not read' % (
                            nodelet, name))
        self.assertEqual(problems, [], '\n' + '\n'.join(problems))

    def test_nodelet_topics_and_services_are_documented(self):
        docs, problems = read('docs/nodelets.md'), []
        for nodelet, files in NODELETS.items():
            text = section(docs, nodelet)
            for name in sorted(topics_used(files)):
                if not mentions(text, name):
                    problems.append('%s uses topic or service %s; docs/nodelets.md does not name it there' % (
                        nodelet, name))
        self.assertEqual(problems, [], '\n' + '\n'.join(problems))


if __name__ == '__main__':
    if '--standalone' in sys.argv:  # without ROS: python3 docs_match_code.py --standalone
        sys.argv.remove('--standalone')
        unittest.main()
    else:
        import rostest
        rostest.rosrun(PKG, 'docs_match_code', DocsMatchCode)
