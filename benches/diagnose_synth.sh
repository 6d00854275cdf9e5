#!/usr/bin/env bash
# Generate and diagnose the synthetic withheld set (diagnose::synth: seven
# labels, random forms/sizes/levels/noise, perturbed specimens) and print the
# confusion matrix, top-1 accuracy, false claims on `none`, median held-out
# shrink and confidence vs hit rate. Usage: benches/diagnose_synth.sh [DEV_DIR] [N] [SEED] [SET]
# (SET: standard, pairs or oov; see benches/diagnose_pairs.sh, benches/diagnose_oov.sh)
set -euo pipefail
cd "$(dirname "$0")/.."
# PROFILE=dev uses the dev profile (crate opt-level 1, dependencies 3) instead of a release build
release=--release
[ "${PROFILE:-release}" = dev ] && release=
cargo run $release --example diagnose_synth -- "${1:-../shared/diagnose-dev}" "${2:-42}" "${3:-2026}" ${4:-}
