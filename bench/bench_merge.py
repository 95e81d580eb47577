#!/usr/bin/env python3
"""Benchmark of the merging core (not a test: it prints figures and their ratio to the targets).

    scripts/env.sh python bench/bench_merge.py [--data DIR] [--repeat N] [--quick] [--curve] [--markdown FILE]
    scripts/env.sh python bench/bench_merge.py --large36 [CACHE] [--repeat N] [--markdown FILE]
    scripts/env.sh python bench/bench_merge.py [--large36 CACHE] --generated [NAMES] [--seeds S ... | --reversed |
        --shuffled S ...] [--markdown FILE]
    scripts/env.sh python bench/bench_merge.py --reveal SHARES [--generated [NAMES]] [--markdown FILE]

Each row runs in its own subprocess so that its peak resident memory (ru_maxrss / VmHWM) is its own.
Estimation "cold" = fresh MergingPipeline (empty feature cache); "warm" = a second estimate() on the same
pipeline with unchanged grids. Times are medians over --repeat runs. Timings on a shared machine are inflated.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / 'scripts'))   # make_sample_maps: the generated scenarios' specs
import machine  # noqa: E402  (bench/, beside this script)

CANVAS = 2048
# row name -> (scenario folder, label); "canvas8" pastes group8_cave into 2048x2048 canvases,
# "truth30" composes large30 with the ground-truth transforms (no estimation).
ROWS: Dict[str, Tuple[str, str]] = {
    'pair2': ('pair_large_hospital_section_1', '2 maps'),
    'group4': ('group4_hospital_section', '4 maps'),
    'group8': ('group8_cave', '8 maps'),
    'large30': ('large30_hospital_section', '30 maps'),
    'canvas2': ('canvas2_hospital_section', '2 canvas maps'),
    'canvas4': ('canvas4_cave', '4 canvas maps'),
    'canvas8': ('group8_cave', '8 canvas maps (pasted)'),
    'truth30': ('large30_hospital_section', '30 maps, truth tf (compose only)'),
}
QUICK = ['pair2', 'group4']
EST_TARGET_S, CPP_CANVAS8_S, CPP_LARGE30_S, COMPOSE_TARGET_S = 2.0, (7.0, 13.0), 73.0, 0.250


def load_scenario(folder: Path) -> Tuple[list, dict]:
    from multirobot_map_merge.mapio import load_map
    truth = json.loads((folder / 'truth.json').read_text())
    return [load_map(str(folder / m['file'])) for m in truth['maps']], truth


def to_canvas(grid):
    """Paste grid into the centre of an unknown CANVAS x CANVAS grid; the map frame is unchanged."""
    from multirobot_map_merge.grid import Grid
    dy, dx = (CANVAS - grid.height) // 2, (CANVAS - grid.width) // 2
    data = np.full((CANVAS, CANVAS), -1, np.int8)
    data[dy:dy + grid.height, dx:dx + grid.width] = grid.data
    ox, oy = (grid.cell_to_map() @ np.array([-dx, -dy, 1.0]))[:2]   # old origin - offset * resolution
    return Grid(data, grid.resolution, (ox, oy, grid.origin[2]), grid.frame_id)


def peak_rss_mib() -> float:
    """Peak resident set of this process: VmHWM if available, else ru_maxrss (KiB on Linux)."""
    try:
        for line in Path('/proc/self/status').read_text().splitlines():
            if line.startswith('VmHWM:'):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def med(xs: List[float]) -> Optional[float]:
    return statistics.median(xs) if xs else None


def run_row(name: str, data_dir: Path, repeat: int) -> dict:
    """Measure one row in this process; returns medians and the peak RSS."""
    from multirobot_map_merge import transforms as tf
    from multirobot_map_merge.pipeline import MergingPipeline
    from multirobot_map_merge.estimation.settings import EstimationSettings
    grids, truth = load_scenario(data_dir / ROWS[name][0])
    if name == 'canvas8':
        grids = [to_canvas(g) for g in grids]
    rss_loaded = peak_rss_mib()
    cold: List[float] = []
    warm: List[float] = []
    comp: List[float] = []
    placed = 0
    for _ in range(repeat):
        pipeline = MergingPipeline(EstimationSettings())
        pipeline.feed(grids)
        if name == 'truth30':
            pipeline.set_transforms([tf.rigid(*m['pose']) for m in truth['maps']])
        else:
            cold.append(pipeline.estimate().seconds)
            warm.append(pipeline.estimate().seconds)
        pipeline.compose('world')
        comp.append(pipeline.compose_seconds)
        placed = sum(t is not None for t in pipeline.transforms)
    return {'name': name, 'maps': len(grids), 'cold': med(cold), 'warm': med(warm), 'compose': med(comp),
            'placed': placed, 'mergeable': len(truth.get('mergeable', truth['maps'])),
            'size': f'{grids[0].width}x{grids[0].height}', 'rss_loaded': rss_loaded, 'rss_peak': peak_rss_mib()}


CURVE_SIZES = (2, 4, 8, 12, 16, 20, 24, 30)


def run_curve(data_dir: Path, repeat: int) -> List[dict]:
    """Estimation of the first n maps of the 30-map scenario, for growing n: the cost per added map."""
    import time
    from multirobot_map_merge.pipeline import MergingPipeline
    from multirobot_map_merge.estimation.settings import EstimationSettings
    grids, truth = load_scenario(data_dir / ROWS['large30'][0])
    # each next map is the one that shares most with those before it (as robots of one fleet): every first n maps
    # can merge, so the curve shows the cost of adding a map, not of leaving one out
    shared = np.array(truth['overlap']['shared_m2'])
    order = [int(np.argmax(shared.sum(axis=1)))]
    while len(order) < len(grids):
        rest = [k for k in range(len(grids)) if k not in order]
        order.append(max(rest, key=lambda k: shared[k, order].sum()))
    grids = [grids[k] for k in order]
    rows = []
    for n in CURVE_SIZES:
        wall, cpu, placed = [], [], 0
        for _ in range(repeat):
            pipeline = MergingPipeline(EstimationSettings())
            pipeline.feed(grids[:n])
            c0 = time.process_time()
            wall.append(pipeline.estimate().seconds)
            cpu.append(time.process_time() - c0)
            placed = sum(t is not None for t in pipeline.transforms)
        rows.append({'maps': n, 'wall': med(wall), 'cpu': med(cpu), 'placed': placed})
    return rows


def curve_table(rows: List[dict]) -> List[str]:
    lines = ['| maps | placed | estimation (s) | CPU (s) | s per map | CPU s per map | CPU s per added map |',
             '|---|---|---|---|---|---|---|']
    prev = None
    for r in rows:
        added = '-' if prev is None else f"{(r['cpu'] - prev['cpu']) / (r['maps'] - prev['maps']):.3f}"
        lines.append(f"| {r['maps']} | {r['placed']} | {r['wall']:.2f} | {r['cpu']:.2f} | {r['wall'] / r['maps']:.3f} "
                     f"| {r['cpu'] / r['maps']:.3f} | {added} |")
        prev = r
    return lines


def spawn_row(name: str, data_dir: Path, repeat: int) -> Optional[dict]:
    cmd = [sys.executable, __file__, '--row', name, '--data', str(data_dir), '--repeat', str(repeat)]
    print(f'... {name}', file=sys.stderr, flush=True)
    proc = subprocess.run(cmd, stdout=subprocess.PIPE, text=True)
    if proc.returncode != 0:
        print(f'row {name} failed (exit {proc.returncode})', file=sys.stderr)
        return None
    return json.loads(proc.stdout.strip().splitlines()[-1])


def fmt(v: Optional[float], scale: float = 1.0, digits: int = 2) -> str:
    return '-' if v is None else f'{v * scale:.{digits}f}'


def table(results: List[dict]) -> List[str]:
    head = ['row', 'maps', 'map size', 'est. cold (s)', 'est. warm (s)', 'compose (ms)', 'placed/mergeable',
            'RSS loaded (MiB)', 'peak RSS (MiB)']
    lines = ['| ' + ' | '.join(head) + ' |', '|' + '---|' * len(head)]
    for r in results:
        cells = [ROWS[r['name']][1], str(r['maps']), r['size'], fmt(r['cold']), fmt(r['warm'], digits=3),
                 fmt(r['compose'], 1000, 1), f"{r['placed']}/{r['mergeable']}", fmt(r['rss_loaded'], digits=0),
                 fmt(r['rss_peak'], digits=0)]
        lines.append('| ' + ' | '.join(cells) + ' |')
    return lines


def targets(results: List[dict]) -> List[str]:
    by = {r['name']: r for r in results}
    out = []
    if 'canvas8' in by and by['canvas8']['cold'] is not None:
        t = by['canvas8']['cold']
        out.append(f'- 8 canvas-size maps estimated in under {EST_TARGET_S:.0f} s: {t:.2f} s = '
                   f'{t / EST_TARGET_S:.2f} x target ({"met" if t < EST_TARGET_S else "MISSED"}); '
                   f'C++ {CPP_CANVAS8_S[0]:.0f}-{CPP_CANVAS8_S[1]:.0f} s -> '
                   f'{CPP_CANVAS8_S[0] / t:.1f}-{CPP_CANVAS8_S[1] / t:.1f} x faster')
    if 'large30' in by and by['large30']['cold'] is not None:
        t = by['large30']['cold']
        out.append(f'- 30-map scenario estimated: {t:.2f} s; C++ {CPP_LARGE30_S:.0f} s -> '
                   f'{CPP_LARGE30_S / t:.1f} x faster')
    if 'truth30' in by:
        t = by['truth30']['compose']
        out.append(f'- 30 maps composed in under {COMPOSE_TARGET_S * 1000:.0f} ms: {t * 1000:.1f} ms = '
                   f'{t / COMPOSE_TARGET_S:.2f} x target ({"met" if t < COMPOSE_TARGET_S else "MISSED"})')
    return out


# ----------------------------------------------------------------------------------------------- generated rows
# Rows on scenarios that scripts/make_sample_maps.py generates (not in the shared data): made on demand into a cache
# folder, registered in ROWS only when asked for (--large36) so the default table is unchanged.
GENERATED_ROWS: Dict[str, Tuple[str, str]] = {
    'large36': ('large36', '36 maps, 9 broken (generated)'),
    'large36_b': ('large36_b', '36 maps, 9 broken (generated, building 6)'),
    'large36_c': ('large36_c', '36 maps, 9 broken (generated, building 7)'),
    'large36_d': ('large36_d', '36 maps, 9 broken (generated, building 8)'),
}
LARGE36_TARGET_S = 3.0          # issue #13: one estimation of the 36 maps by merge_maps
SHARED_EVAL = REPO / '..' / 'shared' / 'eval'


def ensure_generated(cache: Path, name: str) -> Optional[float]:
    """Generate scenario ``name`` into cache/name unless its truth.json (written last) is there; returns the
    generation's wall time, or None if it was cached."""
    if (cache / name / 'truth.json').is_file():
        return None
    cache.mkdir(parents=True, exist_ok=True)
    print(f'... generating {name} into {cache} (under a minute)', file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    cmd = [sys.executable, str(REPO / 'scripts' / 'make_sample_maps.py'), '--scenario', name, '--out', str(cache)]
    proc = subprocess.run(cmd, stdout=subprocess.PIPE, text=True)
    sys.stderr.write(proc.stdout)
    if not (cache / name / 'truth.json').is_file():
        raise RuntimeError(f'generating {name} failed (exit {proc.returncode})')
    return time.perf_counter() - t0


MERGE_OPTIONS: List[str] = []   # more options of merge_maps (--no-processes)


def merge_and_score(folder: Path, out_dir: Path, log: Optional[Path] = None, seed: int = 0,
                    truth: Optional[dict] = None) -> Optional[dict]:
    """Run nodes/merge_maps on the scenario's maps (one cold estimation in its own process) and score its placements
    with the shared scorer; None if the scorer is missing or a step failed. With log, merge_maps runs with -v and
    its stderr (each match judged, with its reason) goes to that file; `seed`: merge_maps --seed; the maps are given
    in the order of `truth` (default: the scenario's truth.json; the scorer finds them by file name)."""
    score_py = SHARED_EVAL / 'score.py'
    if not score_py.is_file():
        print(f'bench_merge: {score_py} not found: not scored', file=sys.stderr)
        return None
    truth = truth or json.loads((folder / 'truth.json').read_text())
    out_dir.mkdir(parents=True, exist_ok=True)
    result = out_dir / 'result.json'
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in (str(REPO), os.environ.get('PYTHONPATH')) if p))
    merge = [sys.executable, str(REPO / 'nodes' / 'merge_maps'), '--transforms-json', str(result),
             '--output', str(out_dir / 'merged'), '--seed', str(seed), *(['-v'] if log else []), *MERGE_OPTIONS,
             *(str(folder / m['file']) for m in truth['maps'])]
    print(f'... merge_maps on {len(truth["maps"])} maps of {folder.name}', file=sys.stderr, flush=True)
    with open(log, 'w') if log else open(os.devnull, 'w') as err:
        code = subprocess.run(merge, env=env, stdout=subprocess.DEVNULL, stderr=err if log else None).returncode
    if code != 0 or not result.is_file():
        print('bench_merge: merge_maps failed', file=sys.stderr)
        return None
    proc = subprocess.run([sys.executable, str(score_py), '--truth', str(folder / 'truth.json'),
                           '--result', str(result)], stdout=subprocess.PIPE, text=True)
    if proc.returncode != 0:
        print('bench_merge: score.py failed', file=sys.stderr)
        return None
    return json.loads(proc.stdout)


