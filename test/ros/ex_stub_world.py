#!/usr/bin/env python3
"""Test-only stand-in for a robot with SLAM and move_base, for the explore rostests that need control over goals.

A hard-coded 6 m x 4 m walled room (0.05 m cells) with a short wall at x 2.5-2.6 m, y 1-2 m; the robot starts at
~start [x, y] and has seen a disc of ~seen_radius m around it and the rectangle ~seen_rect [x0, y0, x1, y1].
Publishes `map` (latched full map, frame `map`), `map_updates` (the rectangle revealed after each goal), tf `map` ->
`base_link` at 20 Hz, and serves `move_base` (MoveBaseAction):
  * a goal inside ~abort_region [x0, y0, x1, y1] (or outside the room / in a wall) is ABORTED at once;
  * any other goal succeeds after ~drive_time s: the robot is moved there and a disc of ~reveal_radius m around
    it becomes known (0 disables revealing);
  * a new goal or a cancel preempts the running one.
"""
import threading

import actionlib
import numpy as np
import rospy
import tf2_ros
from geometry_msgs.msg import TransformStamped
from map_msgs.msg import OccupancyGridUpdate
from move_base_msgs.msg import MoveBaseAction, MoveBaseResult
from nav_msgs.msg import OccupancyGrid

RES = 0.05
W, H = 120, 80   # cells


def true_world() -> np.ndarray:
    world = np.zeros((H, W), np.int8)
    world[:2, :] = world[-2:, :] = 100
    world[:, :2] = world[:, -2:] = 100
    world[20:40, 50:52] = 100   # a short wall at x 2.5-2.6 m, y 1-2 m
    return world


class StubWorld:
    def __init__(self) -> None:
        self.world = true_world()
        self.known = np.zeros((H, W), bool)
        self.lock = threading.Lock()
        self.pose = [float(v) for v in rospy.get_param('~start', [1.0, 2.0])]
        self.abort = [float(v) for v in rospy.get_param('~abort_region', [])]
        self.drive_time = float(rospy.get_param('~drive_time', 0.5))
        self.reveal_radius = float(rospy.get_param('~reveal_radius', 0.0))
        self.reveal(float(rospy.get_param('~seen_radius', 1.0)), publish=False)
        rect = [float(v) for v in rospy.get_param('~seen_rect', [])]
        if len(rect) == 4:
            self.known[int(rect[1] / RES):int(rect[3] / RES), int(rect[0] / RES):int(rect[2] / RES)] = True
        self.map_pub = rospy.Publisher('map', OccupancyGrid, queue_size=1, latch=True)
        self.upd_pub = rospy.Publisher('map_updates', OccupancyGridUpdate, queue_size=10)
        self.tf = tf2_ros.TransformBroadcaster()
        self.map_pub.publish(self.full_map())
        self.server = actionlib.SimpleActionServer('move_base', MoveBaseAction, self.execute, auto_start=False)
        self.server.start()
        rospy.Timer(rospy.Duration(0.05), self.publish_tf)

    def data(self) -> np.ndarray:
        return np.where(self.known, self.world, np.int8(-1)).astype(np.int8)

    def full_map(self) -> OccupancyGrid:
        msg = OccupancyGrid()
        msg.header.frame_id = 'map'
        msg.header.stamp = rospy.Time.now()
        msg.info.resolution, msg.info.width, msg.info.height = RES, W, H
        msg.info.origin.orientation.w = 1.0
        with self.lock:
            msg.data = self.data().ravel().tolist()
        return msg

    def reveal(self, radius: float, publish: bool = True) -> None:
        if radius <= 0.0:
            return
        with self.lock:
            cx, cy = self.pose
            ys, xs = np.mgrid[0:H, 0:W]
            disc = np.hypot((xs + 0.5) * RES - cx, (ys + 0.5) * RES - cy) <= radius
            self.known |= disc
            rows, cols = np.flatnonzero(disc.any(axis=1)), np.flatnonzero(disc.any(axis=0))
            r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
            patch = self.data()[r0:r1, c0:c1]
        if publish:
            upd = OccupancyGridUpdate()
            upd.header.frame_id = 'map'
            upd.header.stamp = rospy.Time.now()
            upd.x, upd.y, upd.width, upd.height = int(c0), int(r0), int(c1 - c0), int(r1 - r0)
            upd.data = patch.ravel().tolist()
            self.upd_pub.publish(upd)

    def publish_tf(self, _event) -> None:
        t = TransformStamped()
        t.header.stamp = rospy.Time.now()
        t.header.frame_id, t.child_frame_id = 'map', 'base_link'
        with self.lock:
            t.transform.translation.x, t.transform.translation.y = self.pose
        t.transform.rotation.w = 1.0
        try:
            self.tf.sendTransform(t)
        except rospy.ROSException:   # shutting down
            pass

    def reachable(self, x: float, y: float) -> bool:
        if len(self.abort) == 4 and self.abort[0] <= x <= self.abort[2] and self.abort[1] <= y <= self.abort[3]:
            return False
        c, r = int(x / RES), int(y / RES)
        return 0 <= c < W and 0 <= r < H and self.world[r, c] == 0

    def execute(self, goal) -> None:
        p = goal.target_pose.pose.position
        if not self.reachable(p.x, p.y):
            self.server.set_aborted(MoveBaseResult(), 'unreachable')
            return
        end = rospy.get_time() + self.drive_time
        while rospy.get_time() < end:
            if self.server.is_preempt_requested() or rospy.is_shutdown():
                self.server.set_preempted()
                return
            rospy.sleep(0.02)
        with self.lock:
            self.pose = [p.x, p.y]
        self.reveal(self.reveal_radius)
        self.server.set_succeeded(MoveBaseResult())


if __name__ == '__main__':
    rospy.init_node('ex_stub_world')
    StubWorld()
    rospy.spin()
