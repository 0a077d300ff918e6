#!/usr/bin/env bash
# Set up primkit on a fresh Debian machine: system libraries, a virtual environment in .venv,
# and primkit itself (editable) with the pinned versions of constraints.txt.
# Safe to run again: each step is skipped when already done.
set -euo pipefail
cd "$(dirname "$0")/.."

# open3d needs libusb and the GL/EGL loaders; pyvista renders off screen through EGL.
# xvfb + xauth: real windows for the viewers (xvfb-run) and their window test; chromium: the
# headless-browser check of `primkit report` pages; libvulkan1 + mesa-vulkan-drivers: Open3D's window
# (`primkit view open3d`) renders through Vulkan, on the CPU where there is no GPU. paraview +
# python3-paraview: Debian's ParaView (5.11, its own VTK 9.2) for the plugin's test (tests/plugins/test_paraview.py).
need=()
for pkg in libgl1 libegl1 libopengl0 libusb-1.0-0 libfontconfig1 libgomp1 xvfb xauth chromium libvulkan1 mesa-vulkan-drivers paraview python3-paraview; do
  dpkg -s "$pkg" >/dev/null 2>&1 || need+=("$pkg")
done
if [ ${#need[@]} -gt 0 ]; then
  sudo_=""; [ "$(id -u)" -eq 0 ] || sudo_="sudo"
  $sudo_ apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo_ apt-get install -y -qq --no-install-recommends "${need[@]}"
fi

[ -x .venv/bin/python ] || python3 -m venv .venv
stamp=.venv/.primkit-installed
want="$(cat constraints.txt setup.cfg pyproject.toml | sha256sum | cut -c1-16)"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  # torch==2.13.0 (pinned in constraints.txt) is the local CPU build on these machines.
  .venv/bin/python -m pip install -q --disable-pip-version-check -c constraints.txt torch==2.13.0
  .venv/bin/python -m pip install -q --disable-pip-version-check -c constraints.txt -e ".[dev]"
  echo "$want" > "$stamp"
fi
