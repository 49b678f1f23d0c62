"""The building blocks: angles, SE(2) poses, the motion and measurement models, the landmark EKF, importance weights, resampling, parameter sets."""
