#!/usr/bin/env bash
# Generate and diagnose two-effect experiments (diagnose::synth::pair_set: the
# fifteen pairs of the six effects in turn, each at a size that matters alone,
# random level range, noise, translations, follower series, perturbed
# specimens) and print how often both effects are in verdict.effects and the
# primary (verdict.effect) is one of the two.
# Usage: benches/diagnose_pairs.sh [DEV_DIR] [N] [SEED]
set -euo pipefail
cd "$(dirname "$0")/.."
# PROFILE=dev uses the dev profile (crate opt-level 1, dependencies 3) instead of a release build
release=--release
[ "${PROFILE:-release}" = dev ] && release=
cargo run $release --example diagnose_synth -- "${1:-../shared/diagnose-dev}" "${2:-30}" "${3:-2026}" pairs
