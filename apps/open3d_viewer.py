"""Run primkit's Open3D viewer (one mesh or point cloud, its parts and cuboids in Open3D's window)
from a checkout:

    python apps/open3d_viewer.py SHAPE --model chair [--export DIR] [--png PATH ...]

the same as ``primkit view open3d ...``: the viewer itself is :mod:`primkit.viewers.open3d_viewer`,
installed with the package.
"""

import sys

from primkit.cli import main

if __name__ == "__main__":
    sys.exit(main(["view", "open3d", *sys.argv[1:]]))
