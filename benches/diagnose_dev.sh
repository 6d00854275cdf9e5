#!/usr/bin/env bash
# Diagnose every labelled development experiment and print the confusion
# matrix, top-1 accuracy, false claims on `none` cases, median held-out
# shrink and the time per experiment. Usage: benches/diagnose_dev.sh [DEV_DIR]
set -euo pipefail
cd "$(dirname "$0")/.."
# PROFILE=dev uses the dev profile (crate opt-level 1, dependencies 3) instead of a release build
release=--release
[ "${PROFILE:-release}" = dev ] && release=
cargo run $release --example diagnose_dev -- "${1:-../shared/diagnose-dev}"
