#!/usr/bin/env python3
"""Test helper: publishes map_server map files latched, one OccupancyGrid per topic.

Params: ~maps: list of "topic=relative/or/absolute.yaml[@kind]" (relative to the repo's data/samples; kind: how a
SLAM package publishes it, see mm_common / map_kinds.py); ~frame_ids
(optional list, same order; default: '<topic ns>/map'); ~delay (s, default 0) before publishing; ~lifetime (s,
default 0 = forever): exit after it (a robot that vanishes).
"""
import rospy
from nav_msgs.msg import OccupancyGrid

from mm_common import load_spec
from multirobot_map_merge.ros.conversions import grid_to_msg


def main():
    rospy.init_node('mm_sample_map_publisher')
    specs = rospy.get_param('~maps')
    frames = rospy.get_param('~frame_ids', [])
    rospy.sleep(float(rospy.get_param('~delay', 0.0)))
    pubs = []
    for k, spec in enumerate(specs):
        topic = spec.split('=', 1)[0]
        frame = frames[k] if k < len(frames) else topic.rsplit('/', 1)[0].strip('/') + '/map'
        grid = load_spec(spec, frame, seed=k)[1]
        pub = rospy.Publisher(topic, OccupancyGrid, queue_size=1, latch=True)
        pub.publish(grid_to_msg(grid, stamp=rospy.Time.now()))
        pubs.append(pub)
    lifetime = float(rospy.get_param('~lifetime', 0.0))
    if lifetime > 0:
        rospy.sleep(lifetime)
    else:
        rospy.spin()


if __name__ == '__main__':
    main()
