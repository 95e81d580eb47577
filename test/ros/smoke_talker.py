#!/usr/bin/env python3
"""Publishes one latched 4x3 nav_msgs/OccupancyGrid on `map` and spins (helper for smoke.test)."""
import rospy
from nav_msgs.msg import OccupancyGrid


def main():
    rospy.init_node("smoke_talker")
    pub = rospy.Publisher("map", OccupancyGrid, queue_size=1, latch=True)
    grid = OccupancyGrid()
    grid.header.stamp = rospy.Time.now()
    grid.header.frame_id = "smoke_map"
    grid.info.resolution = 0.05
    grid.info.width, grid.info.height = 4, 3
    grid.info.origin.orientation.w = 1.0
    grid.data = [-1, 0, 100, 0] * 3
    pub.publish(grid)
    rospy.spin()


if __name__ == "__main__":
    main()
