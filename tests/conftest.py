"""Test configuration: property tests (hypothesis) are derandomised, so every run draws the same examples.

A test run that passes once passes again: the examples are a fixed function of the test, like a
fixed seed. Set HYPOTHESIS_PROFILE=explore to search with fresh random examples instead.
"""

import os

from hypothesis import settings

settings.register_profile("fixed", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "fixed"))
