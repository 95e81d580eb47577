"""Candidate placements without descriptors: rotation by wall directions, translation by cross-correlation.

Small overlaps give too few descriptor matches for RANSAC. Here, at a coarse resolution, grid i is turned by
candidate angles (a sweep, plus the differences of the grids' dominant wall directions modulo 90 degrees; only
those about the turns where the two grids' wall families meet, when both have families) and slid over grid j by
FFT cross-correlation of
    walls_i * walls_j  -  penalty * (walls_i * open_j + open_i * walls_j)  +  free_reward * open_i * open_j
(open = free and away from walls). A wall on the other's open floor is a contradiction, hence the heavy penalty;
floor both maps saw free is weak but real evidence, which matters where the two share few walls (on the dev set's
small overlaps the true placement ranked first to third instead of 18th to 62nd). The best peaks are returned as
pixel transforms i -> j for refinement and verification by the matcher; nothing here decides whether a pair is
accepted.
"""
from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Callable, Dict, List, Optional, Sequence, Tuple

import cv2
import numpy as np

from .features import PreparedGrid, nonzero_2d
from .orientation import near_turns
from .validation import must_not_be_negative

PENALTY = 3.0
FREE_REWARD = 0.3
SCREEN_ANGLES = 8        # angles of the coarser screen's best peaks searched at the search's factor
SCREEN_COARSER = 1.5     # the screen's factor / the search's factor (see correlate_candidates)
SCREEN_MIN_PIXELS = 32   # the screen needs both grids this many pixels across at its factor
PLACE_PX = 2.0           # peaks at neighbouring angles whose grid centres lie this close (coarse pixels) ...
PLACE_DEGREES = 3.5      # ... and whose angles differ by this little (a sweep step and a bit) are one place
PLACE_PEAKS = 4          # peaks of one angle that may each make a place among the best (distinct_places)


@dataclass
class SearchSettings:
    search_factor: int = 4            # working pixels per pixel of the correlation search
    search_sweep_degrees: float = 3.0  # rotation step of the search for maps without straight walls
    search_penalty: float = PENALTY   # correlation search: cost of a wall on the other's open floor
    search_free_reward: float = FREE_REWARD  # correlation search: reward of floor both maps saw free
    search_keep: int = 8              # correlation search: candidates refined
    search_budget_s: float = math.inf  # correlation searches of one estimation stop after this many seconds

    def validate(self) -> None:
        must_not_be_negative(self, 'search_penalty', 'search_free_reward', 'search_keep', 'search_budget_s')


@dataclass
class CoarseGrid:
    walls: np.ndarray        # float32 0/1, coarse pixels
    open: np.ndarray         # float32 0/1
    factor: int              # working pixels per coarse pixel
    direction: float         # dominant wall direction modulo 90 degrees (radians), NaN if none
    strength: float          # share of wall gradient energy near that direction


def coarse(p: PreparedGrid, factor: int) -> CoarseGrid:
    """The search's view of a prepared grid, made once per factor (a grid is searched many times)."""
    key = ('coarse', factor)
    if key not in p.derived:
        p.derived[key] = _coarse(p, factor)
    return p.derived[key]


