#!/usr/bin/env python3
"""Side by side: the release binary `osim-spine convert IN OUT` (read, upgrade,
typed-model validation, atomic write; one process per run, so process start is
included) against OpenSim 4.6's `opensim.Model(IN)` (load only, timed inside
this Python process, so the import of opensim is not counted), alternating the
two, ROUNDS rounds (default 10). Prints the medians and the ratio.

usage: python benches/osim_io_vs_opensim.py [--tool PATH] [--model PATH] [--rounds 10]
Build the tool first: cargo build --release
"""
import argparse
import os
import statistics
import subprocess
import tempfile
import time

import opensim

HERE = os.path.dirname(os.path.abspath(__file__))
CYCLIST = os.path.join(HERE, "..", "..", "shared", "data", "models", "cyclistFullBodyMuscle.osim")
TARGET = os.environ.get("CARGO_TARGET_DIR", os.path.join(HERE, "..", "target"))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--tool", default=os.path.join(TARGET, "release", "osim-spine"))
    ap.add_argument("--model", default=CYCLIST)
    ap.add_argument("--rounds", type=int, default=10)
    a = ap.parse_args()
    opensim.Logger.setLevelString("error")
    model = os.path.abspath(a.model)
    tool_t, osim_t = [], []
    with tempfile.TemporaryDirectory() as d:
        out = os.path.join(d, "out.osim")
        for _ in range(a.rounds):
            t0 = time.perf_counter()
            subprocess.run([a.tool, "convert", model, out], check=True,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            tool_t.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            opensim.Model(model)
            osim_t.append(time.perf_counter() - t0)
    tool_m, osim_m = statistics.median(tool_t), statistics.median(osim_t)
    load = os.getloadavg()[0]
    print(f"{os.path.basename(model)}, median of {a.rounds} (alternating), load average {load:.1f}")
    print(f"  osim-spine convert (process: read + validate + write): {tool_m * 1e3:8.1f} ms")
    print(f"  OpenSim 4.6 opensim.Model(path):                       {osim_m * 1e3:8.1f} ms")
    print(f"  speed-up: {osim_m / tool_m:.1f}x")


if __name__ == "__main__":
    main()
