"""Run primkit's collection viewer (a collection in one grid, parts coloured alike) from a checkout:

    python apps/collection_browser.py FOLDER --model chair [--png PATH ...]

the same as ``primkit view collection ...``: the viewer itself is
:mod:`primkit.viewers.collection_browser`, installed with the package.
"""

import sys

from primkit.cli import main

if __name__ == "__main__":
    sys.exit(main(["view", "collection", *sys.argv[1:]]))
