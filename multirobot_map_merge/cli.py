"""merge_maps: merge map_server maps, or the robot maps of a rosbag, offline (no roscore needed).

    merge_maps [--confidence C] [--feature NAME] [--free-threshold N] [--occupied-threshold N]
               [--known-poses POSES.yaml [--legacy-cell-poses]]
               [--output PREFIX] [--png FILE] [--transforms-json FILE] MAP.yaml...
    merge_maps [options] --bag FILE.bag [--at SECONDS] [--topic-suffix map]

Writes PREFIX.pgm + PREFIX.yaml as map_saver does, a PNG preview (PREFIX.png unless --png) and beside it an
overlay (PREFIX_overlay.png: each map in its own colour, with a legend), and with --transforms-json the placement
of every map (the format of ../shared/eval/README.md). With --bag, every nav_msgs/OccupancyGrid topic <ns>/map of
the bag (with <ns>/map_updates applied) is one robot, merged as it was at the end of the bag or at --at seconds.
Maps may be trinary (map_saver's files) or hold probabilities (map_server's scale or raw mode, e.g. a Cartographer
map): matching reads them through --free-threshold and --occupied-threshold, the merged map keeps their values.
On a terminal, an estimation that takes over a second shows its progress.
Exit codes: 0 merged (maybe with warnings), 1 nothing to merge (no map placed with a known cell), 2 bad input (a
map, poses file or bag that cannot be read or is invalid, bad options), with a one-line reason. A map that can be
read but not used whole gets a one-line warning: cells outside -1 and 0..100 are read as unknown; a map that cannot
be matched (too small or too large at the working resolution) or whose placement would make the merged map
unusable (not finite, over 2^28 cells) is left out (`"included": false` in --transforms-json).

POSES.yaml gives the pose of each map's frame in the world (metres, radians), by file name or in order:
    poses: {map_00.yaml: [0.0, 0.0, 0.0], map_01.yaml: {x: 4.2, y: -1.0, yaw: 1.57}}
    poses: [[0.0, 0.0, 0.0], [4.2, -1.0, 1.57]]
"""
from __future__ import annotations

import argparse
import json
import logging
import math
import os
import signal
import sys
import threading
import time
from typing import List, Optional, Sequence, Tuple

import yaml

from . import transforms as tf
from .admission import describe_invalid
from .estimation.features import FEATURE_TYPES
from .estimation.settings import EstimationSettings
from .grid import Grid
from .known_poses import InitPose
from .mapio import MapFileError, load_map, save_map, save_png
from .overlay import overlay_path, save_overlay, used_pairs
from .pipeline import MergingPipeline
from .progress import TerminalProgress, attach

log = logging.getLogger('rosout.multirobot_map_merge.cli')
MAX_DEFAULT_THREADS = 4   # worker processes started by default at most: each holds 170-180 MiB at its peak (the
                          # generated hospital36), and a batch holds 7-8 matches on average (mall36: 553 in 74)


class UsageError(Exception):
    """Bad input: reported as one line, exit code 2."""


def default_threads() -> int:
    """The cores this process may use (its CPU affinity: a container's or taskset's share), at most
    MAX_DEFAULT_THREADS: the matches' result does not depend on how many run at once."""
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):   # not Linux
        cores = os.cpu_count() or 1
    return max(1, min(cores, MAX_DEFAULT_THREADS))


