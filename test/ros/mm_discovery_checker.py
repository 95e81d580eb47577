#!/usr/bin/env python3
"""rostest node: map_merge discovers exactly the robots it should (map_merge.md §3) and publishes latched.

Params: ~node (the map_merge node's name), ~expected (robot namespaces whose map and map_updates topics the node must
subscribe, and nothing else under ~watch), ~watch (topic prefixes to look at), ~merged_topic, ~frame,
~wrong_type_topic (this checker publishes a std_msgs/String there: a topic with the right name but the wrong type),
~timeout (s).
"""
import sys
import unittest

import rosgraph
import rospy
import rostest
from nav_msgs.msg import OccupancyGrid
from std_msgs.msg import String


def subscriptions(node: str) -> set:
    """Topics the node subscribes to, from the master."""
    _, subscribers, _ = rosgraph.Master('/mm_discovery_checker').getSystemState()
    return {topic for topic, nodes in subscribers if node in nodes}


class DiscoveryCheck(unittest.TestCase):
    def test_discovered_robots_and_latched_output(self):
        node = rospy.get_param('~node')
        watch = rospy.get_param('~watch')
        expected = set()
        for ns in rospy.get_param('~expected'):
            expected |= {ns + '/' + rospy.get_param('~robot_map_topic', 'map'), ns + '/map_updates'}
        wrong = rospy.Publisher(rospy.get_param('~wrong_type_topic'), String, queue_size=1, latch=True)
        wrong.publish(String(data='not a map'))

        deadline = rospy.get_time() + float(rospy.get_param('~timeout', 30.0))
        seen = set()
        while rospy.get_time() < deadline:
            seen = {t for t in subscriptions(node) if any(t.startswith(w) for w in watch)}
            if seen >= expected:
                break
            rospy.sleep(0.5)
        self.assertEqual(seen & expected, expected, f'not subscribed to {sorted(expected - seen)}')
        rospy.sleep(2.5)   # two more discovery passes: nothing else may be picked up
        seen = {t for t in subscriptions(node) if any(t.startswith(w) for w in watch)}
        self.assertEqual(seen, expected, f'unexpected subscriptions {sorted(seen - expected)}')

        # latched: a new subscriber gets the last merged map at once, stamped before it subscribed. A fresh map
        # published just as it connects is what the latch then hands over, so a newer stamp is tried again; a topic
        # that is not latched never passes.
        for _ in range(3):
            received, subscribed_at = subscribe_briefly(rospy.get_param('~merged_topic'))
            self.assertTrue(received, 'no merged map received')
            if min(m.header.stamp for m in received) < subscribed_at:
                break
        self.assertLess(min(m.header.stamp for m in received), subscribed_at, 'the merged map is not latched')
        self.assertEqual(received[0].header.frame_id, rospy.get_param('~frame'))


def subscribe_briefly(topic):
    """What a new subscriber receives within a second of its first message (or of 10 s), and when it subscribed."""
    received = []
    subscribed_at = rospy.Time.now()
    sub = rospy.Subscriber(topic, OccupancyGrid, received.append)
    end = rospy.get_time() + 10.0
    while rospy.get_time() < end and not received:
        rospy.sleep(0.05)
    rospy.sleep(1.0)
    sub.unregister()
    return received, subscribed_at


if __name__ == '__main__':
    rospy.init_node('mm_discovery_checker')
    rostest.rosrun('multirobot_map_merge', 'map_merge_discovery', DiscoveryCheck, sys.argv)
