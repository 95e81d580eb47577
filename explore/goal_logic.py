"""explore_lite's goal selection (explore.md §6–§8), without ROS and without clocks (time is passed in).

The node calls ``GoalLogic.plan(frontiers, resolution, now)`` on every planning tick and acts on the result
(send a goal, keep the current one, or stop), and ``on_goal_done(status, target)`` from the action's done callback.
"""
from __future__ import annotations

import enum
import logging
import math
import threading
from dataclasses import dataclass, field, replace
from typing import Any, List, Optional, Sequence, Tuple

from .frontier_search import Frontier

_log = logging.getLogger('rosout.' + __name__)

Point2 = Tuple[float, float]

# actionlib_msgs/GoalStatus values (no ROS import in the core).
PREEMPTED = 2
SUCCEEDED = 3
ABORTED = 4

# The original's blacklist radius: a square of ±5 cells (strict) around each blacklisted point.
BLACKLIST_TOLERANCE_CELLS = 5
# The original's "same goal" test: xy distance below 1 cm.
SAME_GOAL_DISTANCE = 0.01


def same_point(a: Sequence[float], b: Sequence[float]) -> bool:
    """The original's ``operator==`` on points: distance in the xy plane < 0.01 m (z ignored)."""
    dx, dy = a[0] - b[0], a[1] - b[1]
    return math.sqrt(dx * dx + dy * dy) < SAME_GOAL_DISTANCE


def on_blacklist(point: Sequence[float], blacklist: Sequence[Sequence[float]], resolution: float) -> bool:
    """True if ``point`` is strictly within ±5 cells in both x and y of a blacklisted point."""
    tol = BLACKLIST_TOLERANCE_CELLS * resolution
    return any(abs(point[0] - b[0]) < tol and abs(point[1] - b[1]) < tol for b in blacklist)


@dataclass
class _AreaProgress:
    """How the pursuit of one goal area went: the nearest the robot got and how long it has been pursued since."""
    point: Point2          # the latest goal in the area (the frontier's centroid drifts as the map grows)
    best_distance: float   # the smallest min_distance seen while it was the goal
    stalled: float         # seconds pursued (as the goal) without getting nearer than best_distance
    seen: float            # time of the latest plan that chose it


class PlanAction(enum.Enum):
    SEND_GOAL = 'send_goal'  # send ``target`` to the navigation action (it replaces the previous goal)
    KEEP_GOAL = 'keep_goal'  # same goal as last time: send nothing
    WAIT = 'wait'            # every frontier is blacklisted but teammates still explore: cancel the goal, plan on
    STOP = 'stop'            # exploration ended: cancel goals and stop the timer (then ``return_target`` if set)


@dataclass
class PlanResult:
    action: PlanAction
    target: Optional[Point2] = None          # goal position (orientation is always identity, as the original)
    frontier: Optional[Frontier] = None      # the chosen frontier
    reason: str = ''                         # STOP: 'no_frontiers' or 'all_blacklisted'
    blacklisted: List[Point2] = field(default_factory=list)  # goals blacklisted by the progress timeout here
    return_target: Any = None                # STOP with return_to_init: the initial pose to drive back to