def reordered_truth(truth: dict, order: List[int]) -> dict:
    """The truth of the same maps given to merge_maps in `order` (the k-th map given is the truth's map order[k]): its
    indices (a map's place in the list, as merge_maps -v names the maps) count in that order."""
    place = {k: n for n, k in enumerate(order)}
    return dict(truth, maps=[truth['maps'][k] for k in order], mergeable=sorted(place[k] for k in truth['mergeable']),
                components=[sorted(place[k] for k in c) for c in truth.get('components', [])])


def reversed_truth(truth: dict) -> dict:
    """The truth of the same maps given to merge_maps in reverse order."""
    return reordered_truth(truth, list(range(len(truth['maps'])))[::-1])


def shuffled_truth(truth: dict, seed: int) -> dict:
    """The truth of the same maps given to merge_maps in an order drawn with `seed`."""
    return reordered_truth(truth, [int(k) for k in np.random.default_rng(seed).permutation(len(truth['maps']))])


def scenario_lines(truth: dict) -> List[str]:
    """The generated scenario's own figures (sizes, broken and mergeable maps), read from its truth."""
    ms = truth['maps']
    cells = sorted(m['size'][0] * m['size'][1] for m in ms)
    big = max(ms, key=lambda m: m['size'][0] * m['size'][1])['size']
    small = min(ms, key=lambda m: m['size'][0] * m['size'][1])['size']
    broken = sum(m['broken'] for m in ms)
    return [f"- scenario {truth['scenario']} ({truth['world']}, {truth['world_size_m'][0]:g} x "
            f"{truth['world_size_m'][1]:g} m): {len(ms)} maps of {small[0]}x{small[1]} to {big[0]}x{big[1]} cells "
            f"(median {cells[len(cells) // 2] / 1e3:.0f} k cells, total {sum(cells) / 1e6:.1f} M), {broken} broken, "
            f"{len(truth['mergeable'])} mergeable"]


