#!/bin/sh
# Profile the restorer's training step by operation (restore/README, "Where a training step's
# time goes"): perf samples with DWARF call stacks of `bench restorer --fast-only`, attributed
# by attribute.py. Usage: profile.sh CONFIG BATCH [ROUNDS]; run from the workspace root after
# `cargo build --release`.
set -eu
config=${1:-tiny}; batch=${2:-4}; rounds=${3:-6}
out=${TMPDIR:-/tmp}/restorer-profile-$config
perf record -F 200 --call-graph dwarf,32768 -o "$out.data" \
  target/release/metasplat bench restorer --configs "$config" --train-only \
  --batch "$batch" --threads 2 --rounds "$rounds" --fast-only
perf script -i "$out.data" -F tid,ip,sym > "$out.txt" 2>/dev/null
python3 "$(dirname "$0")/attribute.py" "$out.txt"
