"""The application: one MR.CLAM experiment end to end, figures, the ``fastslam-edu`` command."""
