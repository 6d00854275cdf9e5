#!/bin/sh
# The long fuzz pass: every reader's target for SECONDS (default
# 300) with a 1 GB memory limit and a 2 s per-input timeout, so a hang or
# an allocation blow-up is a finding. Run from the repo root after
# `cargo install cargo-fuzz` and `sh fuzz/seed.sh`:
#   sh fuzz/run_all.sh [SECONDS [TARGET...]]   (default: every target)
# The targets are built once (cargo +nightly fuzz build), then run
# directly. Prints one line per target: runs, seconds, crash files.
set -u
secs=${1:-300}
[ $# -gt 0 ] && shift
targets=${*:-osim_reader mesh_vtp mesh_stl mesh_obj mesh_ply landmarks experiment stiffness_table nifti_labels nifti_geometry segmentation_level}
cd fuzz
cargo +nightly fuzz build || exit 1
bin=target/x86_64-unknown-linux-gnu/release
mkdir -p logs
for t in $targets; do
  case $t in
    osim_reader|mesh_vtp) dict="-dict=dict/xml.dict" ;;
    landmarks|experiment|stiffness_table) dict="-dict=dict/csv.dict" ;;
    *) dict="" ;;
  esac
  mkdir -p corpus/$t artifacts/$t
  $bin/$t corpus/$t -max_total_time=$secs -rss_limit_mb=1024 -malloc_limit_mb=1024 \
    -timeout=2 -artifact_prefix=artifacts/$t/ $dict > logs/$t.log 2>&1
  code=$?
  runs=$(grep -o 'Done [0-9]* runs in [0-9]* second' logs/$t.log | tail -1)
  echo "$t: exit $code; ${runs:-no summary (see fuzz/logs/$t.log)}; artifacts: $(ls artifacts/$t | wc -l)"
done
