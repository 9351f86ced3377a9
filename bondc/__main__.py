"""``python -m bondc`` — the same as the ``bondc`` command."""

import sys

from bondc.cli import main

sys.exit(main())
