#!/bin/sh
# Accuracy of generated models on ../shared/scoliosis-dev: builds the cyclist base as that folder's README says
# (no --palpation), then scores generate on all 30 sets with it and with
# the repository's default base (base_model/). Run from the repository root.
set -e
cargo build --release --bin osim-spine --example scoliosis_dev
B=$(mktemp -d)
trap 'rm -rf "$B"' EXIT
./target/release/osim-spine base \
  --generic ../shared/data/models/cyclistFullBodyMuscle.osim \
  --geometry ../shared/data/geometry-bodyframe --out "$B/cyclist"
echo "## cyclist base"
./target/release/examples/scoliosis_dev "$B/cyclist" ../shared/scoliosis-dev
echo "## default base (base_model/)"
./target/release/examples/scoliosis_dev base_model ../shared/scoliosis-dev
