"""``python3 -m experiments.cli``: the ``scene-estimator`` command."""
import sys

from experiments.cli import main

sys.exit(main())
