#!/usr/bin/env python3
"""Test helper: keeps publishing malformed input, once per second, cycling through the cases.

Full maps on ~map_topic (a robot of its own): data length != width * height, NaN resolution, zero resolution,
negative resolution, an infinite or NaN origin, a huge width x height with little data. Updates on ~updates_topic
(of a good robot): out of bounds, wrong data length, negative x.
"""
import itertools

import rospy
from map_msgs.msg import OccupancyGridUpdate
from nav_msgs.msg import OccupancyGrid


def bad_map(case):
    m = OccupancyGrid()
    m.header.stamp = rospy.Time.now()
    m.header.frame_id = 'bad/map'
    m.info.resolution, m.info.width, m.info.height = 0.05, 10, 10
    m.info.origin.orientation.w = 1.0
    m.data = [0] * 100
    if case == 'length':
        m.data = [0] * 99
    elif case == 'nan':
        m.info.resolution = float('nan')
    elif case == 'zero':
        m.info.resolution = 0.0
    elif case == 'negative':
        m.info.resolution = -0.05
    elif case == 'inf_origin':
        m.info.origin.position.x = float('inf')
    elif case == 'nan_origin':
        m.info.origin.position.y = float('nan')
    elif case == 'huge':
        m.info.width, m.info.height = 100000, 100000
    return m


def bad_update(case):
    u = OccupancyGridUpdate()
    u.header.stamp = rospy.Time.now()
    u.x, u.y, u.width, u.height = 0, 0, 2, 2
    u.data = [100] * 4
    if case == 'outside':
        u.x = 100000
    elif case == 'length':
        u.data = [100] * 3
    elif case == 'negative':
        u.x = -5
    return u


def main():
    rospy.init_node('mm_bad_map_publisher')
    map_pub = rospy.Publisher(rospy.get_param('~map_topic', '/robot3/map'), OccupancyGrid, queue_size=5, latch=True)
    upd_pub = rospy.Publisher(rospy.get_param('~updates_topic', '/robot1/map_updates'), OccupancyGridUpdate,
                              queue_size=5)
    maps = itertools.cycle(['length', 'nan', 'zero', 'negative', 'inf_origin', 'nan_origin', 'huge'])
    updates = itertools.cycle(['outside', 'length', 'negative'])
    while not rospy.is_shutdown():
        map_pub.publish(bad_map(next(maps)))
        upd_pub.publish(bad_update(next(updates)))
        try:
            rospy.sleep(0.5)
        except rospy.ROSInterruptException:
            break


if __name__ == '__main__':
    main()
