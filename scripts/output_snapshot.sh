#!/usr/bin/env bash
# Writes the outputs that the restructuring must keep byte-identical into OUT, then lists their checksums in OUT/SHA256SUMS.
# Usage: scripts/output_snapshot.sh OUT [BINARY]
#   compare two snapshots with: diff OUT1/SHA256SUMS OUT2/SHA256SUMS
# Needs ../shared/ (the diagnose-dev cases) beside the repository.
set -euo pipefail
out=$(realpath -m "$1")
repo=$(cd "$(dirname "$0")/.." && pwd)
bin=${2:-$repo/target/release/osim-spine}
shared=$repo/../shared
[ -d "$shared/diagnose-dev" ] || { echo "no ../shared/diagnose-dev: cannot snapshot" >&2; exit 2; }
rm -rf "$out" && mkdir -p "$out"
# run from OUT with relative paths (reports name their inputs): repo/ and shared/ are links
ln -s "$repo" "$out/repo" && ln -s "$(realpath "$shared")" "$out/shared" && cd "$out"
n=0
run() {
  n=$((n + 1))
  echo "+ $*" >&2
  "$bin" "$@" >"$out/log.$n.txt" 2>&1 || { cat "$out/log.$n.txt" >&2; exit 1; }
}
# generate on the README example, then evaluate it against its truth
run generate --landmarks repo/fixtures/example-scoliosis.csv --out gen/patient.osim
run evaluate --model gen/patient.osim --truth repo/fixtures/example-scoliosis-centres.csv \
  --truth-landmarks repo/fixtures/example-scoliosis.csv --out eval
# the embedded default spine from its tables
run base --procedural --out base
# calibrate on dev-07, diagnose on three dev cases
run calibrate shared/diagnose-dev/dev-07 --out cal07
for c in dev-03 dev-09 dev-17; do
  run diagnose "shared/diagnose-dev/$c" --out "diag-$c"
done
# check --format json over the landmark corpus: the fixtures and the scoliosis-dev sets (exit codes kept)
for f in $(ls repo/fixtures/*.csv shared/scoliosis-dev/*/*.csv | sort); do
  rel=$(basename "$(dirname "$f")")_$(basename "$f")
  set +e; "$bin" check --format json "$f" >"$out/check_$rel.json" 2>&1; echo "exit $?" >>"$out/check_$rel.json"; set -e
done
# console logs name the output folder; keep them, but only the files are compared
find . -type f ! -name 'log.*' ! -name SHA256SUMS | sort | xargs sha256sum >SHA256SUMS
echo "$(wc -l <SHA256SUMS) files in $out/SHA256SUMS" >&2
