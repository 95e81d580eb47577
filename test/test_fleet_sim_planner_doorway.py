"""fleet_sim's planner: a robot standing in a doorway its own map draws narrower than robot_radius + margin on
each side still gets out (the retry with the robot's radius alone), and a closed room stays closed."""
import numpy as np

from fleet_sim.planner import PlannerConfig, plan_path

RES = 0.05


def two_rooms(door_cells: int) -> np.ndarray:
    """Two free rooms (4 m x 3 m each) side by side, a wall of 2 cells between them with a door of door_cells."""
    v = np.zeros((60, 162), np.int8)
    v[[0, -1], :] = 100
    v[:, [0, -1]] = 100
    v[:, 80:82] = 100
    mid = 30
    v[mid - door_cells // 2: mid - door_cells // 2 + door_cells, 80:82] = 0
    return v


def test_robot_in_a_tight_doorway_gets_out():
    cfg = PlannerConfig()                       # lethal within robot_radius + margin = 0.25 m of a wall
    v = two_rooms(11)                           # 0.55 m: the middle of the door is clear of the margin
    v[[25, 35], 76] = v[[25, 35], 85] = 100    # specks of noise in front of both mouths close them to the margin
    in_door = (81 * RES, 30 * RES)
    assert plan_path(v, RES, (0.0, 0.0), in_door, (1.0, 1.5), PlannerConfig(margin=0.0)).path is not None
    result = plan_path(v, RES, (0.0, 0.0), in_door, (1.0, 1.5), cfg)
    assert result.path is not None and np.allclose(result.path[-1], (1.0, 1.5))
    # every point of the way keeps the robot's radius from the walls' cell centres
    walls = np.argwhere(v >= 50)[:, ::-1] * RES + RES / 2
    d = np.min(np.hypot(*(result.path[:, None, :] - walls[None, :, :]).transpose(2, 0, 1)), axis=1)
    assert d.min() >= cfg.robot_radius - RES


def test_a_closed_room_is_still_refused():
    v = two_rooms(0)
    result = plan_path(v, RES, (0.0, 0.0), (1.0, 1.5), (6.0, 1.5), PlannerConfig())
    assert result.path is None and result.reason == 'no path to the goal'
