#!/usr/bin/env bash
# Installs the Debian packages the project needs at run time and in its tests, when missing:
#   libusb-1.0-0  loaded by Open3D's wheels
#   chromium, xvfb  the web-viewer check (tests/viz/test_web_viewer.py: Chromium on a virtual screen)
set -euo pipefail
need=()
if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then need+=(libusb-1.0-0); fi
if ! command -v chromium >/dev/null 2>&1; then need+=(chromium); fi
if ! command -v Xvfb >/dev/null 2>&1; then need+=(xvfb xauth); fi
if [ ${#need[@]} -eq 0 ]; then exit 0; fi
if [ "$(id -u)" -ne 0 ] || ! command -v apt-get >/dev/null 2>&1; then
  echo "warning: missing system packages ${need[*]}; install them with apt-get (need root)" >&2
  exit 0
fi
echo "installing system packages: ${need[*]}"
apt-get update -qq >/dev/null
DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need[@]}" >/dev/null
