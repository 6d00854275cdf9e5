#!/usr/bin/env python3
"""Score `osim-spine flexibility` on ../shared/bending-dev.

usage: flexibility_dev.py PERSONALISED_DIR UNIFORM_DIR PATIENT

PERSONALISED_DIR / UNIFORM_DIR: the --out folders of `flexibility` run without
and with --uniform on the patient's films (with --predict
film_left_small_T1.csv). Prints JSON: prediction RMSE of the withheld film
(personalised, uniform; both placed on their pelvic landmarks by a 2-D rigid
fit of S1_SR, S1_SL, S1_SEC, FH_R, FH_L onto the truth's noise-free film), the
main curve's Cobb angle (end vertebrae of ../shared/scoliosis-dev truth.json),
and the estimate against the truth multipliers: per-joint coverage of the 95%
intervals and the main-curve / rest ratio of geometric means.
"""
import csv
import json
import math
import sys
from pathlib import Path

SHARED = Path(__file__).resolve().parents[2] / "shared"
PELVIC = ["S1_SR", "S1_SL", "S1_SEC", "FH_R", "FH_L"]
LEVELS = [f"T{i}" for i in range(1, 13)] + [f"L{i}" for i in range(1, 6)] + ["S1"]


def read_film(path):
    pts = {}
    with open(path) as f:
        rows = [l for l in f if not l.startswith("#")]
    for r in csv.DictReader(rows):
        pts[r["name"]] = (float(r["u"]), float(r["v"]))
    return pts


def place(src, dst):
    """2-D rigid fit of src's pelvic points onto dst's; returns src moved."""
    names = [n for n in PELVIC if n in src and n in dst]
    n = len(names)
    cs = [sum(src[k][i] for k in names) / n for i in (0, 1)]
    cd = [sum(dst[k][i] for k in names) / n for i in (0, 1)]
    dot = cross = 0.0
    for k in names:
        a = (src[k][0] - cs[0], src[k][1] - cs[1])
        b = (dst[k][0] - cd[0], dst[k][1] - cd[1])
        dot += a[0] * b[0] + a[1] * b[1]
        cross += a[0] * b[1] - a[1] * b[0]
    phi = math.atan2(cross, dot)
    c, s = math.cos(phi), math.sin(phi)
    out = {}
    for k, (u, v) in src.items():
        x, y = u - cs[0], v - cs[1]
        out[k] = (c * x - s * y + cd[0], s * x + c * y + cd[1])
    return out


def rmse(a, b):
    names = [k for k in b if k in a]
    return math.sqrt(sum((a[k][0] - b[k][0]) ** 2 + (a[k][1] - b[k][1]) ** 2 for k in names) / len(names))


def tilt(p, r, l):
    if r not in p or l not in p:
        return None
    du, dv = p[l][0] - p[r][0], p[l][1] - p[r][1]
    return math.degrees(math.atan2(dv, du))


def cobb(p, upper, lower):
    a, b = tilt(p, f"{upper}_SR", f"{upper}_SL"), tilt(p, f"{lower}_IR", f"{lower}_IL")
    return None if a is None or b is None else b - a


def main():
    pdir, udir, patient = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3]
    bt = json.loads((SHARED / "bending-dev" / patient / "bending_truth.json").read_text())
    truth = json.loads((SHARED / "scoliosis-dev" / patient / "truth.json").read_text())["metrics"]
    clean = {k: tuple(v) for k, v in bt["films"]["left_small"]["clean"].items()}
    stem = "film_left_small_T1"
    pers = place(read_film(pdir / f"predicted_{stem}.csv"), clean)
    unif = place(read_film(udir / f"predicted_{stem}.csv"), clean)
    up, lo = truth["upper_end_vertebra"], truth["lower_end_vertebra"]
    out = {
        "patient": patient,
        "rmse_personalised_mm": rmse(pers, clean),
        "rmse_uniform_mm": rmse(unif, clean),
        "truth_uniform_rmse_mm": bt["uniform_prediction_rmse_mm"],
        "main_curve": f"{up}-{lo}",
        "cobb_film_deg": cobb(clean, up, lo),
        "cobb_personalised_deg": cobb(pers, up, lo),
        "cobb_uniform_deg": cobb(unif, up, lo),
    }
    # the truth patient's own uniform prediction, scored the same way (check of the scoring)
    tu = {k: tuple(v) for k, v in bt["uniform_prediction_clean"].items()}
    out["truth_uniform_rmse_rescored_mm"] = rmse(place(tu, clean), clean)
    rep = json.loads((pdir / "flexibility.json").read_text())
    mult = bt["multipliers"]
    if not rep["joints"]:
        print(json.dumps(out, indent=1))
        return
    inside = [j["ci95"][0] <= mult[j["joint"]] <= j["ci95"][1] for j in rep["joints"]]
    out["joints_in_ci95"] = sum(inside)
    out["joints"] = len(inside)
    ui, li = LEVELS.index(up), LEVELS.index(lo)

    def in_curve(name):
        u = name.split("_")[0]
        return ui <= LEVELS.index(u) < li

    def gm(vals):
        return math.exp(sum(math.log(v) for v in vals) / len(vals))

    est = {j["joint"]: j["relative_stiffness"] for j in rep["joints"]}
    t_in = gm([mult[k] for k in est if in_curve(k)])
    t_out = gm([mult[k] for k in est if not in_curve(k)])
    e_in = gm([v for k, v in est.items() if in_curve(k)])
    e_out = gm([v for k, v in est.items() if not in_curve(k)])
    out["curve_ratio_truth"] = t_in / t_out
    out["curve_ratio_estimated"] = e_in / e_out
    out["curve_ratio_error"] = (e_in / e_out) / (t_in / t_out) - 1.0
    out["per_joint"] = {k: [round(est[k], 3), round(mult[k], 3)] for k in est}
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
