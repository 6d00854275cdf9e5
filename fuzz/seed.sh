#!/bin/sh
# Seed corpora for the fuzz targets from real files and the malformed
# corpora (run from the repo root: sh fuzz/seed.sh). fuzz/corpus/ is not
# checked in.
set -e
c=fuzz/corpus
mkdir -p $c/osim_reader $c/mesh_vtp $c/mesh_stl $c/mesh_obj $c/mesh_ply $c/landmarks $c/experiment $c/stiffness_table
cp tests/corpus/osim/*.osim base_model/*.osim $c/osim_reader/
for e in vtp stl obj ply; do
  cp tests/corpus/mesh/*.$e $c/mesh_$e/ 2>/dev/null || true
  cp tests/fixtures/mesh/*.$e $c/mesh_$e/ 2>/dev/null || true
done
# small real meshes only (a few vertebrae)
ls base_model/*.vtp | head -3 | xargs -I{} cp {} $c/mesh_vtp/
S=../shared
for f in $(ls $S/scoliosis-dev/*/landmarks*.csv 2>/dev/null | head -6); do cp "$f" $c/landmarks/$(echo "$f" | tr / _); done
for f in $(find tests/fixtures -name '*.trc' -o -name '*.json' | head -6); do cp "$f" $c/landmarks/; done
for f in $(ls $S/diagnose-dev/*/experiment.toml 2>/dev/null | head -3); do cp "$f" $c/experiment/$(echo "$f" | tr / _); done
cp templates/stiffness-*.toml templates/stiffness-*.csv $c/stiffness_table/ 2>/dev/null || true
