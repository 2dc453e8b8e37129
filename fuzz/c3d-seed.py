#!/usr/bin/env python3
"""Seeds for c3d_fuzz (called by fuzz/seed-corpus): a C3D file cut to its
first N frames (header word 5 and POINT:FRAMES rewritten, the data section
truncated), so that the fuzzer mutates the header and parameters rather than
a long recording; optionally with the processor byte changed (84 Intel,
85 DEC, 86 MIPS: the numbers then read differently, which is the point).
Usage: c3d-seed.py IN OUT [FRAMES] [PROCESSOR]"""
import struct
import sys

src, dst = sys.argv[1], sys.argv[2]
frames = int(sys.argv[3]) if len(sys.argv) > 3 else 20
proc = int(sys.argv[4]) if len(sys.argv) > 4 else None
b = bytearray(open(src, "rb").read())
pblock = b[0]
pstart = (pblock - 1) * 512
if b[pstart + 3] != 84:
    sys.exit(f"{src}: only Intel files are cut here")
npts, atot, first, last = struct.unpack_from("<4H", b, 2)
scale = struct.unpack_from("<f", b, 12)[0]
dblock = struct.unpack_from("<H", b, 16)[0]
n = min(frames, last - first + 1)
struct.pack_into("<H", b, 8, first + n - 1)
# POINT:FRAMES, when present, would otherwise ask for the whole recording.
groups, at = {}, pstart + 4
while at < (dblock - 1) * 512:
    nl = abs(struct.unpack_from("<b", b, at)[0])
    if nl == 0:
        break
    gid = struct.unpack_from("<b", b, at + 1)[0]
    name = bytes(b[at + 2:at + 2 + nl]).decode("ascii", "replace").upper()
    nxt = struct.unpack_from("<H", b, at + 2 + nl)[0]
    body = at + 4 + nl
    if gid < 0:
        groups[-gid] = name
    elif groups.get(gid) == "POINT" and name == "FRAMES" and b[body] == 2 and b[body + 1] == 0:
        struct.pack_into("<h", b, body + 2, n)
    if nxt == 0:
        break
    at = at + 2 + nl + nxt
width = 4 if scale < 0 else 2
end = (dblock - 1) * 512 + n * (4 * npts + atot) * width
del b[end:]
if proc is not None:
    b[pstart + 3] = proc
open(dst, "wb").write(bytes(b))
