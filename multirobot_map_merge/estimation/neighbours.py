"""The two nearest descriptors of each keypoint among a union's, from its nearest among each member's, kept.

A union's keypoints are its members' own, pooled (features.pooled_keypoints), and the growth matches a grid against
a union again each time the union grows: its distances to the members that were there already are the same. So the
K nearest of every keypoint of one descriptor array among another's are computed once (NeighbourCache, one per
estimation) and the two nearest among a union follow from them. Exactly: a member whose K nearest hold fewer than
two of the keypoints the union took from it bounds the distance of the rest from below by its K-th, and a keypoint
whose second nearest so far is not within every such bound is matched against the whole union again. On the
generated 36-map buildings the descriptor distances were 6-14 % of an estimation's work (serial, under cProfile).
"""
from __future__ import annotations

import threading
from typing import Dict, List, Optional, Sequence, Tuple

import cv2
import numpy as np

K = 4   # nearest kept per keypoint and member

# (descriptors of a grid, the rows of it that a union took, in the union's order): a single grid is one part, all rows
Parts = Sequence[Tuple[np.ndarray, np.ndarray]]


class NeighbourCache:
    """The K nearest descriptors (Hamming) of one array's rows among another's, per pair of arrays; thread safe."""

    def __init__(self) -> None:
        self._items: Dict[Tuple[int, int], tuple] = {}
        self._lock = threading.Lock()

    def key(self, query: np.ndarray, train: np.ndarray) -> tuple:
        return id(query), id(train)

    def nearest(self, query: np.ndarray, train: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """(distances, indices), each (len(query), min(K, len(train))), nearest first."""
        key = self.key(query, train)
        with self._lock:
            hit = self._items.get(key)
        if hit is not None:
            return hit[2], hit[3]
        distance, index = self.computed(key, query, train)
        with self._lock:
            # the arrays are kept with their result: their ids are not reused while the entry lives
            self._items[key] = (query, train, distance, index)
        return distance, index

    def computed(self, key: tuple, query: np.ndarray, train: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """The distances of a pair not kept here (`key`: its key here): computed (or taken from another process,
        workers.py)."""
        return cv2.batchDistance(query, train, cv2.CV_32S, normType=cv2.NORM_HAMMING, K=min(K, len(train)))


def parts_of(descriptors: np.ndarray, parts: Optional[Parts]) -> Parts:
    return parts if parts is not None else [(descriptors, np.arange(len(descriptors)))]


def two_nearest(query: np.ndarray, query_parts: Parts, train: np.ndarray, train_parts: Parts,
                cache: NeighbourCache) -> Tuple[np.ndarray, np.ndarray]:
    """(distances (N, 2), nearest index (N,)) of each row of `query` among the rows of `train`, as
    cv2.batchDistance(query, train, K=2) finds them, where both are pooled from the rows of their parts."""
    out_d, out_i = [], []
    for q, q_rows in query_parts:
        n = len(q_rows)
        rows = np.arange(n)
        best, second = np.full(n, np.inf), np.full(n, np.inf)
        best_i = np.full(n, -1, np.int64)
        bound = np.full(n, np.inf)   # below this, no row of train left unseen is nearer
        offset = 0
        for t, t_rows in train_parts:
            position = np.full(len(t), -1, np.int64)
            position[t_rows] = offset + np.arange(len(t_rows))
            offset += len(t_rows)
            distance, index = cache.nearest(q, t)
            distance, at = distance[q_rows].astype(np.float64), position[index[q_rows]]
            taken = at >= 0
            count = np.cumsum(taken, axis=1)
            found = count[:, -1]
            first, then = np.argmax(taken, axis=1), np.argmax(taken & (count == 2), axis=1)
            d1 = np.where(found >= 1, distance[rows, first], np.inf)
            d2 = np.where(found >= 2, distance[rows, then], np.inf)
            unseen = (found < 2) & (distance.shape[1] < len(t)) & (found < len(t_rows))
            bound = np.where(unseen, np.minimum(bound, distance[:, -1]), bound)
            nearer = d1 < best
            second = np.where(nearer, np.minimum(best, d2), np.minimum(second, d1))
            best_i = np.where(nearer, at[rows, first], best_i)
            best = np.where(nearer, d1, best)
        distance = np.column_stack([best, second])
        again = np.flatnonzero(second > bound)
        if again.size:
            d, i = cv2.batchDistance(q[q_rows[again]], train, cv2.CV_32S, normType=cv2.NORM_HAMMING, K=2)
            distance[again], best_i[again] = d, i[:, 0]
        out_d.append(distance)
        out_i.append(best_i)
    return np.concatenate(out_d).astype(np.float32), np.concatenate(out_i)
