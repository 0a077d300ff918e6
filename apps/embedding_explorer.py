"""Run primkit's embedding viewer (the t-SNE map of a collection, with each shape's nearest neighbours) from a checkout:

    python apps/embedding_explorer.py FOLDER --model chair [--png PATH ...]

the same as ``primkit view embedding ...``: the viewer itself is
:mod:`primkit.viewers.embedding_explorer`, installed with the package.
"""

import sys

from primkit.cli import main

if __name__ == "__main__":
    sys.exit(main(["view", "embedding", *sys.argv[1:]]))
