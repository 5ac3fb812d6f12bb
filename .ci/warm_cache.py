"""Fill numba's on-disk cache before the tests, as a user's first run does: the two test
workers, and the command-line processes the tests start, then load the compiled kernels
instead of each compiling the same ones on a cold cache (about a minute of compiling).

Run: python .ci/warm_cache.py
"""

from motionbase import app
from motionbase.pipeline import Pipeline

for kwargs in ({}, {"platform": "stewart6"}, {"planar": True}, {"cueing": "mpc"}):
    Pipeline(app.load_config(**kwargs))
