#!/bin/sh
# Seed corpora for the fuzz targets from real files and the malformed
# corpora (run from the repo root: sh fuzz/seed.sh). fuzz/corpus/ is not
# checked in.
set -e
c=fuzz/corpus
mkdir -p $c/osim_reader $c/mesh_vtp $c/mesh_stl $c/mesh_obj $c/mesh_ply $c/landmarks $c/experiment $c/stiffness_table $c/nifti_labels $c/nifti_geometry $c/segmentation_level
cp tests/corpus/osim/*.osim base_model/*.osim $c/osim_reader/
for e in vtp stl obj ply; do
  cp tests/corpus/mesh/*.$e $c/mesh_$e/ 2>/dev/null || true
  cp tests/fixtures/mesh/*.$e $c/mesh_$e/ 2>/dev/null || true
done
# small real meshes only (a few vertebrae)
ls base_model/*.vtp | head -3 | xargs -I{} cp {} $c/mesh_vtp/
S=../shared
for f in $(ls $S/scoliosis-dev/*/landmarks*.csv 2>/dev/null | head -6); do cp "$f" $c/landmarks/$(basename $(dirname "$f"))_$(basename "$f"); done
cp fixtures/*.csv $c/landmarks/
# TRC and JSON, from the example's first rows (mm, LPS).
python3 - fixtures/example-scoliosis.csv $c/landmarks <<'PY'
import csv, sys
rows = [r for r in csv.reader(l for l in open(sys.argv[1]) if not l.startswith('#'))]
head, body = rows[0], rows[1:15]
pts = [(r[0], r[1:4]) for r in body]
json = '{"units": "mm", "frame": "LPS", "landmarks": {%s}}' % ', '.join(
    '"%s": [%s]' % (n, ', '.join(xyz)) for n, xyz in pts)
open(sys.argv[2] + '/example.json', 'w').write(json)
names = '\t\t\t'.join(n for n, _ in pts)
xyz = '\t'.join('X%d\tY%d\tZ%d' % (i + 1, i + 1, i + 1) for i in range(len(pts)))
vals = '\t'.join('\t'.join(v) for _, v in pts)
trc = ('PathFileType\t4\t(X/Y/Z)\tex.trc\nDataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames\n'
       '100\t100\t1\t%d\tmm\t100\t1\t1\nFrame#\tTime\t%s\n\t\t%s\n\n1\t0\t%s\n' % (len(pts), names, xyz, vals))
open(sys.argv[2] + '/example.trc', 'w').write(trc)
PY
for f in $(ls $S/diagnose-dev/*/experiment.toml 2>/dev/null | head -3); do cp "$f" $c/experiment/$(basename $(dirname "$f"))_$(basename "$f"); done
cp templates/stiffness-*.toml templates/stiffness-*.csv $c/stiffness_table/ 2>/dev/null || true
# NIfTI-1 label maps: small synthetic ones (uint8 and int16, sform and
# qform), written by python's struct module.
python3 - "$c/nifti_labels" <<'PY'
import struct, sys
def nii(path, dims, code, bpv, sform, labels):
    h = bytearray(348)
    struct.pack_into('<i', h, 0, 348)
    struct.pack_into('<8h', h, 40, 3, *dims, 1, 1, 1, 1)
    struct.pack_into('<hh', h, 70, code, bpv * 8)
    struct.pack_into('<8f', h, 76, 1.0, 1.0, 1.5, 2.0, 0, 0, 0, 0)
    struct.pack_into('<f', h, 108, 352.0)
    struct.pack_into('<B', h, 123, 2)  # xyzt_units: mm
    struct.pack_into('<hh', h, 252, 0 if sform else 1, 1 if sform else 0)
    struct.pack_into('<12f', h, 280, 1, 0, 0, -5, 0, 1.5, 0, 3, 0, 0, 2, 7)
    h[344:348] = b'n+1\0'
    fmt = {1: 'B', 2: 'h'}[bpv]
    vol = struct.pack('<%d%s' % (len(labels), fmt), *labels)
    open(path, 'wb').write(bytes(h) + b'\0' * 4 + vol)
n = 6 * 5 * 4
nii(sys.argv[1] + '/u8_sform.nii', (6, 5, 4), 2, 1, True, [(i * 7) % 30 for i in range(n)])
nii(sys.argv[1] + '/i16_qform.nii', (6, 5, 4), 4, 2, False, [(i % 3) * 22 for i in range(n)])
PY
# NIfTI-1 headers: the label maps' first 348 bytes.
for f in $c/nifti_labels/*.nii; do head -c 348 "$f" > $c/nifti_geometry/$(basename "$f" .nii).hdr; done
# One segmentation level: a format byte (0 STL, 1 OBJ, 2 PLY, 3 VTP),
# then a closed vertebra surface (the embedded base's small ones, so one
# palpation stays well under the 2 s timeout).
for v in base_model/proc_L3.vtp base_model/proc_L5.vtp base_model/proc_sacrum.vtp; do
  { printf '\003'; cat "$v"; } > $c/segmentation_level/$(basename "$v")
done