def parse_args(argv: Optional[Sequence[str]]) -> argparse.Namespace:
    defaults = EstimationSettings()
    ap = argparse.ArgumentParser(prog='merge_maps', description=__doc__.split('\n\n')[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('maps', nargs='*', metavar='MAP.yaml')
    ap.add_argument('--bag', metavar='FILE.bag', help='merge the robot maps recorded in a rosbag, not map files')
    ap.add_argument('--at', type=float, metavar='SECONDS',
                    help="with --bag: the maps as they were this many seconds after the bag's start (default: its end)")
    ap.add_argument('--topic-suffix', metavar='NAME',
                    help='with --bag: last name component of the robot map topics (default map; updates on '
                         'NAME_updates)')
    ap.add_argument('--confidence', type=float, default=defaults.confidence,
                    help='confidence inliers / (8 + 0.3 matches) a pair needs, counted on verified wall '
                         'correspondences (default %(default)s as the C++ node; up to about 3.3 asks for more '
                         'agreement)')
    ap.add_argument('--feature', default=defaults.feature, choices=FEATURE_TYPES,
                    help='keypoint detector (default %(default)s)')
    ap.add_argument('--free-threshold', type=int, default=defaults.free_threshold, metavar='N',
                    help='highest occupancy (0..100) read as free when matching (default %(default)s, as map_saver)')
    ap.add_argument('--occupied-threshold', type=int, default=defaults.occupied_threshold, metavar='N',
                    help='lowest occupancy (0..100) read as a wall when matching (default %(default)s); the values '
                         'between count as unknown (probabilistic maps, e.g. Cartographer\'s). The merged map keeps '
                         'the values as published')
    ap.add_argument('--known-poses', metavar='POSES.yaml', help='merge at known initial poses instead of estimating')
    ap.add_argument('--legacy-cell-poses', action='store_true',
                    help='with --known-poses: the C++ 2.x semantics (x/y in cells, inverted, corner pivot)')
    ap.add_argument('--output', default='merged', metavar='PREFIX', help='merged map PREFIX.pgm/.yaml')
    ap.add_argument('--png', metavar='FILE', help='PNG preview (default PREFIX.png)')
    ap.add_argument('--transforms-json', metavar='FILE', help='write each map\'s placement as JSON')
    ap.add_argument('--threads', type=int, default=default_threads(),
                    help=f'pairs matched in parallel, on as many worker processes (default: the cores this process '
                         f'may use, at most {MAX_DEFAULT_THREADS}; %(default)s here)')
    ap.add_argument('--no-processes', dest='processes', action='store_false',
                    help='match the pairs on threads of this process instead of worker processes')
    ap.add_argument('--seed', type=int, default=defaults.seed,
                    help='seed of the random sampling (RANSAC, point subsets; default %(default)s): the same maps and '
                         'seed give the same merge, in any order')
    ap.add_argument('-v', '--verbose', action='store_true', help='log per-pair statistics')
    return ap.parse_args(argv)


def read_poses(path: str, maps: Sequence[str]) -> List[InitPose]:
    try:
        with open(path) as f:
            doc = yaml.safe_load(f)
    except (OSError, yaml.YAMLError) as e:
        raise UsageError(f'cannot read poses file {path}: {e}'.splitlines()[0])
    poses = doc.get('poses') if isinstance(doc, dict) else None
    if isinstance(poses, list):
        if len(poses) != len(maps):
            raise UsageError(f'{path}: {len(poses)} poses for {len(maps)} maps')
        entries = poses
    elif isinstance(poses, dict):
        entries = []
        for m in maps:
            entry = poses.get(m, poses.get(os.path.basename(m)))
            if entry is None:
                raise UsageError(f'{path}: no pose for {os.path.basename(m)}')
            entries.append(entry)
    else:
        raise UsageError(f"{path}: expected 'poses:' with a list or a mapping of file name to pose")
    out = []
    for m, e in zip(maps, entries):
        try:
            if isinstance(e, dict):
                out.append(InitPose(float(e.get('x', 0.0)), float(e.get('y', 0.0)), float(e.get('yaw', 0.0))))
            else:
                x, y, yaw = (float(v) for v in e)
                out.append(InitPose(x, y, yaw))
        except (TypeError, ValueError):
            raise UsageError(f'{path}: pose of {os.path.basename(m)} is not [x, y, yaw] numbers: {e!r}')
        if not all(math.isfinite(v) for v in (out[-1].x, out[-1].y, out[-1].yaw)):
            raise UsageError(f'{path}: pose of {os.path.basename(m)} is not finite: {e!r}')
    return out


def load_inputs(args: argparse.Namespace) -> Tuple[List[str], List[Optional[Grid]]]:
    """(names, grids) of the map files, or of the robots in --bag (a robot without a map yet has None)."""
    if args.bag is None:
        if args.at is not None or args.topic_suffix is not None:
            raise UsageError('--at and --topic-suffix need --bag')
        if not args.maps:
            raise UsageError('no maps given: MAP.yaml... or --bag FILE.bag')
        try:
            return list(args.maps), [load_map(p) for p in args.maps]
        except MapFileError as e:
            raise UsageError(str(e))
    if args.maps:
        raise UsageError('give MAP.yaml files or --bag, not both')
    from .ros.bag_input import BagError, read_bag_maps   # lazily: needs rosbag
    try:
        robots = read_bag_maps(args.bag, args.at, args.topic_suffix or 'map')
    except BagError as e:
        raise UsageError(str(e))
    if all(r.grid is None for r in robots):
        when = f'in the first {args.at:g} s of' if args.at is not None else 'in'
        raise UsageError(f'{args.bag}: no full map {when} the bag on ' + ', '.join(r.map_topic for r in robots))
    print('merge_maps: bag robots: ' + ', '.join(
        f'{r.name} ({r.maps} maps, {r.updates} updates{"" if r.grid is not None else ", no map"})' for r in robots),
        file=sys.stderr, flush=True)
    return [r.name for r in robots], [r.grid for r in robots]


def transforms_document(names: Sequence[str], pipeline: MergingPipeline, estimate_ms: float, compose_ms: float,
                        key: str = 'file'):
    """key: 'file' (map files) or 'robot' (bag robot namespaces)."""
    entries = []
    for k, (name, t) in enumerate(zip(names, pipeline.transforms)):
        if t is None or k in pipeline.left_out:
            entries.append({key: name, 'included': False})
        else:
            x, y, yaw, scale = tf.params(t)
            entries.append({key: name, 'included': True,
                            'transform': {'x': x, 'y': y, 'yaw': yaw, 'scale': scale}})
    return {'maps': entries, 'reference': pipeline.reference, 'estimate_ms': estimate_ms, 'compose_ms': compose_ms}


def warn_unused(maps: Sequence[str], pipeline: MergingPipeline) -> None:
    """One line per map that was not used whole (admission.py, compose.select_parts)."""
    for k, count in sorted(pipeline.invalid_cells.items()):
        print(f'merge_maps: warning: {maps[k]}: {describe_invalid(count)}', file=sys.stderr)
    for k, reason in sorted(pipeline.refused.items()):
        print(f'merge_maps: warning: {maps[k]}: left out: {reason}', file=sys.stderr)
    for k, reason in sorted(pipeline.left_out.items()):
        print(f'merge_maps: warning: {maps[k]}: left out: {reason}', file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    settings = EstimationSettings(feature=args.feature, confidence=args.confidence, threads=max(args.threads, 1),
                                  processes=args.processes, seed=args.seed, free_threshold=args.free_threshold,
                                  occupied_threshold=args.occupied_threshold)
    try:
        settings.validate()
    except ValueError as e:
        raise UsageError(str(e))
    if args.legacy_cell_poses and not args.known_poses:
        raise UsageError('--legacy-cell-poses needs --known-poses')
    names, grids = load_inputs(args)
    poses = read_poses(args.known_poses, names) if args.known_poses else None
    print(f'merge_maps: {sum(g is not None for g in grids)} maps loaded', file=sys.stderr, flush=True)

    pipeline = MergingPipeline(settings)
    pipeline.feed(grids, matching=poses is None)
    t0 = time.perf_counter()
    if poses is not None:
        pipeline.set_known_poses(poses, legacy=args.legacy_cell_poses)
    else:
        print(f'merge_maps: estimating transforms of {len(grids)} maps...',
              file=sys.stderr, flush=True)
        with TerminalProgress('merge_maps: estimating', unit='maps placed or set aside') as progress:
            attach(settings, progress)   # the estimation reports through progress_of(settings)
            pipeline.estimate()
        attach(settings, None)
    estimate_ms = (time.perf_counter() - t0) * 1000.0
    merged = pipeline.compose('map')
    compose_ms = pipeline.compose_seconds * 1000.0
    warn_unused(names, pipeline)
    placed = sum(t is not None and k not in pipeline.left_out for k, t in enumerate(pipeline.transforms))
    print(f'merge_maps: {placed} of {len(grids)} maps placed (estimate {estimate_ms:.0f} ms, '
          f'compose {compose_ms:.0f} ms)', file=sys.stderr, flush=True)

    for path in (args.output, args.png, args.transforms_json):
        if path:
            os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    if args.transforms_json:
        with open(args.transforms_json, 'w') as f:
            json.dump(transforms_document(names, pipeline, estimate_ms, compose_ms,
                                          'robot' if args.bag else 'file'), f, indent=1)
    if merged is None:
        print('merge_maps: nothing to merge: no map has a known cell', file=sys.stderr)
        return 1
    yaml_path, _ = save_map(merged, args.output)
    png = save_png(merged, args.png or args.output + '.png')
    labels = [n if args.bag else os.path.basename(n) for n in names]
    pairs = used_pairs(pipeline.last_estimate.pairs, pipeline.transforms) if poses is None else []
    shown = [None if k in pipeline.left_out else t for k, t in enumerate(pipeline.transforms)]
    overlay = save_overlay(overlay_path(png), grids, shown, labels, pairs)
    print(f'merge_maps: wrote {yaml_path}, {png} and {overlay}', file=sys.stderr)
    return 0


class Terminated(BaseException):
    """SIGTERM, raised in the main thread as SIGINT raises KeyboardInterrupt: the estimation ends through its `with`
    blocks, which remove its files (a merge_maps killed with the default handler left its folder in /dev/shm)."""


def _terminate(signum, frame) -> None:
    raise Terminated()


def main(argv: Optional[Sequence[str]] = None) -> int:
    args = parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING, format='%(levelname)s %(message)s')
    main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _terminate) if main_thread else None
    try:
        return run(args)
    except Terminated:
        print('merge_maps: terminated', file=sys.stderr)
        return 143   # as a shell reports SIGTERM
    except UsageError as e:
        print(f'merge_maps: error: {e}', file=sys.stderr)
        return 2
    except OSError as e:
        print(f'merge_maps: error: {e}'.splitlines()[0], file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print('merge_maps: interrupted', file=sys.stderr)
        return 130   # as a shell reports SIGINT
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


if __name__ == '__main__':
    sys.exit(main())
