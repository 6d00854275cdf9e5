#!/usr/bin/env python3
"""Compare two output snapshots (scripts/output_snapshot.sh) file by file.

Usage: scripts/output_compare.py SNAP_A SNAP_B

For every file whose checksum differs, says whether the text outside numbers
is the same and, if so, the largest absolute and relative difference between
corresponding numbers: round-off differences show as tiny figures, a changed
result as a large one or as changed text.
"""
import re
import sys
from pathlib import Path

NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?")


def sums(snap):
    out = {}
    for line in (snap / "SHA256SUMS").read_text().splitlines():
        digest, name = line.split(maxsplit=1)
        out[name] = digest
    return out


def compare(a, b):
    ta, tb = a.read_text(errors="replace"), b.read_text(errors="replace")
    if NUMBER.sub("#", ta) != NUMBER.sub("#", tb):
        return "text differs"
    na = [float(x) for x in NUMBER.findall(ta)]
    nb = [float(x) for x in NUMBER.findall(tb)]
    pairs = [(x, y) for x, y in zip(na, nb) if x != y]
    abs_max = max((abs(x - y) for x, y in pairs), default=0.0)
    # relative to numbers of at least 1e-6 (a round-off change of a zero is not relative)
    rel_max = max((abs(x - y) / max(abs(x), abs(y)) for x, y in pairs if max(abs(x), abs(y)) >= 1e-6), default=0.0)
    return f"{len(pairs)} of {len(na)} numbers differ: max abs {abs_max:.3g}, max rel {rel_max:.3g}"


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    a, b = Path(sys.argv[1]), Path(sys.argv[2])
    sa, sb = sums(a), sums(b)
    for name in sorted(set(sa) | set(sb)):
        if name not in sa or name not in sb:
            print(f"{name}: only in {'B' if name not in sa else 'A'}")
        elif sa[name] != sb[name]:
            print(f"{name}: {compare(a / name, b / name)}")
    same = sum(1 for n in sa if sb.get(n) == sa[n])
    print(f"{same} of {len(sa)} files byte-identical")


if __name__ == "__main__":
    main()
