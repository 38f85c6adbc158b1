#!/usr/bin/env python3
"""Convert ICT-FaceKit expression / identity OBJs into the compact softcap pose-delta format.

usage: ict_fixture.py SRC_DIR OUT_FILE [--identities]

Each OBJ must have the same vertex count and order as SRC_DIR/neutral.obj (ICT-FaceKit meshes
are in vertex correspondence). Output ("SCPOSE01" format, little endian, documented in
fixtures/ict-face/README.md):

    magic     8 bytes  b"SCPOSE01"
    n_verts   u32      vertices of the neutral mesh
    n_poses   u32
    scale     f32      OBJ length units (cm) per quantisation step (2e-4)
    per pose: name_len u16, name utf-8, nnz u32,
              nnz x (vertex u32, dx i16, dy i16, dz i16)   delta = q * scale, from neutral
Vertices whose delta is below half a quantisation step in every axis are omitted.
"""
import glob
import os
import struct
import sys

SCALE = 2e-4


def read_vertices(path):
    out = []
    with open(path) as f:
        for line in f:
            if line.startswith("v "):
                out.append(tuple(float(t) for t in line.split()[1:4]))
    return out


def main():
    src, out = sys.argv[1], sys.argv[2]
    sub = "identities" if "--identities" in sys.argv else "expressions"
    neutral = read_vertices(os.path.join(src, "neutral.obj"))
    files = sorted(glob.glob(os.path.join(src, sub, "*.obj")))
    blob = bytearray(b"SCPOSE01")
    blob += struct.pack("<IIf", len(neutral), len(files), SCALE)
    for path in files:
        verts = read_vertices(path)
        if len(verts) != len(neutral):
            sys.exit(f"{path}: {len(verts)} vertices, neutral has {len(neutral)}")
        entries = []
        for i, (p, q) in enumerate(zip(verts, neutral)):
            d = [round((a - b) / SCALE) for a, b in zip(p, q)]
            if any(d):
                if max(abs(x) for x in d) > 32767:
                    sys.exit(f"{path}: vertex {i} delta exceeds the i16 range")
                entries.append(struct.pack("<Ihhh", i, *d))
        name = os.path.splitext(os.path.basename(path))[0].encode()
        blob += struct.pack("<H", len(name)) + name + struct.pack("<I", len(entries))
        blob += b"".join(entries)
    with open(out + ".tmp", "wb") as f:
        f.write(blob)
    os.replace(out + ".tmp", out)
    print(f"{out}: {len(files)} poses, {len(blob)} bytes")


if __name__ == "__main__":
    main()
