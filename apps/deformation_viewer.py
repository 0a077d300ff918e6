"""Run primkit's deformation viewer (deformation transfer and part edits, live) from a checkout:

    python apps/deformation_viewer.py SOURCE TARGET --model chair [--png PATH ...]

the same as ``primkit view deformation ...``: the viewer itself is
:mod:`primkit.viewers.deformation_viewer`, installed with the package.
"""

import sys

from primkit.cli import main

if __name__ == "__main__":
    sys.exit(main(["view", "deformation", *sys.argv[1:]]))
