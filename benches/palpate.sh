#!/usr/bin/env bash
# Timing of `osim-spine palpate`: a folder of 18 level meshes
# (T1..L5 + sacrum) and a 512 x 512 x 400 label map with 18 labels, both
# made from the default base model by examples/palpate_inputs.rs.
# Usage: benches/palpate.sh [release|dev]   (default release)
set -euo pipefail
cd "$(dirname "$0")/.."
profile=${1:-release}
flag=$([ "$profile" = release ] && echo --release || echo)
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
cargo run -q $flag --example palpate_inputs -- "$tmp"
cargo build -q $flag
bin=target/$([ "$profile" = release ] && echo release || echo debug)/osim-spine
for input in "$tmp/folder" "$tmp/labels.nii"; do
  for i in 1 2 3; do
    /usr/bin/time -f "$(basename "$input") run $i: %e s wall, %M kB max RSS" \
      "$bin" palpate "$input" --out "$tmp/out.csv" > /dev/null 2> "$tmp/err" || { cat "$tmp/err"; exit 1; }
    tail -n 1 "$tmp/err"
  done
done
