#!/usr/bin/env python3
"""Soak benchmark of the map_merge node: many robots, maps growing, robots appearing late, a long run.

    scripts/env.sh python bench/bench_soak.py [--duration 1800] [--robots 24] [--late 8] [--json FILE]
        [any other bench_node.py option, e.g. --param known_init_poses:=true]

It runs bench_node.py (own roscore on a free port, a publisher process, the node, measured from outside) with
--content grow (each robot's map grows in size and origin as it explores, for half the run), full maps at 1 Hz
and updates at 2 Hz per robot, the last --late robots appearing one by one over the first third of the run, and
prints bench_node's table plus the soak figures per quarter of the run: merged rate (average and lowest 10 s
window), node CPU (cores) and RSS, and the RSS growth over the second half (MiB and %), when no map changes any
more: memory that keeps growing then is a leak.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import List, Optional

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_node  # noqa: E402  (same folder)

SOAK_DEFAULTS = ['--duration', '1800', '--robots', '24', '--late', '8', '--content', 'grow',
                 '--map-rate', '1', '--update-rate', '2']


def quarters(result: dict) -> List[dict]:
    samples, duration = result['samples'], result['duration_s']
    out = []
    for q in range(4):
        lo, hi = q * duration / 4.0, (q + 1) * duration / 4.0
        part = [s for s in samples if lo < s['t'] <= hi + 1.0]
        if not part:
            continue
        out.append(dict(quarter=q + 1, merged_hz=sum(s['merged_hz'] for s in part) / len(part),
                        merged_hz_min=min(s['merged_hz'] for s in part),
                        cores=sum(s['cores'] for s in part) / len(part), rss_mib=part[-1]['rss_mib'],
                        included=part[-1]['included']))
    return out


def soak_report(result: dict) -> dict:
    samples = result['samples']
    warm = [s for s in samples if s['t'] >= result['duration_s'] / 2.0]
    growth = (warm[-1]['rss_mib'] - warm[0]['rss_mib']) if len(warm) >= 2 else None
    figures = dict(quarters=quarters(result), rss_growth_second_half_mib=growth,
                   rss_growth_second_half_pct=100.0 * growth / warm[0]['rss_mib'] if growth is not None else None)
    print('\nsoak, per quarter of the run (each sample covers the previous --sample seconds):')
    print('| quarter | merged Hz (avg) | lowest sample Hz | node CPU (cores) | RSS at end (MiB) | robots included |')
    print('|---|---|---|---|---|---|')
    for q in figures['quarters']:
        print(f"| {q['quarter']} | {q['merged_hz']:.2f} | {q['merged_hz_min']:.2f} | {q['cores']:.2f} | "
              f"{q['rss_mib']:.0f} | {q['included']}/{result['robots']} |")
    if growth is not None:
        print(f"RSS growth over the second half: {growth:+.1f} MiB ({figures['rss_growth_second_half_pct']:+.1f} %)")
    return figures


def main(argv: Optional[List[str]] = None) -> None:
    argv = list(sys.argv[1:] if argv is None else argv)
    args = bench_node.parse_args(SOAK_DEFAULTS + argv)   # later options win: the caller's override the defaults
    result = bench_node.run(args)
    bench_node.report(result)
    result['soak'] = soak_report(result)
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))


if __name__ == '__main__':
    main()
