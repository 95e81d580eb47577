#!/usr/bin/env python3
"""Print how far each merged map is from its true place: placement_report.py TRUTH.json TRANSFORMS.json.

Errors are relative to the first included map, as ../shared/eval scores them: rotation in degrees and the largest
displacement of the map's known-area corners in cells.
"""
import json
import math
import os
import sys

import numpy as np

from multirobot_map_merge import transforms as tf


def main(truth_path: str, result_path: str) -> int:
    truth = json.load(open(truth_path))
    result = {os.path.basename(m['file']): m for m in json.load(open(result_path))['maps']}
    placed = [(m, result.get(m['file'])) for m in truth['maps']]
    placed = [(m, r) for m, r in placed if r and r.get('included')]
    if not placed:
        print('placement: no map placed')
        return 1
    def est(r):
        t = r['transform']
        return tf.rigid(t['x'], t['y'], t['yaw'], t.get('scale', 1.0))
    ref_m, ref_r = placed[0]
    for m, r in placed:
        rel_est = tf.inverse(est(ref_r)) @ est(r)
        rel_true = tf.inverse(tf.rigid(*ref_m['pose'])) @ tf.rigid(*m['pose'])
        corners = np.array(m.get('known_bbox') or [[0, 0]], float)
        rot, disp = tf.difference(rel_est, rel_true, corners)
        print(f"placement: {m['file']}: rotation error {math.degrees(rot):.2f} deg, "
              f"corner error {disp / m['resolution']:.1f} cells")
    left_out = [m['file'] for m in truth['maps'] if not (result.get(m['file']) or {}).get('included')]
    print(f"placement: {len(placed)} of {len(truth['maps'])} maps merged" +
          (f"; left out: {', '.join(left_out)}" if left_out else ''))
    return 0


if __name__ == '__main__':
    if len(sys.argv) != 3:
        print(__doc__.splitlines()[0], file=sys.stderr)
        sys.exit(2)
    sys.exit(main(sys.argv[1], sys.argv[2]))
