"""ROS-free numerical core (numpy, scipy, numba): models, filters, estimators, simulator, faults."""