def score_lines(s: Optional[dict]) -> List[str]:
    if s is None:
        return ['- not scored']
    pairs = s['pairs']
    rot = med([p['rot_deg'] for p in pairs])
    trans = med([p['trans_cells'] for p in pairs])
    t = (s['estimate_ms'] or 0.0) / 1000
    return [f"- merge_maps (own process, cold): estimate {t:.2f} s = {t / LARGE36_TARGET_S:.2f} x target; "
            f"scorer: correct {s['correct']}/{s['mergeable']} mergeable, false merges {s['wrong']}, excluded "
            f"{s['excluded']}, broken maps placed consistently {s['broken_ok']}, extra {s['extra_ok']}; "
            f"pair error median {fmt(rot, digits=3)} deg, {fmt(trans)} cells"]


def run_generated(names: List[str], cache: Path, repeat: int, markdown: Optional[Path]) -> int:
    """Generate (if missing) and time each generated scenario as the 30-map row, then merge_maps + score it."""
    status, lines = 0, []
    for name in names:
        code, block = generated_block(name, cache, repeat)
        status = max(status, code)
        lines += block + ['']
        print('\n'.join(block + ['']), flush=True)
    if markdown:
        markdown.write_text('\n'.join(lines))
    return status


def generated_block(name: str, cache: Path, repeat: int) -> Tuple[int, List[str]]:
    """(exit status: 0, 1 if timing or scoring failed, 2 if generating failed; the lines to print) for one generated
    scenario."""
    try:
        gen_s = ensure_generated(cache, name)
    except RuntimeError as e:
        return 2, [f'bench_merge: {e}']
    folder = cache / GENERATED_ROWS[name][0]
    truth = json.loads((folder / 'truth.json').read_text())
    row = spawn_row(name, cache, repeat)
    scored = merge_and_score(folder, cache / f'{name}_result')
    made = 'cached' if gen_s is None else f'generated in {gen_s:.0f} s'
    lines = [f'generated-scenario benchmark ({folder}, {made}): {repeat} repeat(s), median; {machine.describe()}',
             '']
    if row is not None:
        t = row['cold']
        lines += [*table([row]), '',
                  f"- {len(truth['maps'])} maps ({sum(m['broken'] for m in truth['maps'])} broken) estimated in "
                  f'under {LARGE36_TARGET_S:.0f} s: {t:.2f} s = '
                  f'{t / LARGE36_TARGET_S:.2f} x target ({"met" if t <= LARGE36_TARGET_S else "MISSED"})']
    lines += scenario_lines(truth) + score_lines(scored)
    return (0 if row is not None and scored is not None else 1), lines


