"""Landmark SLAM: FastSLAM 1.0 (the per-particle step and the run), FastSLAM 2.0's proposal, Montemerlo's landmark tree, the least-squares smoother, the initial pose from landmarks."""
