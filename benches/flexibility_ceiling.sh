#!/bin/sh
# What the films allow: the withheld film predicted by each patient model wearing
# the TRUTH stiffness multipliers (bending_truth.json), against the same model
# with uniform stiffness; scored as benches/flexibility_dev.sh scores an
# estimate. With `clean`, every film (and the T1 of the prediction film) is
# replaced by its noise-free landmarks, so only the model's own bending
# kinematics separate the prediction from the film.
# usage: benches/flexibility_ceiling.sh WORK [clean]   (from the repository, after
# `cargo build --release` and benches/flexibility_dev.sh WORK)
set -e
W=${1:?usage: benches/flexibility_ceiling.sh WORK [clean]}
MODE=${2:-noisy}
BIN=target/release/osim-spine
PY=${OSIM_SPINE_PYTHON:-python3}
for P in D01_thoracic45 D02_lumbar55 D03_double; do
  D=../shared/bending-dev/$P
  C=$W/$P/ceiling-$MODE
  mkdir -p "$C"
  [ -f "$W/$P/patient.osim" ] || { echo "run benches/flexibility_dev.sh $W first"; exit 1; }
  # Step 1: the films, as given or noise-free.
  $PY - "$D" "$C" "$MODE" <<'PY'
import json, sys, shutil
d, c, mode = sys.argv[1:4]
truth = json.load(open(f"{d}/bending_truth.json"))
for name, film in [("film_neutral", "neutral"), ("film_left", "left"), ("film_right", "right"),
                   ("film_left_small_T1", "left_small")]:
    src = f"{d}/{name}.csv"
    if mode != "clean":
        shutil.copyfile(src, f"{c}/{name}.csv")
        continue
    lines = open(src).read().splitlines()
    head = [l for l in lines if l.startswith("#")] + ["name,u,v"]
    names = [l.split(",")[0] for l in lines if not l.startswith("#") and not l.startswith("name,")]
    clean = truth["films"][film]["clean"]
    rows = ["%s,%.6f,%.6f" % (n, clean[n][0], clean[n][1]) for n in names]
    open(f"{c}/{name}.csv", "w").write("\n".join(head + rows) + "\n")
PY
  # Step 2: the truth multipliers as a stiffness table on the patient model.
  $BIN stiffness "$W/$P/patient.osim" --list --out "$C/listed.toml" > /dev/null
  $PY - "$D/bending_truth.json" "$C/listed.toml" "$C/truth.toml" <<'PY'
import json, sys
m = json.load(open(sys.argv[1]))["multipliers"]
out, level = [], None
for line in open(sys.argv[2]).read().splitlines():
    out.append(line)
    if line.startswith("name = "):
        level = line.split('"')[1]
    if line.startswith("stiffness = ") and level in m:
        r = m[level]
        out.append("ratio = { rx = %r, ry = %r, rz = %r }" % (r, r, r))
open(sys.argv[3], "w").write("\n".join(out) + "\n")
PY
  $BIN stiffness "$W/$P/patient.osim" --table "$C/truth.toml" --out "$C/truth.osim" --force > /dev/null
  # Step 3: both predictions of the withheld film from its T1.
  for model in truth patient; do
    M=$C/truth.osim; [ $model = patient ] && M=$W/$P/patient.osim
    $BIN flexibility --model "$M" --film "$C/film_neutral.csv" --film "$C/film_left.csv" \
      --film "$C/film_right.csv" --predict "$C/film_left_small_T1.csv" --uniform \
      --out "$C/$model" --force --allow-mismatch > "$C/$model.log" 2>&1
  done
  # Step 4: scored against the noise-free withheld film.
  $PY benches/flexibility_dev.py "$C/truth" "$C/patient" $P > "$C/score.json"
  $PY - "$C/score.json" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
print("%s: withheld-film RMSE truth multipliers %.2f mm, uniform %.2f mm (ratio %.2f); %s Cobb film %.1f, truth multipliers %.1f, uniform %.1f deg" % (
    s["patient"], s["rmse_personalised_mm"], s["rmse_uniform_mm"], s["rmse_personalised_mm"] / s["rmse_uniform_mm"],
    s["main_curve"], s["cobb_film_deg"], s["cobb_personalised_deg"], s["cobb_uniform_deg"]))
PY
done
