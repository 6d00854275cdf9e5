#!/usr/bin/env python3
"""Regenerate the malformed-mesh corpus in this folder (deterministic).

Every file here must be refused by `osim_spine::mesh::read` with an error
that names the file (see tests/mesh_corpus.rs). Run from anywhere:
    python3 tests/corpus/mesh/make_corpus.py
"""
import base64
import os
import random
import struct
import zlib

HERE = os.path.dirname(os.path.abspath(__file__))
rng = random.Random(20240611)


def put(name, data):
    if isinstance(data, str):
        data = data.encode()
    with open(os.path.join(HERE, name), "wb") as f:
        f.write(data)


def garbage(n):
    return bytes(rng.randrange(256) for _ in range(n))


PTS = [(0, 0, 0), (0.01, 0, 0), (0, 0.01, 0), (0, 0, 0.01)]
TRI = [(0, 2, 1), (0, 1, 3), (1, 2, 3), (2, 0, 3)]


def vtp(points_xml, conn="0 2 1 0 1 3 1 2 3 2 0 3", offs="3 6 9 12", npts=4, npolys=4, root_extra=""):
    return f"""<?xml version="1.0"?>
<VTKFile type="PolyData" version="0.1" byte_order="LittleEndian"{root_extra}>
  <PolyData>
    <Piece NumberOfPoints="{npts}" NumberOfPolys="{npolys}">
      <Points>
{points_xml}
      </Points>
      <Polys>
        <DataArray type="Int32" Name="connectivity" format="ascii">{conn}</DataArray>
        <DataArray type="Int32" Name="offsets" format="ascii">{offs}</DataArray>
      </Polys>
    </Piece>
  </PolyData>
</VTKFile>
"""


def ascii_points(pts):
    body = " ".join(f"{x} {y} {z}" for x, y, z in pts)
    return f'        <DataArray type="Float64" NumberOfComponents="3" format="ascii">{body}</DataArray>'


def b64_points(blob):
    return f'        <DataArray type="Float64" NumberOfComponents="3" format="binary">{blob}</DataArray>'


raw = b"".join(struct.pack("<3d", *p) for p in PTS)

# --- VTP ---
put("vtp_garbage.vtp", garbage(700))
put("vtp_text_garbage.vtp", "this is not XML at all <<< >>> &&&\n")
put("vtp_not_polydata.vtp", '<VTKFile type="UnstructuredGrid"><UnstructuredGrid/></VTKFile>\n')
put("vtp_bad_base64.vtp", vtp(b64_points("AAAA!!!!not*base64****")))
zhdr = struct.pack("<4I", 1, len(raw), len(raw), 20)
put("vtp_bad_zlib.vtp", vtp(b64_points(base64.b64encode(zhdr).decode() + base64.b64encode(garbage(20)).decode()),
                           root_extra=' compressor="vtkZLibDataCompressor"'))
comp = zlib.compress(raw)
zhdr = struct.pack("<4I", 1, len(raw) * 2, len(raw) * 2, len(comp))
put("vtp_zlib_wrong_size.vtp", vtp(b64_points(base64.b64encode(zhdr).decode() + base64.b64encode(comp).decode()),
                                  root_extra=' compressor="vtkZLibDataCompressor"'))
hdr = struct.pack("<I", len(raw) + 64)
put("vtp_binary_short.vtp", vtp(b64_points(base64.b64encode(hdr).decode() + base64.b64encode(raw).decode())))
put("vtp_wrong_point_count.vtp", vtp(ascii_points(PTS), npts=5))
put("vtp_nan.vtp", vtp(ascii_points([(0, 0, 0), (0.01, float("nan"), 0), (0, 0.01, 0), (0, 0, 0.01)])))
put("vtp_index_past_end.vtp", vtp(ascii_points(PTS), conn="0 2 1 0 1 3 1 2 7 2 0 3"))
put("vtp_negative_index.vtp", vtp(ascii_points(PTS), conn="0 2 1 0 1 3 1 2 -1 2 0 3"))
put("vtp_bad_offsets.vtp", vtp(ascii_points(PTS), offs="3 6 99 12"))
put("vtp_wrong_poly_count.vtp", vtp(ascii_points(PTS), npolys=9))
put("vtp_huge_count.vtp", vtp(ascii_points(PTS), npts=10**15))
put("vtp_truncated.vtp", vtp(ascii_points(PTS))[:300])
put("vtp_unclosed_appended.vtp", '<VTKFile type="PolyData"><PolyData><Piece NumberOfPoints="1"/></PolyData>\n'
    '<AppendedData encoding="raw">_\x00\x00\x00')
put("vtp_float_connectivity.vtp", vtp(ascii_points(PTS)).replace(
    'type="Int32" Name="connectivity"', 'type="Float32" Name="connectivity"'))
put("empty.vtp", b"")

# --- STL ---
put("stl_garbage.stl", garbage(500))
good = bytearray(b"\0" * 80 + struct.pack("<I", 4))
for t in TRI:
    good += struct.pack("<3f", 0, 0, 0)
    for k in t:
        good += struct.pack("<3f", *PTS[k])
    good += b"\0\0"
put("stl_truncated_binary.stl", bytes(good[:84 + 50 * 2 + 17]))
nan = bytearray(good)
struct.pack_into("<f", nan, 84 + 12 + 4, float("nan"))
put("stl_binary_nan.stl", bytes(nan))
put("stl_ascii_nan.stl", "solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 nan 0\nvertex 0 1 0\n"
    "endloop\nendfacet\nendsolid x\n")
put("stl_ascii_two_vertices.stl", "solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n"
    "endloop\nendfacet\nendsolid x\n")
put("stl_ascii_unclosed.stl", "solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n")
put("stl_short.stl", b"\x01\x02\x03")
put("empty.stl", b"")

# --- OBJ ---
put("obj_garbage.obj", garbage(400))
put("obj_text_garbage.obj", "hello world\nthis is not an obj\n")
put("obj_face_past_end.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 40\n")
put("obj_negative_past_start.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -9\n")
put("obj_nan.obj", "v 0 0 0\nv 1 NaN 0\nv 0 1 0\nf 1 2 3\n")
put("obj_short_face.obj", "v 0 0 0\nv 1 0 0\nf 1 2\n")
put("obj_bad_number.obj", "v 0 0 0\nv 1 0x0 0\nv 0 1 0\nf 1 2 3\n")
put("obj_no_faces.obj", "# only vertices\nv 0 0 0\nv 1 0 0\n")
put("empty.obj", b"")

# --- PLY ---
put("ply_garbage.ply", garbage(300))
head = ("ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
        "property float z\nelement face 4\nproperty list uchar int vertex_indices\nend_header\n")
body = b"".join(struct.pack("<3f", *p) for p in PTS) + b"".join(struct.pack("<B3i", 3, *t) for t in TRI)
put("ply_truncated_binary.ply", head.encode() + body[:60])
put("ply_huge_count.ply", head.replace("vertex 4", "vertex 4000000000").encode() + body)
put("ply_bad_index.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
    "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
    "0 0 0\n1 0 0\n0 1 0\n3 0 1 5\n")
put("ply_nan.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
    "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
    "0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n")
put("ply_no_end_header.ply", "ply\nformat ascii 1.0\nelement vertex 3\n")
put("ply_bad_format.ply", "ply\nformat binary_middle_endian 1.0\nend_header\n")
put("empty.ply", b"")
