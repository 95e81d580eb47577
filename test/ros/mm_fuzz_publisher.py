#!/usr/bin/env python3
"""Test helper: several bad robots publishing a seeded random stream of malformed maps and map updates.

Params: ~robots (list of namespaces, default [/bad1, /bad2, /bad3, /bad4]); ~rate (messages per second in all,
default 60); ~seed (0: a random seed); ~count_param (where the number of messages sent so far is kept, default
/mm_fuzz/sent); the seed used is set as /mm_fuzz/seed and logged, so that a failing run replays.

Each message is, at random: a plausible small map (cells of any int8 value, tilted or zero quaternion, random
stamp), a map with an absurd origin, resolution, size or data length, or an update with any rectangle (negative,
empty, huge, overflowing, outside) and any data length. Plausible maps stay within a few metres of their robot's
pose, so the merged grid stays small: the test is about robustness, not about a legitimately huge merge.
"""
import os

import numpy as np
import rospy
from map_msgs.msg import OccupancyGridUpdate
from nav_msgs.msg import OccupancyGrid

ABSURD = [0.0, -0.05, 1e-30, 1e30, 1e300, -1e300, float('inf'), float('-inf'), float('nan'), 1e6, -3e9, 2.0 ** 31]
UINT32 = [0, 1, 2 ** 31 - 1, 2 ** 31 + 175, 2 ** 32 - 1, 65536, 100000]
INT32 = [-1, -2 ** 31, 2 ** 31 - 1, 100000, -100000]


def cells(rng, n):
    kind = rng.integers(3)
    if kind == 0:
        return rng.integers(-128, 128, n).astype(np.int8).tolist()
    if kind == 1:
        return rng.choice(np.array([-1, 0, 100, 101, 127, -128, -2], np.int8), n).tolist()
    return rng.choice(np.array([-1, 0, 100], np.int8), n).tolist()


def plausible_map(rng):
    m = OccupancyGrid()
    m.info.width, m.info.height = (int(v) for v in rng.integers(1, 100, 2))
    m.info.resolution = float(rng.uniform(0.05, 0.1))
    m.info.origin.position.x, m.info.origin.position.y = (float(v) for v in rng.uniform(-4.0, 4.0, 2))
    q = m.info.origin.orientation
    yaw = rng.uniform(-3.2, 3.2)
    q.z, q.w = float(np.sin(yaw / 2)), float(np.cos(yaw / 2))
    if rng.random() < 0.2:
        q.x, q.y = (float(v) for v in rng.normal(0.0, 0.3, 2))   # roll / pitch: ignored with a warning
    elif rng.random() < 0.2:
        q.z = q.w = 0.0                                           # all-zero: identity
    m.data = cells(rng, m.info.width * m.info.height)
    return m


def bad_map(rng):
    m = plausible_map(rng)
    case = rng.integers(6)
    if case == 0:
        m.info.origin.position.x = float(rng.choice(ABSURD))
    elif case == 1:
        m.info.resolution = float(rng.choice(ABSURD))
    elif case == 2:
        m.info.width = int(rng.choice(UINT32))      # data length no longer matches (or a huge claimed size)
    elif case == 3:
        m.data = m.data[:int(rng.integers(0, len(m.data) + 1))] + cells(rng, int(rng.integers(0, 3)))
    elif case == 4:
        q = m.info.origin.orientation
        q.x, q.y, q.z, q.w = (float(v) for v in rng.choice(ABSURD, 4))
    else:
        m.info.width, m.info.height = (0, m.info.height) if rng.random() < 0.5 else (m.info.width, 0)
        m.data = []
    return m


def bad_update(rng):
    u = OccupancyGridUpdate()
    u.x, u.y = (int(rng.integers(-5, 120)) if rng.random() < 0.7 else int(rng.choice(INT32)) for _ in range(2))
    u.width, u.height = (int(rng.integers(0, 40)) if rng.random() < 0.7 else int(rng.choice(UINT32))
                         for _ in range(2))
    n = u.width * u.height
    if n > 4000 or rng.random() < 0.2:
        n = int(rng.integers(0, 50))                 # wrong length (the only one possible for a huge rectangle)
    u.data = cells(rng, n)
    return u


def main():
    rospy.init_node('mm_fuzz_publisher')
    seed = int(rospy.get_param('~seed', 0)) or int.from_bytes(os.urandom(4), 'little') % (1 << 31)   # XML-RPC int
    rospy.set_param('/mm_fuzz/seed', seed)
    rospy.loginfo('mm_fuzz_publisher: seed %d (replay with _seed:=%d)', seed, seed)
    print(f'mm_fuzz_publisher: seed {seed}', flush=True)
    rng = np.random.default_rng(seed)
    robots = rospy.get_param('~robots', ['/bad1', '/bad2', '/bad3', '/bad4'])
    count_param = rospy.get_param('~count_param', '/mm_fuzz/sent')
    pubs = [(rospy.Publisher(ns + '/map', OccupancyGrid, queue_size=20, latch=True),
             rospy.Publisher(ns + '/map_updates', OccupancyGridUpdate, queue_size=20)) for ns in robots]
    period = 1.0 / float(rospy.get_param('~rate', 60.0))
    sent = 0
    while not rospy.is_shutdown():
        map_pub, update_pub = pubs[int(rng.integers(len(pubs)))]
        kind = rng.random()
        msg = plausible_map(rng) if kind < 0.3 else bad_map(rng) if kind < 0.55 else bad_update(rng)
        msg.header.stamp = rospy.Time.now() if rng.random() < 0.9 else rospy.Time(int(rng.integers(0, 2 ** 31)))
        msg.header.frame_id = str(rng.choice(['', 'bad/map', '/world', 'x' * 50]))
        try:
            (map_pub if isinstance(msg, OccupancyGrid) else update_pub).publish(msg)
        except (rospy.ROSSerializationException, rospy.ROSException, ValueError, OverflowError) as e:
            rospy.logdebug('mm_fuzz_publisher: cannot even serialise this one: %s', e)   # e.g. nan in a uint32
            continue
        sent += 1
        if sent % 50 == 0:
            rospy.set_param(count_param, sent)
        try:
            rospy.sleep(period)
        except rospy.ROSInterruptException:
            break


if __name__ == '__main__':
    main()