class GoalLogic:
    """Goal selection state: blacklist, previous goal, progress tracking. Thread-safe (the done callback of the
    action runs in another thread than planning; the original races here, this port locks)."""

    def __init__(self, progress_timeout: float, return_to_init: bool = False) -> None:
        self.progress_timeout = progress_timeout
        self.return_to_init = return_to_init
        self._lock = threading.RLock()
        self._blacklist: List[Point2] = []
        # None instead of the original's (0,0,0): a first target within 1 cm of the origin is not "the same goal"
        # (the original would blacklist it at once).
        self._prev_goal: Optional[Point2] = None
        # Progress per goal area, remembered while the area was a goal within the last progress_timeout: a robot
        # that switches back and forth between two goals resumes each one's clock instead of restarting it.
        self._areas: List[_AreaProgress] = []
        self._prev_area: Optional[_AreaProgress] = None
        self._resuming = False
        self._initial_pose: Any = None
        self._returned = False

    @property
    def blacklist(self) -> List[Point2]:
        with self._lock:
            return list(self._blacklist)

    def add_to_blacklist(self, point: Sequence[float]) -> None:
        with self._lock:
            self._blacklist.append((float(point[0]), float(point[1])))
        _log.debug("Adding current goal to black list")

    def is_blacklisted(self, point: Sequence[float], resolution: float) -> bool:
        with self._lock:
            return on_blacklist(point, self._blacklist, resolution)

    def set_initial_pose(self, pose: Any) -> None:
        """Remember the start pose (opaque; handed back in ``PlanResult.return_target``) for return_to_init."""
        with self._lock:
            self._initial_pose = pose

    def resume(self) -> None:
        """As the ROS 2 port's resume: the next plan skips the progress-timeout check once."""
        with self._lock:
            self._resuming = True

    def forget_goal(self) -> None:
        """The current goal was cancelled (pause or stop): the next plan sends its goal even if it is the same one,
        instead of keeping a goal nobody pursues any more."""
        with self._lock:
            self._prev_goal = None
            self._prev_area = None

    @property
    def returning_home(self) -> bool:
        """True after a STOP carried ``return_target``, until a new exploration goal is sent."""
        with self._lock:
            return self._returned

    def select(self, frontiers: Sequence[Frontier], resolution: float) -> Optional[Frontier]:
        """First frontier (cost order) whose centroid is not blacklisted, or None."""
        with self._lock:
            for f in frontiers:
                if not on_blacklist(f.centroid, self._blacklist, resolution):
                    return f
        return None

    def plan(self, frontiers: Sequence[Frontier], resolution: float, now: float,
             team_busy: bool = False) -> PlanResult:
        """One planning cycle (makePlan) over frontiers sorted by cost; ``now`` in seconds. ``team_busy``: a
        teammate still pursues a goal, so when every frontier is blacklisted the robot WAITs (the team map will
        show new frontiers) instead of stopping for good."""
        with self._lock:
            _log.debug("found %d frontiers", len(frontiers))
            for i, f in enumerate(frontiers):
                _log.debug("frontier %d cost: %f", i, f.cost)
            blacklisted: List[Point2] = []
            # The original recurses (re-plans) after blacklisting a timed-out goal; the next round picks another
            # frontier, which normally is a new goal. Each round blacklists one more goal, so the loop ends.
            while True:
                if not frontiers:
                    return self._stop('no_frontiers', blacklisted)
                frontier = self.select(frontiers, resolution)
                if frontier is None:
                    if team_busy:
                        self._prev_goal, self._prev_area = None, None
                        return PlanResult(PlanAction.WAIT, reason='all_blacklisted', blacklisted=blacklisted)
                    return self._stop('all_blacklisted', blacklisted)
                target = frontier.centroid
                same_goal = self._prev_goal is not None and same_point(self._prev_goal, target)
                self._prev_goal = target
                area = self._progress_in(target, frontier.min_distance, now, resolution)
                if area.stalled > self.progress_timeout and not self._resuming:
                    self.add_to_blacklist(target)
                    # the other areas' clocks start afresh: with this goal gone, the one it kept the robot
                    # switching to is pursued alone now and may well be reached
                    self._areas, self._prev_area = [], None
                    blacklisted.append(target)
                    continue
                self._resuming = False
                if same_goal:
                    return PlanResult(PlanAction.KEEP_GOAL, target, frontier, blacklisted=blacklisted)
                self._returned = False
                return PlanResult(PlanAction.SEND_GOAL, target, frontier, blacklisted=blacklisted)

    def _progress_in(self, target: Point2, distance: float, now: float, resolution: float) -> _AreaProgress:
        """Update and return the progress record of the goal area of ``target`` (a new one for a new area).

        Progress is judged per goal area (the blacklist square), not per exact point: map noise moves a frontier's
        centroid by more than 1 cm from plan to plan, and the original then restarts the timeout every time and may
        retry an unreachable frontier forever. For the same reason the clock of an area runs on (it pauses while
        another goal is pursued) when the robot returns to it within progress_timeout, instead of restarting.
        """
        prev = self._prev_area
        if prev is not None:   # pursued since the last plan (the clock of every other area is paused)
            prev.stalled += max(0.0, now - prev.seen)
            prev.seen = now
        self._areas = [a for a in self._areas if now - a.seen <= self.progress_timeout]
        area = prev if prev is not None and on_blacklist(target, [prev.point], resolution) else None
        if area is None:
            area = next((a for a in self._areas if on_blacklist(target, [a.point], resolution)), None)
        if area is None:
            area = _AreaProgress(target, distance, 0.0, now)
            self._areas.append(area)
        area.point, area.seen = target, now
        if distance < area.best_distance:    # got nearer: progress
            area.best_distance, area.stalled = distance, 0.0
        self._prev_area = area
        return area

    def _stop(self, reason: str, blacklisted: List[Point2]) -> PlanResult:
        self._resuming = False
        ret = None
        # Drive home once per end of exploration; a later STOP (e.g. after the return goal completes) does not.
        if self.return_to_init and self._initial_pose is not None and not self._returned:
            ret = self._initial_pose
            self._returned = True
        return PlanResult(PlanAction.STOP, reason=reason, blacklisted=blacklisted, return_target=ret)

    def on_goal_done(self, status: int, target: Optional[Sequence[float]]) -> bool:
        """Done callback of an exploration goal (``target`` captured when it was sent): ABORTED blacklists the
        target. Returns True: the original replans at once after every terminal status."""
        _log.debug("Reached goal with status: %s", status)
        if status == ABORTED and target is not None:
            self.add_to_blacklist(target)
        return True


