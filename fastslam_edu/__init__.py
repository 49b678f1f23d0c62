"""fastslam_edu: particle-filter SLAM, one concept per module, in layers, for teaching.

One name per function, and one suffix rule for a concept written twice. The teaching form (numpy, checked
inputs, what a notebook calls) carries the concept's plain name: ``update_landmark``, ``wrap_angle``,
``tempering_exponents``. Its compiled twin (numba: one particle or one landmark, loops, often writing into arrays
it is given) carries the same name plus ``_kernel``: ``update_landmark_kernel``, ``wrap_angle_kernel``,
``tempering_exponents_kernel``. A compiled function with no teaching twin keeps a plain name (``update_particle``,
``run_segments``); a second numpy form of a concept is named for its own job (``update_landmark_textbook``,
``improved_pose_information_form``), never with a twin's suffix. ``tests/test_vocabulary.py`` checks the rule.

core            the building blocks
    angles          wrapping angles to (-pi, pi]
    se2             SE(2) poses: compose, inverse, relative; poses interpolated in time; least-squares alignment
    motion          the unicycle motion model, sampled for M particles (noise per sqrt(s)); dead reckoning
    measurement     the range-bearing model h, its inverse and Jacobians
    ekf             one 2x2 EKF per landmark per particle (the compiled update, and the textbook one)
    weights         log importance weights, normalisation, effective sample size
    resampling      roulette (multinomial), systematic, stratified and residual resampling
    params          parameter sets: immutable, comparable, copied and serialised one way

datasets        data in, data made (imports no mapping or evaluation code)
    log, mrclam     the MR.CLAM reader and its tables; events: the filter's event stream
    numeric_table   a text table of numbers read with every row checked (errors name the file and the line)
    laser           laser logs (CARMEN, Intel JSON, relations)
    thor_lidar      THOR's .mat files: LiDAR scans and joint angles, read and written
    registry, fetch pinned sources, downloads and checks (`fastslam-edu data`)
    sim             a simulated landmark world and robot (known truth, for tests)
    sim_laser       a simulated laser world: a floor plan, ray casting, noisy odometry (known truth, for tests)
    thor_geometry   THOR's LiDAR -> head -> body -> world geometry, the joint sample of each scan
    floor_plan      a building of walls and floor, and 3D rays cast in it (the simulated THOR's world)
    thor_sim        a simulated THOR sequence driven by a real joint log

landmark        landmark SLAM
    fastslam_step   one FastSLAM 1.0 step per particle, as Probabilistic Robotics table 13.1 reads, and the
                    run over a log, compiled (numba)
    step_records    the named tuples the compiled step takes and writes (particles, sightings, log, settings, record)
    particle_set    the particle set and the four steps on it: propagate, update, resample, combine
    particle_resampling  step 3 compiled: the particles drawn, the set replaced in place (both runs)
    fastslam        the filter's settings and the run over a log (compiled, or step by step for hooks)
    proposal_strategies  how step 1 moves the particles in the run: the motion model, FastSLAM 2.0, known poses
    hooks           code run alongside the filter: a kidnap, a monitor, the progress bar
    gate            the outlier gate and its escape
    evidence        the fraction beta of independent evidence in sightings close in time
    segments        the log cut into runs of odometry steps that end at a measurement step
    proposal        FastSLAM 2.0's proposal: the pose sampled given the sighting
    tree            Montemerlo's persistent balanced tree of landmark filters
    fastslam_tree   the filter with tree-backed maps (O(M log N) resampling)
    ekf_slam        EKF-SLAM: the joint Gaussian over pose and map (the baseline); barcodes known or not
    ekf_slam_steps  its state and table 10.1's steps: prediction, a new landmark, the update (Joseph form)
    ekf_slam_association  table 10.2: Mahalanobis distances, nearest neighbour or the assignment, new landmarks
    association     FastSLAM with unknown correspondences: per-particle maximum likelihood, new landmarks, negative evidence
    association_params  its settings, as the kernels take them, and the particle set with variable-size maps
    association_likelihood  the likelihood of a sighting given a landmark, with the pose's drift; p0 of a new one
    joint_compatibility  the sightings of one instant decided together
    landmark_existence  adding, removing and retiring landmarks: negative evidence, the hand-over of identities
    association_history  the best particle's association history through its ancestors, merging copies
    smoother        least squares over the whole log: the most probable path and map under the same model
    smoother_factors  its factors: keyframes, dead reckoning, odometry and sightings, residuals and Jacobians
    smoother_laplace  its Laplace approximation: the covariances of poses and landmarks at the solution
    initial_pose    the start pose from the first sightings of surveyed landmarks (robots without groundtruth)

grid            grid SLAM
    occupancy       log-odds occupancy grid, its update along the rays of a scan, map correlation
    rays            the cells a beam crosses: Bresenham's line, and its closed form for a whole scan
    gridslam        particle-filter SLAM with a grid (the THOR write-up's algorithm and variants)
    motion          the grid filter's motion: the odometry increment, noise scaled to it
    scan_matching   map correlation (the weight) and hill-climbing scan matching
    thor            THOR's returns: range and floor filtering, the planar laser log
    thor_slam       grid SLAM on a THOR log: planar scans (floor filter on or off), maps and their scores

evaluation      measuring results
    metrics         landmark and trajectory errors, absolute and aligned
    relations       Kuemmerle et al. relation errors
    consistency     NEES: is the filter's reported uncertainty honest (the particle cloud's covariance)
    noise_estimation  the sensor (measurement) and odometry (motion) noise, measured against groundtruth
                      (groundtruth: glitches and gaps; robust: the scaled MAD)
    audit           the MR.CLAM landmark table checked against the sightings
    association     scoring data association: map matched to the survey, accuracy, the oracle bound
    registration    the rigid motion that lays a map without names on the survey (a consensus, for the matching)

app             the application
    experiment      one MR.CLAM run end to end (load, audit, run, score)
    plotting        figures of a run
    cli             the ``fastslam-edu`` command
    diagrams        the lecture figures: the factorisation, a particle, one filter step
    course          the chapter map and the course paths
    widgets         sliders on a figure (JupyterLab), the default figure in the static book
"""

__version__ = "0.1.0"
