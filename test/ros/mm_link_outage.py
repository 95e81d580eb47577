#!/usr/bin/env python3
"""Helper of test/test_remote_robot.py (robots on another host): run inside the test's network namespaces.

    mm_link_outage.py robot --t0 T0                   # in the robot's namespace: publishes /remote/map (+ updates)
    mm_link_outage.py check --t0 T0 --link DEV --outage 15 --within 10   # in the core's namespace (root)

The robot's map (120 x 60 cells, 5 cm, origin 0) carries two clocks, as 16 bits of deciseconds since T0 written as
occupied (1) or free (0) cells: row 10 in every full map (published at 1 Hz) and row 20 only in map updates (2 Hz;
full maps have it free). So the merged map shows when the newest full map and the newest update it holds were
published. The checker waits for the robot in the merged map, takes DEV (its end of the veth link) down for
--outage s and up again, and then needs both clocks to show a time after the link came back, within --within s,
while the node keeps publishing throughout. It prints one JSON line of figures and exits 0 (pass) or 1.
"""
import argparse
import json
import subprocess
import sys
import threading
import time

import numpy as np

BITS, X0, FULL_ROW, UPDATE_ROW = 16, 10, 10, 20
W, H, RES = 120, 60, 0.05


def encode(t0: float) -> list:
    ds = int((time.time() - t0) * 10.0) % (1 << BITS)
    return [100 if ds >> (BITS - 1 - i) & 1 else 0 for i in range(BITS)]


def decode(cells: np.ndarray) -> int:
    return int(sum(1 << (BITS - 1 - i) for i, v in enumerate(cells) if v >= 50))


def base_map() -> np.ndarray:
    data = np.zeros((H, W), np.int8)
    data[0, :] = data[-1, :] = 100
    data[:, 0] = data[:, -1] = 100
    return data


def run_robot(args) -> None:
    import rospy
    from map_msgs.msg import OccupancyGridUpdate
    from nav_msgs.msg import OccupancyGrid
    from multirobot_map_merge.grid import Grid
    from multirobot_map_merge.ros.conversions import grid_to_msg
    rospy.init_node('remote_robot')
    for key, value in (('x', 0.0), ('y', 0.0), ('z', 0.0), ('yaw', 0.0)):
        rospy.set_param(f'/remote/map_merge/init_pose_{key}', value)
    map_pub = rospy.Publisher('/remote/map', OccupancyGrid, queue_size=2, latch=True)
    upd_pub = rospy.Publisher('/remote/map_updates', OccupancyGridUpdate, queue_size=4)
    tick = 0
    while not rospy.is_shutdown():
        if tick % 2 == 0:
            data = base_map()
            data[FULL_ROW, X0:X0 + BITS] = encode(args.t0)
            map_pub.publish(grid_to_msg(Grid(data, RES, frame_id='remote/map'), stamp=rospy.Time.now()))
        else:
            u = OccupancyGridUpdate()
            u.header.stamp, u.header.frame_id = rospy.Time.now(), 'remote/map'
            u.x, u.y, u.width, u.height = X0, UPDATE_ROW, BITS, 1
            u.data = encode(args.t0)
            upd_pub.publish(u)
        tick += 1
        time.sleep(0.5)


def clocks(msg) -> tuple:
    """(full map clock, update clock) in deciseconds since T0, or None if the robot is not in the merged map."""
    data = np.asarray(msg.data, np.int8).reshape(msg.info.height, msg.info.width)
    ox, oy, res = msg.info.origin.position.x, msg.info.origin.position.y, msg.info.resolution
    out = []
    for row in (FULL_ROW, UPDATE_ROW):
        cols = np.floor(((X0 + np.arange(BITS) + 0.5) * RES - ox) / res).astype(int)
        r = int(np.floor(((row + 0.5) * RES - oy) / res))
        if not (0 <= r < data.shape[0] and cols.min() >= 0 and cols.max() < data.shape[1]):
            return None
        out.append(decode(data[r, cols]))
    return tuple(out)


def run_check(args) -> int:
    import rospy
    from nav_msgs.msg import OccupancyGrid
    rospy.init_node('link_outage_checker', disable_signals=True)
    lock = threading.Lock()
    seen = []   # (arrival time, clocks or None)

    def on_merged(msg):
        with lock:
            seen.append((time.time(), clocks(msg)))
    rospy.Subscriber('/map_merge/map', OccupancyGrid, on_merged, queue_size=50, buff_size=1 << 24)
    figures = {}

    def wait_until(predicate, timeout):
        deadline = time.time() + timeout
        while time.time() < deadline:
            with lock:
                hit = next((s for s in seen if predicate(s)), None)
            if hit is not None:
                return hit
            time.sleep(0.1)
        return None

    def fail(why):
        figures['failure'] = why
        print(json.dumps(figures), flush=True)
        return 1

    t_start = time.time()
    first = wait_until(lambda s: s[1] is not None and s[1][1] > 0, 90.0)
    if first is None:
        return fail('the remote robot (map and updates) never reached the merged map over the link')
    figures['first_merge_s'] = round(first[0] - t_start, 1)

    subprocess.run(['ip', 'link', 'set', 'dev', args.link, 'down'], check=True)
    t_down = time.time()
    time.sleep(args.outage)
    with lock:
        during = [t for t, _ in seen if t_down <= t]
    subprocess.run(['ip', 'link', 'set', 'dev', args.link, 'up'], check=True)
    t_up = time.time()
    figures['merged_maps_during_outage'] = len(during)
    if len(during) < args.outage:   # the node keeps publishing (re-sending) at merging_rate while the robot is away
        return fail(f'only {len(during)} merged maps during the {args.outage:.0f} s outage: the node stalled')

    after = (t_up - args.t0) * 10.0
    full = wait_until(lambda s: s[0] >= t_up and s[1] is not None and s[1][0] >= after, args.within)
    update = wait_until(lambda s: s[0] >= t_up and s[1] is not None and s[1][1] >= after,
                        max(args.within - (time.time() - t_up), 0.1))
    figures['full_map_after_link_up_s'] = round(full[0] - t_up, 1) if full else None
    figures['update_after_link_up_s'] = round(update[0] - t_up, 1) if update else None
    if full is None or update is None:
        return fail(f'maps or updates published after the outage did not reach the merged map within '
                    f'{args.within:.0f} s')
    print(json.dumps(figures), flush=True)
    return 0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument('role', choices=('robot', 'check'))
    ap.add_argument('--t0', type=float, required=True)
    ap.add_argument('--link', default='')
    ap.add_argument('--outage', type=float, default=15.0)
    ap.add_argument('--within', type=float, default=10.0)
    args, _ = ap.parse_known_args()
    if args.role == 'robot':
        run_robot(args)
    else:
        code = run_check(args)
        sys.stdout.flush()
        import os
        os._exit(code)   # rospy's threads would keep a plain exit waiting


if __name__ == '__main__':
    main()
