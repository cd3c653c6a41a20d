#!/bin/bash
# On a machine with an NVIDIA GPU, from the repository root, after prepare.sh here:
#   bash splat/benches/gsplat/run.sh
# For 100k and 1M splats at 504x378 and 1008x756: our CPU (all cores) and wgpu paths
# (gpu_step), then gsplat on the same scene and camera (side_by_side.py). One JSON line per
# case in $OUT/results.jsonl (OUT defaults to ./gsplat_out), the export folders beside it.
set -uo pipefail
D=target/device
OUT=${OUT:-gsplat_out}
mkdir -p "$OUT"
export LD_LIBRARY_PATH="$PWD/$D${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
python3 -m pip install --quiet --no-index --find-links "$D/wheels" gsplat 2>&1 | tail -n 3
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader
# The device tool allows 600 s per command: gsplat's first import compiles its CUDA code
# (minutes), so the first case gets the long timeout and the rest short ones.
limit=420
for scale in 1 2; do
  for n in 100000 1000000; do
    dir="$OUT/${n}_x$scale"
    echo "== $n splats, scale $scale"
    timeout 60 "$D/gpu_step" "$n" "$scale" 5 "$dir" || { echo "gpu_step failed ($?)"; continue; }
    timeout $limit python3 splat/benches/gsplat/side_by_side.py "$dir" 20 | tee -a "$OUT/results.jsonl"
    limit=60
  done
done
