"""`python -m memora_graph.cli ...` runs the `memora` command."""

import sys

from memora_graph.cli import main

sys.exit(main())
