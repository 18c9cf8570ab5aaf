"""Import of a lab's ROS 1 / ROS 2 bags as per-action recordings."""
