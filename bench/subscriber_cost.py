#!/usr/bin/env python3
"""What one rospy subscriber costs its own process, per message received.

  subscriber_cost.py TOPIC TYPE [--buff-size BYTES] [--seconds S]

TYPE is a message type ("stereo_msgs/DisparityImage", "sensor_msgs/Image") or "any" (rospy.AnyMsg:
received, not deserialised). Subscribes with queue_size 2, waits 3 s, then counts the messages
and the process CPU time for S seconds (default 15) and prints the rate, the CPU as a share of a
core and per message. Run against a running graph (ROS_MASTER_URI set), for example demo.launch:
the demo's monitor subscribes so to the head's images and disparity.
"""
import argparse
import importlib
import time

import rospy


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("topic")
    parser.add_argument("type")
    parser.add_argument("--buff-size", type=int, default=2 ** 24)
    parser.add_argument("--seconds", type=float, default=15.0)
    args = parser.parse_args()
    if args.type == "any":
        cls = rospy.AnyMsg
    else:
        package, name = args.type.split("/")
        cls = getattr(importlib.import_module(package + ".msg"), name)
    rospy.init_node("subscriber_cost", anonymous=True)
    count = [0]

    def received(_):
        count[0] += 1

    rospy.Subscriber(args.topic, cls, received, queue_size=2, buff_size=args.buff_size)
    time.sleep(3.0)  # connection and warm-up; the count starts after it
    count[0] = 0
    cpu0, wall0 = time.process_time(), time.time()
    time.sleep(args.seconds)
    cpu, wall, n = time.process_time() - cpu0, time.time() - wall0, count[0]
    print("%s (%s, buff_size %d): %d messages, %.1f Hz; CPU %.1f %% of a core, %.2f ms a message" % (
        args.topic, args.type, args.buff_size, n, n / wall, 100.0 * cpu / wall, 1e3 * cpu / max(n, 1)))


if __name__ == "__main__":
    main()
