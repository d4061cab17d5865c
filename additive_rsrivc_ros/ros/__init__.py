"""ROS 2 shell helpers of the monitor node: input synchronization (ROS-free) and message conversion."""