def apply_team_penalty(frontiers: Sequence[Frontier], team_goals: Sequence[Sequence[float]],
                       team_radius: float, heading: Optional[Sequence[float]] = None,
                       team_distances: Optional[Sequence[float]] = None) -> List[Frontier]:
    """Demote frontiers whose centroid is within ``team_radius`` (strict) of another robot's current goal, and
    those a teammate will reach first: the teammate will be there first, so a far frontier is left to the robot
    nearest to it. Who is first, per teammate goal ``g``:

    - with the teammate's remaining distance to ``g`` (``team_distances``, inf: unknown) and the frontier's
      distance from this robot (``min_distance``): the teammate if its remaining distance plus DETOUR times the
      straight line from ``g`` to the centroid is shorter. This robot's own distance, not its goal, counts: a robot
      that chose a far goal must not keep the frontiers there from a teammate standing next to them;
    - else, with ``heading`` (this robot's own goal, or its position when it has none): the teammate if the centroid
      is nearer (straight line) to ``g`` than to ``heading``. Goals are compared with goals so that two robots agree
      which of them a frontier is left to (comparing a teammate's goal with one's own position, both could leave
      it to the other).

    Formula: a penalised frontier gets ``cost + P`` with ``P = (max − min of the finite costs) + 1``, so each
    penalised cost is above every unpenalised finite cost. The result is re-sorted (stable) in three tiers: the
    unpenalised frontiers in cost order (NaN last), then those left to a teammate by distance only, then those
    within ``team_radius`` of a teammate's goal, both demoted tiers nearest first (``min_distance``). A robot
    therefore goes where a teammate is heading only when every other frontier is gone or blacklisted, and then
    helps nearby rather than crossing the building for a large frontier a teammate already works on.
    No team goals: the input order, unchanged. ``team_goals`` must be in the frontiers' frame and exclude this
    robot's own goal.
    """
    if not team_goals or not frontiers:
        return list(frontiers)
    distances = list(team_distances) if team_distances is not None else [math.inf] * len(team_goals)
    finite = [f.cost for f in frontiers if math.isfinite(f.cost)]
    penalty = (max(finite) - min(finite) + 1.0) if finite else 1.0
    keyed = []
    for f in frontiers:
        own = 0.0 if heading is None else _dist(f.centroid, heading)
        at_goal = any(_dist(f.centroid, g) < team_radius for g in team_goals)
        if at_goal or any(_left_to(f, g, d, own) for g, d in zip(team_goals, distances)):
            tier = 2 if at_goal else 1
            keyed.append(((tier, (math.isnan(f.cost), f.min_distance)), replace(f, cost=f.cost + penalty)))
        else:
            keyed.append(((0, (math.isnan(f.cost), f.cost)), f))
    keyed.sort(key=lambda kv: kv[0])
    return [g for _, g in keyed]


# A teammate's way from its goal to a frontier is estimated by the straight line times this factor: this robot's
# own distance (min_distance) runs along the map, round walls and through doors, and a bare straight line would
# leave to a teammate frontiers that it reaches later than this robot (a robot then crosses the building instead).
DETOUR = 1.4


def _dist(a: Sequence[float], b: Sequence[float]) -> float:
    return math.hypot(a[0] - b[0], a[1] - b[1])


def _left_to(f: Frontier, goal: Sequence[float], remaining: float, own_heading: float) -> bool:
    """True if frontier ``f``, beyond ``team_radius`` of ``goal``, is left to the teammate heading for ``goal``
    (see apply_team_penalty)."""
    to_goal = _dist(f.centroid, goal)
    if math.isfinite(remaining) and math.isfinite(f.min_distance):
        return remaining + DETOUR * to_goal < f.min_distance
    return to_goal < own_heading
