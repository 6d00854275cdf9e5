#!/usr/bin/env bash
# Generate and diagnose out-of-vocabulary experiments (diagnose::synth::oov_set:
# creep between load steps, every moment 15 deg off its axis, follower guide
# points 10 mm anterior, stiffness softened by the loading history, in turn, on
# a nominal-form truth) and print how often the verdict is `other` and how
# many effect names were given with confidence >= 0.9.
# Usage: benches/diagnose_oov.sh [DEV_DIR] [N] [SEED]
set -euo pipefail
cd "$(dirname "$0")/.."
# PROFILE=dev uses the dev profile (crate opt-level 1, dependencies 3) instead of a release build
release=--release
[ "${PROFILE:-release}" = dev ] && release=
cargo run $release --example diagnose_synth -- "${1:-../shared/diagnose-dev}" "${2:-24}" "${3:-2026}" oov
