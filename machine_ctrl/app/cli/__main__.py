"""``python -m machine_ctrl.app.cli``: the same as the console script ``machine-ctrl``."""
import sys

from machine_ctrl.app.cli import main

sys.exit(main())