def building_names(arg: str) -> List[str]:
    """--generated's NAMES: 'buildings' (every building kind of make_sample_maps.BUILDING_FLEETS), 'unseen',
    'unseen2' and 'unseen3' (the held-out buildings of every kind, <kind>36_u, _v and _w), 'large' (large36 and its
    three other buildings, large36_b to _d), or a list."""
    import make_sample_maps
    suffix = {'buildings': '', 'unseen': '_u', 'unseen2': '_v', 'unseen3': '_w'}.get(arg)
    if suffix is not None:
        return [f'{kind}36{suffix}' for kind in make_sample_maps.BUILDING_FLEETS]
    if arg == 'large':
        return [name for name, spec in make_sample_maps.GENERATED.items() if spec.get('kind') == 'large']
    return arg.split(',')


def variants_table(names: List[str], per_variant: Dict[str, Dict[str, dict]]) -> List[str]:
    """The table of every building's placed right / mergeable and false merges, a column per variant (label ->
    building -> its row of run_buildings), and a last row of the totals; when the rows say it, a column first of the
    mergeable maps the acceptance rules hold together at their true places (the same in every variant), with how
    many of them only narrowly (merge_diagnosis.NARROW_MARGIN: placed or left out as small changes of the estimates
    have it)."""
    labels = list(per_variant)
    held = {name: r['held'] for rows in per_variant.values() for name, r in rows.items() if 'held' in r}
    narrowly: Dict[str, int] = {}
    for rows in per_variant.values():
        for name, r in rows.items():
            narrowly[name] = max(narrowly.get(name, 0), r.get('narrowly', 0))

    def held_cell(n: int, narrow: int) -> str:
        return f'{n} ({narrow} narrowly)' if narrow else str(n)
    first = ['held at the truth'] if held else []
    lines = ['| building | ' + ' | '.join(first + [f'{v}: right / mergeable, false' for v in labels]) + ' |',
             '|---|' + '---|' * (len(first) + len(labels))]
    for name in names:
        cells = [per_variant[v].get(name) for v in labels]
        scores = ['-' if c is None else f"{c['correct']}/{c['mergeable']}, {c['wrong']}" for c in cells]
        first_cell = [held_cell(held[name], narrowly[name]) if name in held else '-'] if held else []
        lines.append(f'| {name} | ' + ' | '.join(first_cell + scores) + ' |')
    totals = [held_cell(sum(held.values()), sum(narrowly.values()))] if held else []
    for v in labels:
        done = list(per_variant[v].values())
        totals.append(f"{sum(r['correct'] for r in done)}/{sum(r['mergeable'] for r in done)}, "
                      f"{sum(r['wrong'] for r in done)}")
    lines.append('| all | ' + ' | '.join(totals) + ' |')
    return lines


