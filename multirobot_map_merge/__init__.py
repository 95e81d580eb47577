"""multirobot_map_merge: Python (rospy) map merging for multiple robots."""
# Also find the catkin-generated `multirobot_map_merge.msg` (in .ws/devel) when this source
# package is imported first (e.g. with the repo root on sys.path under `python -m pytest`).
__path__ = __import__('pkgutil').extend_path(__path__, __name__)
