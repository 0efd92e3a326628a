"""What a report's maps paint, counted: for each map of report.html (the PNGs it embeds), the
painted pixels and the share in the "missing material" blue and the "not judged" grey.

    python3 tools/bench/map_pixels.py out/demo/report.html

Only the standard library: the PNGs are 8-bit RGBA, decoded here."""

import base64
import re
import struct
import sys
import zlib

MISSING = (0, 0, 255)
NOT_JUDGED = (222, 222, 222)


def rgba(png: bytes):
    """The pixels of an 8-bit RGBA PNG, row by row."""
    pos, width, height, idat = 8, 0, 0, b""
    while pos < len(png):
        (length,) = struct.unpack(">I", png[pos:pos + 4])
        kind, body = png[pos + 4:pos + 8], png[pos + 8:pos + 8 + length]
        if kind == b"IHDR":
            width, height, depth, colour = struct.unpack(">IIBB", body[:10])
            assert (depth, colour) == (8, 6), "8-bit RGBA expected"
        elif kind == b"IDAT":
            idat += body
        pos += 12 + length
    raw, stride, prev, out = zlib.decompress(idat), width * 4, bytearray(width * 4), []
    for row in range(height):
        f, line = raw[row * (stride + 1)], bytearray(raw[row * (stride + 1) + 1:(row + 1) * (stride + 1)])
        for i in range(stride):
            a = line[i - 4] if i >= 4 else 0
            b, c = prev[i], prev[i - 4] if i >= 4 else 0
            if f == 1:
                line[i] = (line[i] + a) & 255
            elif f == 2:
                line[i] = (line[i] + b) & 255
            elif f == 3:
                line[i] = (line[i] + (a + b) // 2) & 255
            elif f == 4:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                line[i] = (line[i] + (a if pa <= pb and pa <= pc else b if pb <= pc else c)) & 255
        out.append(bytes(line))
        prev = line
    return width, height, out


def count(png: bytes):
    width, height, rows = rgba(png)
    painted = missing = grey = 0
    for line in rows:
        for k in range(width):
            r, g, b, a = line[4 * k:4 * k + 4]
            if a == 0:
                continue
            painted += 1
            missing += (r, g, b) == MISSING
            grey += (r, g, b) == NOT_JUDGED
    return painted, missing, grey


def main():
    html = open(sys.argv[1], encoding="utf-8").read()
    total = [0, 0, 0]
    worst = 0.0
    for k, data in enumerate(re.findall(r"data:image/png;base64,([A-Za-z0-9+/=]+)", html)):
        p, m, g = count(base64.b64decode(data))
        if p == 0:
            continue
        total = [total[0] + p, total[1] + m, total[2] + g]
        worst = max(worst, m / p)
    p, m, g = total
    print(f"{p} painted pixels: {100 * m / p:.2f} % missing blue (worst map {100 * worst:.2f} %), "
          f"{100 * g / p:.2f} % not-judged grey")


if __name__ == "__main__":
    main()
