#!/usr/bin/env python3
"""Recovers, from ../shared/scoliosis-dev/, the generic landmarks and the
vertebral centres its maker palpated on the cyclist model's vertebra meshes
(geometry-bodyframe), in each vertebra's body frame (metres).

Each patient's clean set is the generic landmarks scaled about the vertebral
centre (depth = X, height = Y, width = Z of the body frame, truth.json
`scale_factors`), posed by the cyclist model at `pose_deg` in OpenSim 4.6, then
moved rigidly (`ground_m_to_set_mm`). This script undoes the three steps and
prints how far the patients agree with each other (they should to ~1e-6 mm:
that checks the recovery), then writes `level,code,x,y,z` rows (the code
`CENTRE` for the vertebral centre) to OUT.

Usage: .venv/bin/python scripts/scoliosis_truth_generic.py OUT.csv [DEV_DIR]
A dev tool: the engine is compared with its output by
`examples/palpation_vs_truth.rs`.
"""
import csv
import json
import math
import os
import sys

import numpy as np
import opensim as osim

repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
shared = os.path.join(repo, "..", "shared")
dev = sys.argv[2] if len(sys.argv) > 2 else os.path.join(shared, "scoliosis-dev")
out_path = sys.argv[1]

LEVELS = ["T%d" % i for i in range(1, 13)] + ["L%d" % i for i in range(1, 6)] + ["S1"]


def body_name(level):
    if level == "S1":
        return "sacrum"
    if level.startswith("T"):
        return "thoracic" + level[1:]
    return "lumbar" + level[1:]


def read_points(path):
    rows = {}
    with open(path) as f:
        lines = [l for l in f if not l.startswith("#")]
    for r in csv.reader(lines[1:]):
        rows[r[0]] = np.array([float(v) for v in r[1:4]])
    return rows


osim.Logger.setLevelString("error")
model = osim.Model(os.path.join(shared, "data", "models", "cyclistFullBodyMuscle.osim"))
state = model.initSystem()

recovered = {}  # (level, code) -> list of body-frame points
for patient in sorted(os.listdir(dev)):
    pdir = os.path.join(dev, patient)
    if not os.path.isfile(os.path.join(pdir, "truth.json")):
        continue
    truth = json.load(open(os.path.join(pdir, "truth.json")))
    s = model.initializeState()
    cs = model.getCoordinateSet()
    for name, deg in truth["pose_deg"].items():
        cs.get(name).setValue(s, math.radians(deg), False)
    model.assemble(s) if False else model.realizePosition(s)
    setinfo = truth["sets"]["clean"]
    m = np.array(setinfo["ground_m_to_set_mm"])
    a, t = m[:, :3], m[:, 3]
    ainv = np.linalg.inv(a)
    lms = read_points(os.path.join(pdir, setinfo["landmarks"]))
    centres = read_points(os.path.join(pdir, setinfo["truth_centres"]))
    factors = truth["scale_factors"]["factors"]
    for level in LEVELS:
        body = model.getBodySet().get(body_name(level))
        tr = body.getTransformInGround(s)
        r = np.array([[tr.R().get(i, j) for j in range(3)] for i in range(3)])
        p = np.array([tr.p().get(i) for i in range(3)])

        def to_body(x_mm):
            g = ainv @ (x_mm - t)
            return r.T @ (g - p)

        c = to_body(centres[level]) if level in centres else None
        f = factors.get(level)
        sc = np.array([f["depth"], f["height"], f["width"]]) if f else np.ones(3)
        if c is not None:
            recovered.setdefault((level, "CENTRE"), []).append((patient, c))
        for name, x in lms.items():
            lv, code = name.split("_", 1)
            if lv != level:
                continue
            b = to_body(x)
            if c is not None:
                b = c + (b - c) / sc
            recovered.setdefault((level, code), []).append((patient, b))

worst = 0.0
rows = []
for (level, code), vals in sorted(recovered.items(), key=lambda kv: (LEVELS.index(kv[0][0]), kv[0][1])):
    pts = np.array([v for _, v in vals])
    mean = pts.mean(axis=0)
    spread = max(np.linalg.norm(pts - mean, axis=1)) * 1e3
    worst = max(worst, spread)
    rows.append((level, code, *mean))
print("patients agree within %.2e mm (largest distance of one patient's recovery from the mean)" % worst, file=sys.stderr)
with open(out_path, "w") as f:
    f.write("# generic landmarks and vertebral centres of the scoliosis-dev maker, body frames, metres\n")
    f.write("level,code,x,y,z\n")
    for level, code, x, y, z in rows:
        f.write("%s,%s,%.9f,%.9f,%.9f\n" % (level, code, x, y, z))
