"""`python -m jaxsr.cli ...`: the `jaxsr` command without the console script (as experiments/studies/startup.py
runs it)."""

import sys

from . import main

sys.exit(main())
