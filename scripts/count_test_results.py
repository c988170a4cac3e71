#!/usr/bin/env python3
"""Counts passed, failed and skipped test cases in a catkin test_results folder.

Usage: count_test_results.py FOLDER
Prints one "FAILED: ..." line per failure, then "COUNTS passed failed skipped".
"""
import glob, os, sys, xml.etree.ElementTree as ET
folder = sys.argv[1]
passed = failed = skipped = 0
failures = []

def cases(path):
    try:
        return list(ET.parse(path).getroot().iter("testcase")), None
    except ET.ParseError as e:
        return [], str(e)

def failed_case(case):
    return case.find("failure") is not None or case.find("error") is not None

def failure_text(found):
    """What the failed cases say (rostest: "did not generate test results", a process died)."""
    texts = []
    for case in found:
        for tag in ("failure", "error"):
            for f in case.findall(tag):
                text = " ".join(filter(None, [f.get("message"), f.get("type"), (f.text or "").strip()]))
                texts.append(" ".join(text.split())[:400])
    return "; ".join(texts)

# gtest-*.xml: one case per gtest; rosunit-*.xml: the cases of a rostest's gtest node.
# rostest-*.xml holds one case per launch file: it counts only when the launch itself failed
# (a node died, no result) and none of its cases says so already.
rosunit_failed = {}
for path in sorted(glob.glob(os.path.join(folder, "*.xml"))):
    name = os.path.basename(path)
    if name.startswith("rostest-"):
        continue
    found, error = cases(path)
    if error or not found:
        failed += 1
        failures.append(f"{name}: {'unreadable result (' + error + ')' if error else 'no test case ran'}")
        continue
    for case in found:
        label = f"{case.get('classname', '')}.{case.get('name', '')}"
        if failed_case(case):
            failed += 1
            failures.append(f"{name}: {label}")
            if name.startswith("rosunit-"):
                rosunit_failed[name[len("rosunit-"):-len(".xml")]] = True
        elif case.find("skipped") is not None or case.get("status") == "notrun":
            skipped += 1
        else:
            passed += 1
for path in sorted(glob.glob(os.path.join(folder, "rostest-*.xml"))):
    name = os.path.basename(path)
    found, error = cases(path)
    launch_failed = error is not None or not found or any(failed_case(c) for c in found)
    explained = any(name[:-len(".xml")].endswith(node) for node in rosunit_failed)
    if launch_failed and not explained:
        failed += 1
        why = error or failure_text(found) or "no test case"
        failures.append(f"{name}: the rostest itself failed: {why}")
for f in failures:
    print("FAILED:", f)
print(f"COUNTS {passed} {failed} {skipped}")
