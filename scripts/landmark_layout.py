#!/usr/bin/env python3
"""Rewrites templates/landmark_layout.csv from base_model/base.osim (the
default base model's T1-L5 markers in their bodies' frames); run after
regenerating base_model/. tests/landmark_layout.rs checks the two agree."""
import os
import re

repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
text = open(os.path.join(repo, "base_model", "base.osim")).read()
path = os.path.join(repo, "templates", "landmark_layout.csv")
header = [l for l in open(path) if l.startswith("#")]
rows = []
pat = r'<Marker name="([TL]\d+)_(\w+)">\s*<socket_parent_frame>[^<]*</socket_parent_frame>\s*<location>([^<]*)</location>'
for m in re.finditer(pat, text):
    x, y, z = (repr(float(v)) for v in m.group(3).split())
    rows.append((m.group(1), m.group(2), x, y, z))
order = ["T%d" % i for i in range(1, 13)] + ["L%d" % i for i in range(1, 6)]
rows.sort(key=lambda r: (order.index(r[0]), r[1]))
with open(path, "w") as f:
    f.writelines(header)
    f.write("level,code,x,y,z\n")
    for r in rows:
        f.write(",".join(r) + "\n")
