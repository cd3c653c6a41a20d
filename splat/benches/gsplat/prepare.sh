#!/bin/bash
# Builds what the GPU machine needs for run.sh into target/device/ (ignored by git, carried by
# the device tool: `carry: ["target/device"]`): our benchmark binary, the Vulkan loader (that
# machine has the NVIDIA driver but may lack the loader), and the wheels gsplat and its small
# dependencies come in (torch, numpy and ninja are there already). Needs network access here.
set -euo pipefail
cd "$(dirname "$0")/../../.."
mkdir -p target/device/wheels
cargo build --release -p splat --example gpu_step
cp target/release/examples/gpu_step target/device/
cp -L /usr/lib/x86_64-linux-gnu/libvulkan.so.1 target/device/
py=${PYTHON:-python3}
"$py" -m pip download --only-binary :all: -d target/device/wheels gsplat jaxtyping rich --no-deps
"$py" -m pip download --only-binary :all: -d target/device/wheels wadler-lindig markdown-it-py mdurl pygments --no-deps
du -sh target/device
