"""``python -m ipc_taichi.cli``: the same as the ``ipc-taichi`` script."""

import sys

from . import main

sys.exit(main())
