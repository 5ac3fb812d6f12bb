"""``python -m motionbase ARGS``: the same as the ``motionbase`` command."""

import sys

from motionbase.cli import main

sys.exit(main())
