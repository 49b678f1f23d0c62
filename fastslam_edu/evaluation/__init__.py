"""Measuring results: errors against groundtruth, relation errors, consistency (NEES), the noise of sensors and odometry, the landmark-table audit."""
