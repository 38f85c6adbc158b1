#!/usr/bin/env python3
"""Keeps the first N frames of a C3D file (points and analog), standard library only.

    python3 scripts/trim_c3d.py IN.c3d OUT.c3d N

Patches the header's last frame, POINT:FRAMES, POINT:LONG_FRAMES and TRIAL:ACTUAL_END_FIELD
when present, truncates the data section after N frames and pads it to a 512-byte block.
Intel (84) and DEC (85) files only (little-endian integers). Used to make fixtures/c3d/ from
the ezc3d test files in shared/data/c3d.
"""
import struct
import sys


def walk_parameters(b):
    start = (b[0] - 1) * 512
    p = start + 4
    groups = {}
    while True:
        nlen = struct.unpack('b', b[p:p + 1])[0]
        gid = struct.unpack('b', b[p + 1:p + 2])[0]
        if nlen == 0:
            return
        name = b[p + 2:p + 2 + abs(nlen)].decode('latin1')
        q = p + 2 + abs(nlen)
        off = struct.unpack('<h', b[q:q + 2])[0]
        if gid < 0:
            groups[-gid] = name
        else:
            r = q + 2
            dt = struct.unpack('b', b[r:r + 1])[0]
            nd = b[r + 1]
            yield groups.get(gid, str(gid)), name, dt, list(b[r + 2:r + 2 + nd]), r + 2 + nd
        if off == 0:
            return
        p = q + off


def main():
    src, dst, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
    b = bytearray(open(src, 'rb').read())
    assert b[(b[0] - 1) * 512 + 3] in (84, 85), 'only Intel/DEC C3D files'
    n_points, analog_per_frame, first, last = struct.unpack('<HHHH', b[2:10])
    scale = struct.unpack('<f', b[12:16])[0]
    data_start = struct.unpack('<H', b[16:18])[0]
    word = 4 if scale < 0 else 2
    frame_bytes = n_points * 4 * word + analog_per_frame * word
    assert n <= last - first + 1
    struct.pack_into('<H', b, 8, first + n - 1)
    for group, name, dt, dims, at in walk_parameters(b):
        if (group, name) == ('POINT', 'FRAMES'):
            struct.pack_into('<H', b, at, n)
        elif (group, name) == ('POINT', 'LONG_FRAMES'):
            struct.pack_into('<f', b, at, float(n))
        elif (group, name) == ('TRIAL', 'ACTUAL_END_FIELD'):
            struct.pack_into('<HH', b, at, (first + n - 1) & 0xFFFF, (first + n - 1) >> 16)
    end = (data_start - 1) * 512 + n * frame_bytes
    out = bytes(b[:end])
    out += bytes((-len(out)) % 512)
    open(dst, 'wb').write(out)
    print(f'{src}: {last - first + 1} frames -> {dst}: {n} frames, {len(out)} bytes')


if __name__ == '__main__':
    main()