def _coarse(p: PreparedGrid, factor: int) -> CoarseGrid:
    work = p.work
    h, w = work.shape
    size = (max(w // factor, 1), max(h // factor, 1))
    walls = cv2.resize((work >= 50).astype(np.float32), size, interpolation=cv2.INTER_AREA) > 0
    walls = cv2.dilate(walls.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(np.float32)
    far = (work == 0) & (p.wall_distance > 2 * factor)
    open_ = (cv2.resize(far.astype(np.float32), size, interpolation=cv2.INTER_AREA) >= 0.5).astype(np.float32)
    if 'direction' not in p.derived:
        p.derived['direction'] = wall_direction(work)
    direction, strength = p.derived['direction']
    return CoarseGrid(walls, open_ * (1 - walls), factor, direction, strength)


def wall_direction(work: np.ndarray) -> Tuple[float, float]:
    """Dominant wall direction modulo 90 degrees from the gradient of the wall image."""
    img = cv2.GaussianBlur((work >= 50).astype(np.float32), (5, 5), 1.0)
    gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3)
    mag = np.hypot(gx, gy)
    sel = mag > 0.05
    if sel.sum() < 50:
        return float('nan'), 0.0
    ang = np.mod(np.arctan2(gy[sel], gx[sel]), math.pi / 2)
    hist, edges = np.histogram(ang, bins=180, range=(0, math.pi / 2), weights=mag[sel])
    hist = np.convolve(np.r_[hist[-2:], hist, hist[:2]], np.ones(5) / 5, mode='valid')
    k = int(np.argmax(hist))
    strength = float(hist[k] * 5 / max(hist.sum(), 1e-9))
    return float((edges[k] + edges[k + 1]) / 2), strength


def rotation_candidates(ci: CoarseGrid, cj: CoarseGrid, sweep_degrees: float) -> List[float]:
    """Angles (radians) to try for turning grid i onto grid j: a full sweep, plus the angles that align the
    dominant wall directions when both grids have them (rasterised walls bias those directions towards
    multiples of 45 degrees, so they alone can miss the right angle)."""
    angles = list(np.radians(np.arange(0.0, 360.0, sweep_degrees)))
    if ci.strength > 0.08 and cj.strength > 0.08:
        base = cj.direction - ci.direction
        angles += [base + k * math.pi / 2 + d for k in range(4) for d in (-0.02, 0.0, 0.02)]
    return angles


def _fft_shape(h: int, w: int) -> Tuple[int, int]:
    return cv2.getOptimalDFTSize(h), cv2.getOptimalDFTSize(w)


def zero_rows_hint(rows: int) -> int:
    """cv2.dft's nonzeroRows for an image whose first `rows` rows alone hold values (the search's turned grid in
    the corner of its canvas): OpenCV's own DFT then skips the rows of zeros (Debian's OpenCV 4.6: 1.3-1.6 times
    faster, the same spectra); with Intel's IPP (the wheel) the hint makes OpenCV leave IPP's faster DFT (1.6-3.9
    times slower), and is not given (0)."""
    return 0 if cv2.ipp.useIPP() else rows


def _spectrum(image: np.ndarray, shape: Tuple[int, int]) -> np.ndarray:
    """The DFT (packed CCS) of `image` zero-padded at the bottom and right to `shape`."""
    padded = np.zeros(shape, np.float32)
    padded[:image.shape[0], :image.shape[1]] = image
    return cv2.dft(padded)


def correlate_candidates(pi: PreparedGrid, pj: PreparedGrid, factor: int = 4, sweep_degrees: float = 3.0,
                         peaks_per_angle: int = 2, keep: int = 8, penalty: float = PENALTY,
                         free_reward: float = FREE_REWARD,
                         wanted: Optional[Callable[[np.ndarray], bool]] = None, threads: int = 1,
                         screen_angles: int = SCREEN_ANGLES, distinct_places: bool = False,
                         angles: Optional[Sequence[float]] = None) -> List[np.ndarray]:
    """Best coarse placements of grid i on grid j, as 3x3 transforms between working pixels; only those `wanted`
    accepts (a search for placements elsewhere than a known one), `peaks_per_angle` at most per angle. With
    `distinct_places`, after them the best peak of each of the `keep` best places that they miss (Places). With
    `angles` (radians), only those are correlated, at the factor, unscreened; without, the sweep's
    (rotation_candidates), only those about the turns where the grids' wall families meet when both have families
    (orientation.near_turns).

    Coarse to fine: every angle is correlated at SCREEN_COARSER times the factor first (less than half the
    pixels), and only the `screen_angles` angles of its best peaks again at the factor (0: every angle at the
    factor); not for grids too small to tell places apart at the coarser factor (SCREEN_MIN_PIXELS; such a search
    costs little). At twice the factor (walls dilated to 1.2 m), the true angle of a robot's early map (11 x 17 m)
    ranked 21st among the screen's angles, and 7 of 455 searches on three recorded demo runs missed the truth
    (none unscreened or at 1.5 times). The angles are shared among `threads` threads (OpenCV's DFT releases the
    GIL: 1.8 times faster on two cores)."""
    screen_factor = int(round(SCREEN_COARSER * factor))
    if angles is not None:
        angles = list(angles)
    else:
        # the sweep's angles about the turns where the grids' wall families meet (all of them without families)
        angles = near_turns(pi, pj, rotation_candidates(coarse(pi, factor), coarse(pj, factor), sweep_degrees))
        if screen_angles > 0 and screen_factor > factor \
                and min(pi.work.shape + pj.work.shape) >= screen_factor * SCREEN_MIN_PIXELS:
            screened = _correlate(pi, pj, screen_factor, peaks_per_angle, 2 * screen_angles, penalty, free_reward,
                                  None, threads, angles)
            angles = list(dict.fromkeys(angle for _, _, angle in screened))[:screen_angles]
    found = _correlate(pi, pj, factor, peaks_per_angle, keep, penalty, free_reward, wanted, threads, angles,
                       distinct_places)
    return [t for _, t, _ in found]


def _correlate(pi: PreparedGrid, pj: PreparedGrid, factor: int, peaks_per_angle: int, keep: int, penalty: float,
               free_reward: float, wanted: Optional[Callable[[np.ndarray], bool]], threads: int,
               angles: List[float], distinct_places: bool = False) -> List[Tuple[float, np.ndarray, float]]:
    """(score, transform i -> j between working pixels, angle) of the `keep` best peaks at `factor`, over the
    given angles, best first; with `distinct_places`, then the best peaks of the `keep` best places that those
    miss, best first."""
    ci, cj = coarse(pi, factor), coarse(pj, factor)
    hi, wi = ci.walls.shape
    hj, wj = cj.walls.shape
    diag = int(math.ceil(math.hypot(hi, wi)))
    shape = _fft_shape(diag + hj, diag + wj)
    # OpenCV's DFT in float32 (packed CCS spectra): a search 1.2-1.6 times faster than with numpy's FFT
    # score = correlation of i's walls and open floor with the terms of j they are weighed against
    fwj, foj = _spectrum(cj.walls, shape), _spectrum(cj.open, shape)
    against = (fwj - penalty * foj, free_reward * foj - penalty * fwj)
    k = np.array([[factor, 0.0, (factor - 1) / 2.0], [0.0, factor, (factor - 1) / 2.0], [0.0, 0.0, 1.0]])
    k_inv = np.linalg.inv(k)
    units = opposite_pairs(angles)

    def best_of(some: List[Tuple[float, Optional[float]]]) -> List[Tuple[float, np.ndarray, float]]:
        return _best_peaks(ci, against, shape, diag, some, peaks_per_angle, keep,
                           None if wanted is None else (lambda t: wanted(k @ t @ k_inv)), distinct_places)

    if threads > 1 and len(units) > 1:
        with ThreadPoolExecutor(max_workers=threads) as pool:
            parts = list(pool.map(best_of, [units[n::threads] for n in range(threads)]))
    else:
        parts = [best_of(units)]
    found = sorted((f for part, _ in parts for f in part), key=lambda st: st[0], reverse=True)[:keep]
    if distinct_places:
        places = Places(keep, ci)
        for _, best in parts:
            for peak in best:
                places.add(*peak)
        found += [p for p in places.best() if not any(p[1] is t for _, t, _ in found)]
    return [(score, k @ t @ k_inv, angle) for score, t, angle in found]


def _one_place(a: Sequence[float], b: Sequence[float]) -> bool:
    """Whether two peaks, each (x, y of grid i's centre on grid j in coarse pixels, angle), are one place seen at
    two neighbouring angles (coarser than verify.same_place, which compares two refined estimates)."""
    turn = abs((a[2] - b[2] + math.pi) % (2 * math.pi) - math.pi)
    return turn <= math.radians(PLACE_DEGREES) and math.hypot(a[0] - b[0], a[1] - b[1]) <= PLACE_PX


class Places:
    """The best `keep` distinct places among the peaks added, each by its best peak.

    One place scores high at several neighbouring angles, and the best `keep` peaks are often a few places, each
    several times: a map of a generated office (rooms every 8.5 m) had its true place ranked 11th, behind aliases
    at 8.5 and 17 m, each at two or three angles, and the search kept 8. Those peaks stay the search's first
    candidates (ICP from one of them can stop short of the minimum that another start of that place reaches); the
    places they miss come after them."""

    def __init__(self, keep: int, ci: CoarseGrid):
        hi, wi = ci.walls.shape
        self.keep, self.centre = keep, ((wi - 1) / 2.0, (hi - 1) / 2.0)
        self.items: List[list] = []   # [score, x, y, angle of its best peak, that peak], best first

    @property
    def floor(self) -> float:
        """The score a peak must beat to make a new place among the best `keep`."""
        return self.items[-1][0] if len(self.items) >= self.keep else -math.inf

    def add(self, score: float, t: np.ndarray, angle: float) -> bool:
        """Add a peak (coarse transform t of grid i onto grid j, at `angle`); whether it is now a place's best."""
        cx, cy = self.centre
        where = (t[0, 0] * cx + t[0, 1] * cy + t[0, 2], t[1, 0] * cx + t[1, 1] * cy + t[1, 2], angle)
        item = next((it for it in self.items if _one_place(it[1:4], where)), None)
        if item is None:
            if score <= self.floor:
                return False
            item = [score, *where, (score, t, angle)]
            self.items.append(item)
        elif score > item[0]:
            item[:] = [score, *where, (score, t, angle)]
        else:
            return False
        self.items.sort(key=lambda it: -it[0])
        del self.items[self.keep:]
        return any(it is item for it in self.items)

    def best(self) -> List[Tuple[float, np.ndarray, float]]:
        """The best peak of each place, best first."""
        return [it[4] for it in self.items]


def opposite_pairs(angles: Sequence[float]) -> List[Tuple[float, Optional[float]]]:
    """The angles as (angle, the angle half a turn from it or None): each pair is correlated from one turned image
    (see _best_peaks), each angle once, in the order of the first of each pair."""
    def key(angle: float) -> int:   # microradians in [0, 2 pi): an angle missed at a rounding edge goes alone
        return round(angle % (2 * math.pi) * 1e6)

    at: Dict[int, List[int]] = {}
    for n, angle in enumerate(angles):
        at.setdefault(key(angle), []).append(n)
    taken = [False] * len(angles)
    units: List[Tuple[float, Optional[float]]] = []
    for n, angle in enumerate(angles):
        if taken[n]:
            continue
        taken[n] = True
        partner = next((m for m in at.get(key(angle + math.pi), ()) if not taken[m]), None)
        if partner is not None:
            taken[partner] = True
        units.append((angle, None if partner is None else angles[partner]))
    return units


def _best_peaks(ci: CoarseGrid, against: Tuple[np.ndarray, np.ndarray], shape: Tuple[int, int], diag: int,
                units: Sequence[Tuple[float, Optional[float]]], peaks_per_angle: int, keep: int,
                wanted: Optional[Callable[[np.ndarray], bool]], distinct_places: bool = False
                ) -> Tuple[List[Tuple[float, np.ndarray, float]], List[Tuple[float, np.ndarray, float]]]:
    """(score, coarse transform i -> j, angle) of the best peaks over the angles of `units` (opposite_pairs):
    `peaks_per_angle` at most per angle, and all that can rank among the best `keep`; and with `distinct_places`
    the best peaks of the best `keep` places among them (Places; else none).

    Grid i turned half a turn further is the turned image mirrored through the canvas point (diag/2, diag/2) (the
    same source pixel lands there, but for a pixel here and there where nearest-neighbour rounding ties): its
    correlation with j at shift s is the convolution of the turned image with j at s + diag. So a pair of opposite
    angles takes two forward DFTs, not four (the 36 generated maps: 15 % less CPU with Debian's OpenCV 4.6, whose
    DFT is 3-4 times slower than the wheel's; 3 % with the wheel)."""
    hi, wi = ci.walls.shape
    centre = np.array([(wi - 1) / 2.0, (hi - 1) / 2.0])
    corner = diag + 1   # the turned grid's pixels lie within the top-left corner x corner of the canvas
    canvas = np.zeros(shape, np.float32)
    nonzero = zero_rows_hint(corner)
    found: List[Tuple[float, np.ndarray, float]] = []
    floor = -math.inf   # the keep-th best score found so far
    places = Places(keep, ci) if distinct_places else None

    def placement(angle: float) -> np.ndarray:
        # turn about the centre into the top-left corner of a zero canvas of the DFT's size
        c, s = math.cos(angle), math.sin(angle)
        m = np.array([[c, -s, 0.0], [s, c, 0.0]])
        m[:, 2] = diag / 2.0 - m[:, :2] @ centre
        return m

    def take(score: np.ndarray, m: np.ndarray, angle: float) -> None:
        nonlocal floor
        if len(found) >= keep:
            top = cv2.minMaxLoc(score)[1]
            if top <= floor and (places is None or top <= places.floor):
                return   # no peak of this angle can rank among the best `keep` (nor make a place among the best)
        # local maxima, best first
        peaks = (score == cv2.dilate(score, np.ones((5, 5), np.uint8))) & (score > 0)
        ys, xs = nonzero_2d(peaks)
        if ys.size == 0:
            return
        order = np.argsort(score[ys, xs])[::-1]
        taken = placed = 0
        for y, x in zip(ys[order], xs[order]):
            if places is not None and taken >= peaks_per_angle \
                    and (placed >= PLACE_PEAKS or score[y, x] <= places.floor):
                break   # the rest can make no place among the best either
            # circular correlation: shifts past half the size are negative
            dy = y - shape[0] if y > shape[0] - diag else y
            dx = x - shape[1] if x > shape[1] - diag else x
            t = np.eye(3)
            t[:2] = m
            t[:2, 2] += (dx, dy)
            if wanted is not None and not wanted(t):
                continue
            if taken < peaks_per_angle:
                found.append((float(score[y, x]), t, angle))
                taken += 1
            if places is not None and placed < PLACE_PEAKS and places.add(float(score[y, x]), t, angle):
                placed += 1
            if taken >= peaks_per_angle and (places is None or placed >= PLACE_PEAKS):
                break
        if taken and len(found) >= keep:
            floor = sorted((st[0] for st in found), reverse=True)[keep - 1]

    for angle, opposite in units:
        m = placement(angle)
        # warped into the corner alone, the rest of the canvas stays zero
        canvas[:corner, :corner] = cv2.warpAffine(ci.walls, m, (corner, corner), flags=cv2.INTER_NEAREST)
        if cv2.countNonZero(canvas[:corner, :corner]) < 5:
            continue   # the same pixels, mirrored, for the opposite angle
        wall_spectrum = cv2.dft(canvas, nonzeroRows=nonzero)
        canvas[:corner, :corner] = cv2.warpAffine(ci.open, m, (corner, corner), flags=cv2.INTER_NEAREST)
        open_spectrum = cv2.dft(canvas, nonzeroRows=nonzero)
        spectrum = cv2.mulSpectrums(against[0], wall_spectrum, 0, conjB=True)
        spectrum += cv2.mulSpectrums(against[1], open_spectrum, 0, conjB=True)
        take(cv2.idft(spectrum, flags=cv2.DFT_REAL_OUTPUT | cv2.DFT_SCALE), m, angle)
        if opposite is not None:
            spectrum = cv2.mulSpectrums(against[0], wall_spectrum, 0)
            spectrum += cv2.mulSpectrums(against[1], open_spectrum, 0)
            convolution = cv2.idft(spectrum, flags=cv2.DFT_REAL_OUTPUT | cv2.DFT_SCALE)
            take(np.roll(convolution, (-diag, -diag), axis=(0, 1)), placement(opposite), opposite)
    return found, places.best() if places is not None else []
