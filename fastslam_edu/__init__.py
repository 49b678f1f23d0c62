"""fastslam_edu: particle-filter SLAM, one concept per module, for teaching.

Modules
-------
datasets      reading MR.CLAM and LiDAR logs, the event stream, downloads
sim           a simulated landmark world and robot (known truth, for tests)
angles        wrapping angles to (-pi, pi]
motion        the unicycle motion model, sampled for M particles
measurement   the range-bearing model h, its inverse and Jacobians
ekf           one 2x2 EKF per landmark per particle: initialise and update
weights       log importance weights, normalisation, effective sample size
resampling    multinomial, systematic, stratified and residual resampling
metrics       landmark and trajectory errors against groundtruth
"""

__version__ = "0.1.0"
