#!/bin/sh
# Profile the restorer by operation (restore/README, "Where a training step's time goes"):
# perf samples with DWARF call stacks of `bench restorer --fast-only`, attributed by
# attribute.py. Usage: profile.sh CONFIG BATCH [ROUNDS] [SIDE]: a training step of BATCH
# crops, or with BATCH 0 a forward pass over a SIDE² tile (default 512). Run from the
# workspace root after `cargo build --release`.
set -eu
config=${1:-tiny}; batch=${2:-4}; rounds=${3:-6}; side=${4:-512}
out=${TMPDIR:-/tmp}/restorer-profile-$config-$batch
if [ "$batch" = 0 ]; then
  work="--sides $side --batch 0"
else
  work="--train-only --batch $batch"
fi
# shellcheck disable=SC2086 # $work is a list of arguments
perf record -F 200 --call-graph dwarf,32768 -o "$out.data" \
  target/release/metasplat bench restorer --configs "$config" $work \
  --threads 2 --rounds "$rounds" --fast-only
perf script -i "$out.data" -F tid,ip,sym > "$out.txt" 2>/dev/null
python3 "$(dirname "$0")/attribute.py" "$out.txt"
