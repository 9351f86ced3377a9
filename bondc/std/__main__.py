"""``python -m bondc.std``: print docs/components.md."""

import sys

from bondc.std import describe

sys.stdout.write(describe())
