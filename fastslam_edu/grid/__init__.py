"""Grid SLAM: the log-odds occupancy grid, the grid particle filter with scan matching, THOR's geometry."""
