#!/usr/bin/env bash
# Generate and diagnose published-means experiments (diagnose::synth::write_means:
# each the mean of 10 perturbed specimens carrying the same effect, +-7.5 N m
# about X, Y, Z only, rotations only, half with sd_* columns) and print the
# confusion matrix, top-1 accuracy with and without sd_*, effect names claimed
# on `none`, and the smallest noise any diagnosis used.
# Usage: benches/diagnose_means.sh [DEV_DIR] [PER_LABEL] [SEED] [primary]
set -euo pipefail
cd "$(dirname "$0")/.."
# PROFILE=dev uses the dev profile (crate opt-level 1, dependencies 3) instead of a release build
release=--release
[ "${PROFILE:-release}" = dev ] && release=
cargo run $release --example diagnose_means -- "${1:-../shared/diagnose-dev}" "${2:-6}" "${3:-2026}" ${4:-}
