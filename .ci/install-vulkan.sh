#!/usr/bin/env bash
# Installs lavapipe (Mesa's CPU Vulkan driver) from bookworm-backports: Debian 12's own Mesa
# is too old for our compute shaders. The archive address is taken from the machine's own
# apt sources, so no host is written down here.
set -euo pipefail
src=/etc/apt/sources.list.d/debian.sources
uri=$(awk '/^URIs:/ && $2 !~ /security/ {print $2; exit}' "$src")
if [ -z "$uri" ]; then
  echo "no Debian archive found in $src" >&2
  exit 1
fi
cat > /etc/apt/sources.list.d/metasplat-backports.sources <<SRC
Types: deb
URIs: $uri
Suites: bookworm-backports
Components: main
Signed-By: /usr/share/keyrings/debian-archive-keyring.gpg
SRC
apt-get update -qq
DEBIAN_FRONTEND=noninteractive apt-get install -y -qq -t bookworm-backports \
  mesa-vulkan-drivers libvulkan1 >/dev/null
