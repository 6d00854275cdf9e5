#!/usr/bin/env bash
# Diagnose every labelled development experiment and print the confusion
# matrix, top-1 accuracy, false claims on `none` cases, median held-out
# shrink and the time per experiment. Usage: benches/diagnose_dev.sh [DEV_DIR]
set -euo pipefail
cd "$(dirname "$0")/.."
cargo run --release --example diagnose_dev -- "${1:-../shared/diagnose-dev}"
