#!/usr/bin/env bash
# Generate and diagnose published-means experiments (diagnose::synth::write_means:
# each the mean of 10 perturbed specimens carrying the same effect(s): a level
# trend, a shared direction asymmetry, both, or one of the other effects; one
# moment magnitude per direction (+-7.5 N m about X, Y, Z), rotations only
# (`primary`: only the rotation about each load axis), half with sd_* columns)
# and print the published-means reading per kind (right, wrong effects named at
# confidence >= 0.9), the confusion matrix, effect names claimed on `none`, and
# the smallest noise any diagnosis used.
# Usage: benches/diagnose_means.sh [SPECIMEN.osim | DEV_DIR] [PER_KIND] [SEED] [primary]
# (default: the published tables' specimen tests/data/published/specimen.osim,
# 10 per kind, seed 2026; a DEV_DIR uses the lordotic dev-13 and dev-07 specimens)
set -euo pipefail
cd "$(dirname "$0")/.."
# PROFILE=dev uses the dev profile (crate opt-level 1, dependencies 3) instead of a release build
release=--release
[ "${PROFILE:-release}" = dev ] && release=
cargo run $release --example diagnose_means -- "${1:-tests/data/published/specimen.osim}" "${2:-10}" "${3:-2026}" ${4:-}
