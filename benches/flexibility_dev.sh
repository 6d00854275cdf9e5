#!/bin/sh
# Score `osim-spine flexibility` on ../shared/bending-dev: per patient, the
# cyclist base's patient model, flexibility with and without --uniform on the
# neutral, left and right films predicting film_left_small_T1.csv, scored by
# benches/flexibility_dev.py against the withheld film and the truth.
# usage: benches/flexibility_dev.sh WORK   (run from the repository, after
# `cargo build --release`; WORK is a scratch folder)
set -e
W=${1:?usage: benches/flexibility_dev.sh WORK}
BIN=target/release/osim-spine
[ -f "$W/cyclist/base.osim" ] || $BIN base --generic ../shared/data/models/cyclistFullBodyMuscle.osim \
  --geometry ../shared/data/geometry-bodyframe --out "$W/cyclist" > "$W/base.log" 2>&1
for P in D01_thoracic45 D02_lumbar55 D03_double; do
  D=../shared/bending-dev/$P
  mkdir -p "$W/$P"
  [ -f "$W/$P/patient.osim" ] || $BIN generate --base "$W/cyclist" \
    --landmarks ../shared/scoliosis-dev/$P/landmarks_clean.csv --out "$W/$P/patient.osim" > "$W/$P/generate.log" 2>&1
  for mode in personalised uniform; do
    extra=""; [ $mode = uniform ] && extra="--uniform"
    $BIN flexibility --model "$W/$P/patient.osim" --film $D/film_neutral.csv --film $D/film_left.csv \
      --film $D/film_right.csv --predict $D/film_left_small_T1.csv $extra --out "$W/$P/$mode" --force \
      > "$W/$P/$mode.log" 2>&1
  done
  ${OSIM_SPINE_PYTHON:-python3} benches/flexibility_dev.py "$W/$P/personalised" "$W/$P/uniform" $P > "$W/$P/score.json"
  ${OSIM_SPINE_PYTHON:-python3} - "$W/$P/score.json" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
print("%s: withheld-film RMSE personalised %.2f mm, uniform %.2f mm (ratio %.2f); main curve %s Cobb film %.1f, personalised %.1f, uniform %.1f deg; truth in 95%% interval %d/%d; curve/rest stiffness ratio %.2f (truth %.2f, %+.0f%%)" % (
    s["patient"], s["rmse_personalised_mm"], s["rmse_uniform_mm"], s["rmse_personalised_mm"] / s["rmse_uniform_mm"],
    s["main_curve"], s["cobb_film_deg"], s["cobb_personalised_deg"], s["cobb_uniform_deg"],
    s.get("joints_in_ci95", 0), s.get("joints", 0), s.get("curve_ratio_estimated", 0), s.get("curve_ratio_truth", 0),
    100 * s.get("curve_ratio_error", 0)))
PY
done
