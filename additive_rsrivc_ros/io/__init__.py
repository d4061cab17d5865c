"""Records in and out: rosbag2 reading and writing, block-topic bags, time ranges."""
