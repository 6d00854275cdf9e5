"""Property-by-property comparison of a legacy model's upgrade by OpenSim 4.6
with osim-spine's upgrade of the same file.

Usage: upgrade_diff.py ORIGINAL CONVERTED

OpenSim loads ORIGINAL (a pre-4.0 document, upgraded by OpenSim's own
version-update rules) and CONVERTED (written by `osim-spine convert`),
initialises both (initSystem), and re-saves both with printToXML. The two
XML trees are put in canonical order (siblings sorted by tag and name) and
compared element by element: every property value, every component present
in one and not the other. Numbers are compared exactly, as OpenSim prints
them (17 significant digits).

Prints JSON: {"differences": [{"path", "kind", "opensim", "converted"}...],
"elements": number of elements compared}.
"""
import json
import os
import sys
import tempfile
import xml.etree.ElementTree as ET

import opensim as osim

osim.Logger.setLevelString("error")


def resave(path, out):
    m = osim.Model(path)
    m.initSystem()
    m.printToXML(out)


def key(e):
    return (e.tag, e.get("name", ""))


def text(e):
    return " ".join((e.text or "").split())


def numbers(t):
    try:
        return [float(x) for x in t.split()]
    except ValueError:
        return None


def same_text(a, b):
    if a == b:
        return True
    na, nb = numbers(a), numbers(b)
    return na is not None and nb is not None and na == nb


def keyed_children(e):
    out = {}
    for c in e:
        k = key(c)
        i = 0
        while (k, i) in out:
            i += 1
        out[(k, i)] = c
    return out


def label(k):
    (tag, name), i = k
    s = f"{tag}[{name}]" if name else tag
    return s + (f"#{i}" if i else "")


def compare(a, b, path, diffs, count):
    count[0] += 1
    if len(a) == 0 and len(b) == 0 and not same_text(text(a), text(b)):
        diffs.append({"path": path, "kind": "value", "opensim": text(a), "converted": text(b)})
    ca, cb = keyed_children(a), keyed_children(b)
    for k in sorted(set(ca) | set(cb)):
        p = f"{path}/{label(k)}"
        if k not in cb:
            diffs.append({"path": p, "kind": "missing_in_converted", "opensim": text(ca[k]), "converted": None})
        elif k not in ca:
            diffs.append({"path": p, "kind": "extra_in_converted", "opensim": None, "converted": text(cb[k])})
        else:
            compare(ca[k], cb[k], p, diffs, count)


def main():
    orig, conv = sys.argv[1], sys.argv[2]
    with tempfile.TemporaryDirectory() as d:
        ro, rc = os.path.join(d, "opensim.osim"), os.path.join(d, "converted.osim")
        resave(orig, ro)
        resave(conv, rc)
        a, b = ET.parse(ro).getroot(), ET.parse(rc).getroot()
    diffs, count = [], [0]
    compare(a, b, "", diffs, count)
    print(json.dumps({"differences": diffs, "elements": count[0]}))


if __name__ == "__main__":
    main()