def run_variants(names: List[str], cache: Path, markdown: Optional[Path], again: bool,
                 variants: Dict[str, dict]) -> int:
    """run_buildings once per variant (label -> its keyword arguments: `seed`, merge_maps --seed, or `shuffle`, the
    maps in an order drawn with it), then one table of every building's placed right / false merges per variant:
    unseen buildings are as many other draws of the random sampling and other orders of the files as other floor
    plans."""
    status, per_variant = 0, {}
    for label, options in variants.items():
        print(f'--- {label}', flush=True)
        rows: List[dict] = []
        status = max(status, run_buildings(names, cache, None, again, out_rows=rows, **options))
        per_variant[label] = {r['name']: r for r in rows}
    lines = [f'generated buildings, {", ".join(variants)} ({cache}); {machine.describe()}', ''] \
        + variants_table(names, per_variant)
    print('\n'.join([''] + lines), flush=True)
    if markdown:
        markdown.write_text('\n'.join(lines) + '\n')
    return status


def run_buildings(names: List[str], cache: Path, markdown: Optional[Path], again: bool = False, seed: int = 0,
                  out_rows: Optional[List[dict]] = None, reverse: bool = False, shuffle: Optional[int] = None) -> int:
    """Each generated scenario: made if missing, merged by merge_maps -v --seed `seed` (its own process; with
    `reverse`, its maps given in reverse order; with `shuffle`, in an order drawn with that seed), scored; one row
    each (also appended to `out_rows`), the median and worst estimation, how many mergeable maps the acceptance rules
    hold together at their true places and how many of those are placed right (merge_diagnosis.evidence: a map whose
    true place passes no rule is left out by any estimation that keeps them), and of those, the maps held only
    narrowly (NARROW_MARGIN: placed or left out as a little change of the estimates has it), then why each mergeable
    map left out or placed wrong is so (merge_diagnosis; with again, each such map is also matched again against
    right-placed maps and the final union), and in a merge with maps placed wrong, which healthy members contradict
    each other."""
    import make_sample_maps
    from merge_diagnosis import (NARROW_MARGIN, cause_counts, contradicting_members, diagnose, evidence, replay,
                                 verdict_lines)
    rows, notes, verdicts_all, status = [], [], [], 0
    replayed: Dict[str, int] = {}
    for name in names:
        try:
            ensure_generated(cache, name)
        except RuntimeError as e:
            notes.append(f'- {name}: {e}')
            status = 2
            continue
        folder = cache / name
        truth = json.loads((folder / 'truth.json').read_text())
        if reverse:
            truth = reversed_truth(truth)
        if shuffle is not None:
            truth = shuffled_truth(truth, shuffle)
        result_dir = cache / (f'{name}_result' + (f'_seed{seed}' if seed else '') + ('_reversed' if reverse else '')
                              + (f'_shuffled{shuffle}' if shuffle is not None else ''))
        log = result_dir / 'merge_maps.log'
        scored = merge_and_score(folder, result_dir, log, seed, truth)
        spec = make_sample_maps.GENERATED.get(name, {})
        pattern = spec.get('pattern', 'random')
        if scored is None:
            rows.append(f'| {name} | {pattern} | {len(truth["mergeable"])} | - | - | - | - |')
            status = max(status, 1)
            continue
        verdicts = diagnose(log.read_text(), scored, truth)
        verdicts_all += verdicts
        files = [m['file'] for m in truth['maps']]
        held = evidence(folder, truth)
        notes += [line + (f'; without evidence at the truth: {held.without[v.map_index]}'
                          if v.map_index in held.without else '')
                  for v, line in zip(verdicts, verdict_lines(name, verdicts, files))]
        right = {p['file'].rsplit('/', 1)[-1] for p in scored['placements'] if p['ok'] and p['mergeable']} \
            | {(scored.get('reference') or '').rsplit('/', 1)[-1]}   # the reference is placed by definition
        in_evidence = {files[k] for k in set(held.held) & set(truth['mergeable'])}
        narrowly = {files[k] for k in set(held.narrowly) & set(truth['mergeable'])}
        if scored['wrong']:
            # a group placed by a wrong link: where it meets the rest, its members contradict those there
            notes += contradicting_members(folder, truth, result_dir)
        if again and verdicts:
            print(f'... matching the {len(verdicts)} maps of {name} not placed right again', file=sys.stderr,
                  flush=True)
            matched = replay(folder, truth, scored, result_dir, verdicts)
            notes += [line for line, _ in matched]
            for _, label in matched:
                replayed[label] = replayed.get(label, 0) + 1
        t = (scored['estimate_ms'] or 0.0) / 1000
        left = sum(v.outcome == 'left out' for v in verdicts)
        rows.append({'name': name, 'pattern': pattern, 'mergeable': scored['mergeable'], 'correct': scored['correct'],
                     'wrong': scored['wrong'], 'left': left, 'broken_ok': scored['broken_ok'], 't': t,
                     'held': len(in_evidence), 'held_right': len(in_evidence & right),
                     'narrowly': len(narrowly), 'narrowly_right': len(narrowly & right)})
        if out_rows is not None:
            out_rows.append(rows[-1])
    done = [r for r in rows if isinstance(r, dict)]
    order = ', each building\'s maps in reverse order' if reverse else ''
    if shuffle is not None:
        order = f', each building\'s maps in an order drawn with seed {shuffle}'
    lines = [f'generated buildings ({cache}): merge_maps -v, one process per building, cold{order}; '
             f'{machine.describe()}', '',
             '| building | robots | placed right / mergeable | false merges | mergeable left out | broken placed '
             'consistently | estimation (s) |', '|---|---|---|---|---|---|---|']
    for r in rows:
        lines.append(r if isinstance(r, str) else
                     f"| {r['name']} | {r['pattern']} | {r['correct']}/{r['mergeable']} | {r['wrong']} | {r['left']} | "
                     f"{r['broken_ok']} | {r['t']:.2f} |")
    if done:
        times = sorted(r['t'] for r in done)
        worst = max(done, key=lambda r: r['t'])
        narrow = ', '.join(f"{r['name']} {r['narrowly']}" for r in done if r['narrowly'])
        lines += ['', f"- placed right {sum(r['correct'] for r in done)} of {sum(r['mergeable'] for r in done)} "
                      f"mergeable maps in {len(done)} buildings ({sum(r['correct'] == r['mergeable'] for r in done)} "
                      f"buildings complete); false merges {sum(r['wrong'] for r in done)}",
                  f"- at their true places the acceptance rules hold {sum(r['held'] for r in done)} of the mergeable "
                  f"maps together (merge_diagnosis.evidence); placed right {sum(r['held_right'] for r in done)} of "
                  f"those",
                  f"- {sum(r['narrowly'] for r in done)} of them only narrowly (not held once pairs and joins ask "
                  f"{NARROW_MARGIN:g} times the support and precision: {narrow or 'none'}); placed right "
                  f"{sum(r['narrowly_right'] for r in done)} of those",
                  f"- estimation median {statistics.median(times):.2f} s, worst {worst['t']:.2f} s ({worst['name']})"
                  f" (targets {LARGE36_TARGET_S:.0f} s and {2 * LARGE36_TARGET_S:.0f} s)"]
    counts = cause_counts(verdicts_all)
    if counts:
        lines += ['', 'why mergeable maps are not placed right (maps per cause, bench/merge_diagnosis.py):', '',
                  '| outcome: cause | maps |', '|---|---|', *(f'| {k} | {v} |' for k, v in counts.items()), '']
    if replayed:
        lines += ['the same maps matched again (--replay) against the right-placed maps they overlap most and the '
                  'final union:', '', '| matched again | maps |', '|---|---|',
                  *(f'| {k} | {v} |' for k, v in sorted(replayed.items(), key=lambda kv: -kv[1])), '']
    if counts:
        lines += notes
    print('\n'.join(lines), flush=True)
    if markdown:
        markdown.write_text('\n'.join(lines) + '\n')
    return status


