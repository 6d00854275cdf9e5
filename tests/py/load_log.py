"""Load models in OpenSim 4.6 and capture its log, model by model.

Usage: load_log.py RESULT.json MODEL...

For each model: a fresh file sink, Model(path), initSystem(). Writes
RESULT.json: {path: [log lines without their timestamps]}. A model that
fails to load gets the exception text as a line starting "EXCEPTION".
"""
import json
import os
import sys

import opensim as osim

result_path = sys.argv[1]
result = {}
for i, path in enumerate(sys.argv[2:]):
    log = "%s.%d.log" % (result_path, i)
    if os.path.exists(log):
        os.remove(log)
    osim.Logger.removeFileSink()
    osim.Logger.addFileSink(log)
    lines = []
    try:
        m = osim.Model(path)
        m.initSystem()
    except Exception as e:  # reported, not raised: the test names the model
        lines.append("EXCEPTION " + str(e).replace("\n", " "))
    osim.Logger.removeFileSink()
    with open(log) as f:
        # "[2026-11-25 03:20:13.747] [info] ..." -> "[info] ..."
        lines = [l.rstrip("\n").split("] ", 1)[-1] for l in f] + lines
    result[path] = lines
with open(result_path, "w") as f:
    json.dump(result, f, indent=1)
