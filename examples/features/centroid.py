#!/usr/bin/env python3
"""A feature program for evitrack, in Python with the standard library only.

Given a dataset folder (the last argument), write on stdout the CSV `frame,centroid_x,centroid_y`,
one row per frame in the order of poses.csv: the centroid (pixels) of the pixels on the body's
side of the frame's mid-grey (half way between its darkest and brightest pixel); empty cells for a
frame of one grey. The same as examples/external_feature.rs. Use it from a scenario with

    [[features.external]]
    command = ["python3", "examples/features/centroid.py"]
    values = ["centroid_x", "centroid_y"]
    missing = "allowed"
"""

import csv
import json
import os
import struct
import sys
import zlib


def read_png_grey(path):
    """Width, height and the grey rows of an 8-bit PNG (grey, grey+alpha, RGB or RGBA)."""
    with open(path, "rb") as f:
        data = f.read()
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        raise ValueError(f"{path}: not a PNG file")
    pos, idat, header = 8, [], None
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos : pos + 4])
        kind = data[pos + 4 : pos + 8]
        body = data[pos + 8 : pos + 8 + length]
        pos += 12 + length
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            break
    width, height, depth, colour, _, _, interlace = header
    channels = {0: 1, 2: 3, 4: 2, 6: 4}.get(colour)
    if depth != 8 or channels is None or interlace != 0:
        raise ValueError(f"{path}: only 8-bit, non-interlaced, non-palette PNGs are read")
    raw = zlib.decompress(b"".join(idat))
    stride = width * channels
    rows, previous, pos = [], bytearray(stride), 0
    for _ in range(height):
        kind, line = raw[pos], bytearray(raw[pos + 1 : pos + 1 + stride])
        pos += 1 + stride
        for i in range(stride):
            left = line[i - channels] if i >= channels else 0
            up = previous[i]
            corner = previous[i - channels] if i >= channels else 0
            if kind == 1:
                line[i] = (line[i] + left) & 255
            elif kind == 2:
                line[i] = (line[i] + up) & 255
            elif kind == 3:
                line[i] = (line[i] + (left + up) // 2) & 255
            elif kind == 4:
                p = left + up - corner
                pa, pb, pc = abs(p - left), abs(p - up), abs(p - corner)
                pred = left if pa <= pb and pa <= pc else (up if pb <= pc else corner)
                line[i] = (line[i] + pred) & 255
        previous = line
        if channels <= 2:
            rows.append(line[::channels])
        else:
            rows.append([(line[i] + line[i + 1] + line[i + 2]) // 3 for i in range(0, stride, channels)])
    return width, height, rows


def centroid(rows, bright):
    lo = min(min(r) for r in rows)
    hi = max(max(r) for r in rows)
    if hi == lo:
        return None
    mid = (lo + hi) / 2
    n = sx = sy = 0
    for y, row in enumerate(rows):
        for x, v in enumerate(row):
            if (v > mid) if bright else (v < mid):
                n += 1
                sx += x
                sy += y
    return (sx / n, sy / n) if n else None


def text(value):
    """The shortest text that reads back to the same float, as Rust's `{}` writes it."""
    s = repr(value)
    return s[:-2] if s.endswith(".0") else s


def main():
    if len(sys.argv) < 2:
        sys.exit("usage: centroid.py DATASET_FOLDER")
    folder = sys.argv[-1]
    with open(os.path.join(folder, "manifest.json")) as f:
        polarity = json.load(f)["camera"].get("polarity", "bright_on_dark")
    with open(os.path.join(folder, "poses.csv"), newline="") as f:
        files = [row["file"] for row in csv.DictReader(f)]
    out = csv.writer(sys.stdout, lineterminator="\n")
    out.writerow(["frame", "centroid_x", "centroid_y"])
    for k, name in enumerate(files):
        _, _, rows = read_png_grey(os.path.join(folder, name))
        c = centroid(rows, polarity == "bright_on_dark")
        out.writerow([k, text(c[0]), text(c[1])] if c else [k, "", ""])


if __name__ == "__main__":
    main()
