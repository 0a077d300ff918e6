"""Run primkit's abstraction viewer (one shape and its cuboids) from a checkout:

    python apps/abstraction_viewer.py SHAPE --model chair [--png PATH ...]

the same as ``primkit view abstraction ...``: the viewer itself is
:mod:`primkit.viewers.abstraction_viewer`, installed with the package.
"""

import sys

from primkit.cli import main

if __name__ == "__main__":
    sys.exit(main(["view", "abstraction", *sys.argv[1:]]))