def run_reveal(folder: Path, shares: List[float]) -> List[str]:
    """A scenario (the 30-map one, or a generated building) revealed as a fleet explores it (bench/reveal.py: 2 m
    tiles, nearest to each robot's start first, as bench_node publishes them), estimated afresh at each share of the
    reveal and scored: maps placed, and those placed wrong with their errors."""
    from multirobot_map_merge.estimation.estimator import estimate
    from multirobot_map_merge.estimation.settings import EstimationSettings
    from reveal import reveal_order, revealed_grids, score_placements, scorer, wrong_of
    score = scorer()
    if score is None:
        return ['bench_merge: ../shared/eval/score.py not found: nothing to score']
    grids, truth = load_scenario(folder)
    orders = [reveal_order(g) for g in grids]
    lines = [f'{folder.name} revealed tile by tile, estimated afresh (merge_maps settings) and scored; '
             f'{machine.describe()}', '',
             '| share revealed | known m2 (median map) | placed | placed wrong | estimate (s) | wrong: file, degrees, '
             'cells |', '|---|---|---|---|---|---|']
    for share in shares:
        shown = revealed_grids(grids, orders, share)
        found = estimate(shown, EstimationSettings())
        scored = score_placements(score, truth, dict(enumerate(found.transforms)))
        known = statistics.median(float((s.data >= 0).sum()) * s.resolution ** 2 for s in shown)
        lines.append(f'| {share:.2f} | {known:.0f} | {scored["included"]} | {scored["wrong"]} | {found.seconds:.2f} | '
                     f'{"; ".join(f"{f} {r:.2f} {c:.1f}" for f, r, c in wrong_of(scored))} |')
    return lines


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--data', type=Path, default=REPO / '..' / 'shared' / 'data' / 'dev')
    ap.add_argument('--repeat', type=int, default=3)
    ap.add_argument('--no-processes', action='store_true',
                    help='merge_maps --no-processes: the matches on threads (to compare with the worker processes)')
    ap.add_argument('--quick', action='store_true', help='only the 2- and 4-map rows, 1 repeat')
    ap.add_argument('--markdown', type=Path, help='also write the table as Markdown to this file')
    ap.add_argument('--curve', action='store_true',
                    help='only the cost curve: estimation of the first 2..30 maps of the 30-map scenario')
    ap.add_argument('--large36', type=Path, nargs='?', const=REPO / 'out' / 'bench', metavar='CACHE',
                    help='only the generated 36-map scenario (9 broken maps): made into CACHE/large36 if missing '
                         '(default out/bench), timed as the 30-map row, then merged by merge_maps and scored')
    ap.add_argument('--generated', metavar='NAMES', nargs='?', const='buildings',
                    help='generated scenarios, made into CACHE/NAME if missing (--large36 CACHE, default out/bench; '
                         'under a minute each), one merge_maps -v process each: a row per scenario (placed right, '
                         'false merges, estimation time), the median and worst, the mergeable maps the acceptance '
                         'rules hold together at their true places and how many of those are placed right, and why '
                         'each mergeable map is left out or placed wrong. NAMES: comma-separated '
                         '(make_sample_maps.py GENERATED: large36, large36_b.._d, <kind>36 for every building kind, '
                         '<kind>36_u, _v and _w the held-out ones), unseen: every <kind>36_u, unseen2: every '
                         '<kind>36_v, unseen3: every <kind>36_w, large: large36 to large36_d, or none: every <kind>36')
    ap.add_argument('--replay', action='store_true',
                    help='with --generated: match each mergeable map not placed right again, against the right-placed '
                         'maps it overlaps most and against the merged map, each verdict checked with the truth '
                         '(after the timing: a pair refused that the union also refuses, or accepted by pairs only)')
    ap.add_argument('--seeds', metavar='S', type=int, nargs='+', default=[0],
                    help='with --generated: merge each building once per seed of the random sampling (merge_maps '
                         '--seed), then a table of placed right and false merges per building and seed (default: 0)')
    ap.add_argument('--reversed', action='store_true',
                    help='with --generated: each building\'s maps given to merge_maps in reverse order (the merge '
                         'should not depend on the order of the files)')
    ap.add_argument('--shuffled', metavar='S', type=int, nargs='+',
                    help='with --generated: each building\'s maps given to merge_maps in an order drawn with seed S '
                         '(several: once per order, then a table of placed right and false merges per order)')
    ap.add_argument('--reveal', metavar='SHARES', type=lambda v: [float(x) for x in v.split(',')],
                    help='only the 30-map scenario (or with --generated, those buildings) revealed as a fleet explores '
                         'it, estimated afresh at these shares of the reveal (comma-separated, 0..1) and scored: the '
                         'maps placed wrong on partial maps')
    ap.add_argument('--row', choices=list(ROWS) + list(GENERATED_ROWS), help=argparse.SUPPRESS)   # internal
    args = ap.parse_args()
    if args.no_processes:
        MERGE_OPTIONS.append('--no-processes')
    if args.large36 or args.row in GENERATED_ROWS:
        ROWS.update(GENERATED_ROWS)
    if args.generated:
        import make_sample_maps
        names = building_names(args.generated)
        unknown = [n for n in names if n not in make_sample_maps.GENERATED]
        if unknown:
            ap.error(f'unknown generated scenario {unknown[0]} (one of {", ".join(make_sample_maps.GENERATED)})')
        cache = (args.large36 or REPO / 'out' / 'bench').resolve()
        if (args.reversed or args.shuffled is not None) and (args.reveal or args.seeds != [0]):
            ap.error('--reversed and --shuffled go with --generated [--replay] alone')
        if args.reversed and args.shuffled is not None:
            ap.error('--reversed or --shuffled, not both')
        if args.reveal:
            lines = []
            for name in names:
                ensure_generated(cache, name)
                lines += run_reveal(cache / name, args.reveal) + ['']
            print('\n'.join(lines))
            if args.markdown:
                args.markdown.write_text('\n'.join(lines))
            return 0
        if args.seeds != [0]:
            return run_variants(names, cache, args.markdown, args.replay,
                                {f'seed {s}': dict(seed=s) for s in args.seeds})
        if args.shuffled is not None and len(args.shuffled) > 1:
            return run_variants(names, cache, args.markdown, args.replay,
                                {f'order {s}': dict(shuffle=s) for s in args.shuffled})
        return run_buildings(names, cache, args.markdown, args.replay, reverse=args.reversed,
                             shuffle=args.shuffled[0] if args.shuffled else None)
    if args.large36:
        return run_generated(['large36'], args.large36.resolve(), max(1, args.repeat),
                             args.markdown)
    data_dir = args.data.resolve()
    if not data_dir.is_dir():
        print(f'bench_merge: data directory {data_dir} not found (use --data DIR)', file=sys.stderr)
        return 2
    if args.row:
        print(json.dumps(run_row(args.row, data_dir, max(1, args.repeat))))
        return 0
    if args.reveal:
        lines = run_reveal(data_dir / ROWS['large30'][0], args.reveal)
        print('\n'.join(lines))
        if args.markdown:
            args.markdown.write_text('\n'.join(lines) + '\n')
        return 0
    if args.curve:
        lines = [f'estimation cost curve (first n maps of {ROWS["large30"][0]}), {max(1, args.repeat)} repeat(s), '
                 f'median; {machine.describe()}', '',
                 *curve_table(run_curve(data_dir, max(1, args.repeat)))]
        print('\n'.join(lines))
        if args.markdown:
            args.markdown.write_text('\n'.join(lines) + '\n')
        return 0
    names = QUICK if args.quick else list(ROWS)
    repeat = 1 if args.quick else max(1, args.repeat)
    missing = [ROWS[n][0] for n in names if not (data_dir / ROWS[n][0] / 'truth.json').is_file()]
    if missing:
        print(f'bench_merge: scenarios missing in {data_dir}: {", ".join(sorted(set(missing)))}', file=sys.stderr)
        return 2
    results = [r for r in (spawn_row(n, data_dir, repeat) for n in names) if r is not None]
    lines = [f'merging core benchmark: {repeat} repeat(s), median; {machine.describe()} (timings are inflated on a '
             f'busy machine)', '', *table(results), '',
             *targets(results)]
    print('\n'.join(lines))
    if args.markdown:
        args.markdown.write_text('\n'.join(lines) + '\n')
    return 0 if len(results) == len(names) else 1


if __name__ == '__main__':
    sys.exit(main())
