"""The ROS side of map merging: the map_merge node and what only it and bag input need (parameters, message
conversions, robot discovery, the stored robot maps). Everything else in the package imports no rospy."""
