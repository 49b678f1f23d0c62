"""fastslam_edu: particle-filter SLAM, one concept per module, for teaching.

Data
    datasets        MR.CLAM reader, the filter's event stream, landmark-table audit, downloads,
                    laser logs (CARMEN, Intel JSON, relations, THOR .mat)
    sim             simulated landmark world and robot; simulated laser world (known truth, for tests)
    thor_sim        a simulated THOR sequence driven by a real joint log
    noise_estimation  measuring the sensor and odometry noise against groundtruth

Landmark SLAM (FastSLAM 1.0)
    angles          wrapping angles to (-pi, pi]
    motion          the unicycle motion model, sampled for M particles (noise per sqrt(s))
    measurement     the range-bearing model h, its inverse and Jacobians
    ekf             one 2x2 EKF per landmark per particle: initialise and update
    weights         log importance weights, normalisation, effective sample size
    resampling      multinomial, systematic, stratified and residual resampling
    fastslam_step   one filter step per particle as Probabilistic Robotics table 13.1 reads (compiled, numba)
    fastslam        the particle set, resampling, combining, and the run over a log (hooks, gate, proposals)
    proposal        FastSLAM 2.0's proposal: the pose sampled given the sighting (an engine option)
    landmark_tree   Montemerlo's persistent balanced tree of landmark filters
    fastslam_tree   the filter with tree-backed maps (O(M log K) resampling)
    smoother        least squares over the whole log: the most probable path and map under the same model
    metrics         landmark and trajectory errors, SE(2) alignment
    consistency     NEES: is the filter's reported uncertainty honest (the particle cloud's covariance)
    initial_pose    the start pose from the first sightings of surveyed landmarks (robots without groundtruth)
    experiment      one MR.CLAM run end to end (load, audit, run, score)
    plotting        figures of a run

Grid SLAM
    se2             SE(2) poses: compose, inverse, relative
    grid            log-odds occupancy grid, Bresenham and vectorised ray casting
    thor            THOR's LiDAR -> head -> body -> world geometry, floor filtering
    gridslam        particle-filter SLAM with a grid (the THOR write-up's algorithm and variants)
    relations       Kuemmerle et al. relation errors

cli                 the ``fastslam-edu`` command
"""

__version__ = "0.1.0"
