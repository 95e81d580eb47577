"""fleet_sim ROS node: a light 2D multi-robot simulator standing in for Gazebo + SLAM + move_base (thin rospy adapter
over fleet_sim.sim).

Node name `fleet_sim`. Per robot `<ns>` (no leading slash; frames `<ns>/<map_frame>`, `<ns>/<base_frame>`):
  * `<ns>/map` (nav_msgs/OccupancyGrid, latched, ~map_rate while the map changes) and `<ns>/map_updates`
    (map_msgs/OccupancyGridUpdate of the changed rectangle, ~update_rate; a full map instead when the map grew):
    log-odds map of the robot's laser in its own map frame, whose origin is the robot's start pose;
  * TF `<ns>/map` -> `<ns>/base_link` (~tf_rate): the pose the maps are drawn at (with ~drift_yaw, ~drift_xy the
    SLAM's belief, not the true pose);
  * `<ns>/move_base` (move_base_msgs/MoveBaseAction): goals in frame `<ns>/map` (or empty); plans on the robot's own
    map with unknown space traversable, drives, re-plans when the path meets a discovered wall; SUCCEEDED within
    ~goal_tolerance, ABORTED when there is no path or the robot is stuck, PREEMPTED on cancel or a new goal;
    feedback with the current pose at ~update_rate. The goal orientation is ignored;
  * `<ns>/scan` (sensor_msgs/LaserScan, frame `<ns>/base_link`) with ~publish_scan;
  * ground truth (never on TF): `<ns>/ground_truth/start_pose` (latched) and `<ns>/ground_truth/pose` (~update_rate),
    geometry_msgs/PoseStamped in frame `world`.
Global: `~world_map` (nav_msgs/OccupancyGrid of the world, frame `world`, latched) and `/clock` when `/use_sim_time` is
true (sim time starts at 1 s and runs ~speedup times faster than real time; all rates above are in sim time).

Parameters (private, read once at start; any bad value stops the node with one message):
{params}

Threads: one simulation loop (the main thread) owns the simulation: it steps motion in fixed ~sim_step steps, takes
the goals that actionlib's callbacks queued in the SimpleActionServers (polled, so no callback touches the sim), and
publishes. rospy's threads only deliver messages.
"""
from __future__ import annotations

import math
import sys
import time
from typing import List

import genpy
import numpy as np
import rospy
import tf2_ros
from actionlib import SimpleActionServer
from geometry_msgs.msg import PoseStamped, TransformStamped
from map_msgs.msg import OccupancyGridUpdate
from move_base_msgs.msg import MoveBaseAction, MoveBaseFeedback
from nav_msgs.msg import OccupancyGrid
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import LaserScan

from multirobot_map_merge.paramdoc import docstring

from .messages import grid_msg, update_msg
from .params import FleetSimParams, ParamError, describe
from .robot import ACTIVE, SUCCEEDED, SimRobot
from .sim import FleetSim

CLOCK_START = 1.0          # s: sim time at start (time 0 means "no time yet" to many ROS tools)
MAX_LAG = 0.5              # s (real) behind schedule before the loop stops trying to catch up
STATUS_RATE = 1.0          # Hz (sim time) of each move_base server's periodic status
CLOCK_PERIOD = 0.01        # s (real): /clock at most at 100 Hz; each message wakes every node using sim time
WARN_PERIOD = 10.0


__doc__ = __doc__.format(params=docstring(describe()))


def _pose_msg(pose, frame: str, stamp) -> PoseStamped:
    msg = PoseStamped()
    msg.header.stamp = stamp
    msg.header.frame_id = frame
    msg.pose.position.x, msg.pose.position.y = float(pose[0]), float(pose[1])
    msg.pose.orientation.z, msg.pose.orientation.w = math.sin(pose[2] / 2.0), math.cos(pose[2] / 2.0)
    return msg


class _RobotIO:
    """Publishers and the action server of one robot."""

    def __init__(self, robot: SimRobot, params: FleetSimParams) -> None:
        ns = robot.ns
        self.robot = robot
        self.map_frame = f'{ns}/{params.map_frame}'
        self.base_frame = f'{ns}/{params.base_frame}'
        self.map_pub = rospy.Publisher(f'{ns}/map', OccupancyGrid, queue_size=2, latch=True)
        self.update_pub = rospy.Publisher(f'{ns}/map_updates', OccupancyGridUpdate, queue_size=10)
        self.scan_pub = rospy.Publisher(f'{ns}/scan', LaserScan, queue_size=5) if params.publish_scan else None
        self.start_pub = rospy.Publisher(f'{ns}/ground_truth/start_pose', PoseStamped, queue_size=1, latch=True)
        self.pose_pub = rospy.Publisher(f'{ns}/ground_truth/pose', PoseStamped, queue_size=5)
        self.server = SimpleActionServer(f'{ns}/move_base', MoveBaseAction, auto_start=False)
        # periodic status at 1 Hz sim time instead of actionlib's 5 Hz (50 messages/s per robot at 10x speed-up);
        # every status change is still published at once
        self.server.action_server.status_frequency = STATUS_RATE
        self.server.start()
        self.map_scans = -1      # mapper.n_scans at the last full map (no new full map while nothing changed)


class FleetSimNode:
    def __init__(self, params: FleetSimParams, sim: FleetSim, use_sim_time: bool) -> None:
        self.params = params
        self.sim = sim
        self.use_sim_time = use_sim_time
        self._last_warn = {}
        self._clock_sent = -math.inf
        self.clock_pub = rospy.Publisher('/clock', Clock, queue_size=10) if use_sim_time else None
        if self.clock_pub is not None:
            self._publish_clock()   # before anything else, so other nodes' time starts
        self.world_pub = rospy.Publisher('~world_map', OccupancyGrid, queue_size=1, latch=True)
        self.tf = tf2_ros.TransformBroadcaster()
        self.io: List[_RobotIO] = [_RobotIO(r, params) for r in sim.robots]

    # ------------------------------------------------------------------ helpers
    def stamp(self) -> genpy.Time:
        if self.use_sim_time:
            return rospy.Time.from_sec(CLOCK_START + self.sim.t)
        return rospy.Time.now()

    def _warn(self, key: str, text: str, *args) -> None:
        now = time.monotonic()
        if now - self._last_warn.get(key, -math.inf) >= WARN_PERIOD:
            self._last_warn[key] = now
            rospy.logwarn('fleet_sim: ' + text, *args)

    def _publish_clock(self) -> None:
        now = time.monotonic()
        if now - self._clock_sent < CLOCK_PERIOD:
            return
        self._clock_sent = now
        msg = Clock()
        msg.clock = rospy.Time.from_sec(CLOCK_START + self.sim.t)
        self.clock_pub.publish(msg)

    # ------------------------------------------------------------------ publishing
    def publish_static(self) -> None:
        stamp = self.stamp()
        w = self.sim.world
        self.world_pub.publish(grid_msg(w.data, w.resolution, w.origin, 'world', stamp))
        for io in self.io:
            io.start_pub.publish(_pose_msg(io.robot.start, 'world', stamp))
            self.publish_map(io, stamp)
            io.robot.mapper.changed_rect()       # the full map covers everything so far
        self.publish_tf(stamp)

    def publish_map(self, io: _RobotIO, stamp, if_changed: bool = False) -> None:
        mapper = io.robot.mapper
        if if_changed and mapper.n_scans == io.map_scans:
            return       # the latched map is still current
        io.map_scans = mapper.n_scans
        io.map_pub.publish(grid_msg(mapper.values(), mapper.resolution, mapper.origin, io.map_frame, stamp))

    def publish_update(self, io: _RobotIO, stamp) -> None:
        mapper = io.robot.mapper
        rect = mapper.changed_rect()
        if rect is None:
            return
        if rect.full:                              # the map grew: an update cannot say so
            self.publish_map(io, stamp)
            return
        io.update_pub.publish(update_msg(mapper.values(rect), rect.x, rect.y, io.map_frame, stamp))

    def publish_tf(self, stamp) -> None:
        out = []
        for io in self.io:
            x, y, yaw = io.robot.pose_map
            t = TransformStamped()
            t.header.stamp = stamp
            t.header.frame_id = io.map_frame
            t.child_frame_id = io.base_frame
            t.transform.translation.x, t.transform.translation.y = x, y
            t.transform.rotation.z, t.transform.rotation.w = math.sin(yaw / 2.0), math.cos(yaw / 2.0)
            out.append(t)
        self.tf.sendTransform(out)

    def publish_scan(self, io: _RobotIO, stamp) -> None:
        r = io.robot
        msg = LaserScan()
        msg.header.stamp = stamp
        msg.header.frame_id = io.base_frame
        n = r.cfg.n_beams
        msg.angle_min = float(r.angles[0])
        msg.angle_increment = 2.0 * math.pi / n
        msg.angle_max = msg.angle_min + (len(r.angles) - 1) * msg.angle_increment   # within ~fov
        msg.scan_time = 1.0 / self.params.scan_rate
        msg.range_min = 0.0
        msg.range_max = float(r.cfg.max_range)
        msg.ranges = r.ranges.astype(np.float32).tolist()
        io.scan_pub.publish(msg)

    # ------------------------------------------------------------------ goals
    def handle_goals(self) -> None:
        for i, io in enumerate(self.io):
            server = io.server
            if server.is_new_goal_available():
                goal = server.accept_new_goal()      # also PREEMPTS the goal being driven, if any
                if goal is None:
                    continue
                if server.is_preempt_requested():    # cancelled before we took it
                    io.robot.cancel()
                    server.set_preempted(text='cancelled before it started')
                    continue
                self.start_goal(i, io, goal)
            elif server.is_preempt_requested() and server.is_active():
                io.robot.cancel()
                server.set_preempted(text='cancelled')

    def start_goal(self, i: int, io: _RobotIO, goal) -> None:
        frame = goal.target_pose.header.frame_id.lstrip('/')
        p = goal.target_pose.pose.position
        if frame not in ('', io.map_frame):
            io.robot.cancel()
            self._warn(f'frame:{io.robot.ns}', 'robot [%s]: goal in frame [%s] refused: goals must be in [%s]',
                       io.robot.ns, frame, io.map_frame)
            io.server.set_aborted(text=f'goal frame {frame!r} is not {io.map_frame!r}')
            return
        outcome = self.sim.set_goal(i, float(p.x), float(p.y))
        rospy.logdebug('fleet_sim: robot [%s]: goal (%.2f, %.2f)', io.robot.ns, p.x, p.y)
        if outcome is not None:
            self.finish_goal(io, outcome)

    def finish_goal(self, io: _RobotIO, outcome) -> None:
        if not io.server.is_active():
            return
        if outcome.status == SUCCEEDED:
            io.server.set_succeeded(text=outcome.text)
        else:
            rospy.loginfo('fleet_sim: robot [%s]: goal aborted: %s', io.robot.ns, outcome.text)
            io.server.set_aborted(text=outcome.text)

    # ------------------------------------------------------------------ loop
    def step(self) -> None:
        self.handle_goals()
        due, outcomes = self.sim.step()
        for i, outcome in outcomes:
            self.finish_goal(self.io[i], outcome)
        if self.clock_pub is not None:
            self._publish_clock()
        stamp = self.stamp()
        if self.params.publish_scan and due.scan:
            for io in self.io:          # a standing robot's laser still publishes (its last scan)
                self.publish_scan(io, stamp)
        if due.tf:
            self.publish_tf(stamp)
        if due.map:
            for io in self.io:
                self.publish_map(io, stamp, if_changed=True)
        if due.update:
            for io in self.io:
                self.publish_update(io, stamp)
                io.pose_pub.publish(_pose_msg(io.robot.pose, 'world', stamp))
                if io.robot.state == ACTIVE and io.server.is_active():
                    fb = MoveBaseFeedback()
                    fb.base_position = _pose_msg(io.robot.pose_map, io.map_frame, stamp)
                    io.server.publish_feedback(fb)

    def run(self) -> None:
        dt = self.params.sim_step / self.params.speedup     # real seconds per step
        self.publish_static()
        base, k0 = time.monotonic(), self.sim.steps
        while not rospy.is_shutdown():
            try:
                self.step()
            except Exception as e:      # a bug in one step must not end the simulation
                self._warn('step', 'step failed: %s: %s', type(e).__name__, e)
            target = base + (self.sim.steps - k0) * dt
            lag = time.monotonic() - target
            if lag < 0.0:
                time.sleep(-lag)
            elif lag > MAX_LAG:
                self._warn('lag', 'cannot keep up with ~speedup %.1f (%.2f s behind): running slower',
                           self.params.speedup, lag)
                base, k0 = time.monotonic(), self.sim.steps


def main() -> None:
    rospy.init_node('fleet_sim')
    try:
        params = FleetSimParams.from_mapping(rospy.get_param('~', {}))
        sim = FleetSim(params)
    except ParamError as e:
        rospy.logfatal('fleet_sim: bad parameter: %s', e)
        sys.exit(1)
    use_sim_time = bool(rospy.get_param('/use_sim_time', False))
    if params.speedup != 1.0 and not use_sim_time:
        rospy.logwarn('fleet_sim: ~speedup %.2f without /use_sim_time: the simulation runs faster than the stamps',
                      params.speedup)
    rospy.loginfo('fleet_sim: world %d x %d cells at %.3f m, robots %s, speedup %.1f', sim.world.width,
                  sim.world.height, sim.world.resolution,
                  ', '.join(f'{s.ns} at ({s.x:.2f}, {s.y:.2f}, {s.yaw:.2f})' for s in sim.specs), params.speedup)
    node = FleetSimNode(params, sim, use_sim_time)
    node.run()
