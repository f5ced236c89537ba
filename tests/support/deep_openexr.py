"""The OpenEXR library's own view of deep files, for tests/deep_input.rs: an independent reader
and writer (the OpenEXR Python package, which wraps the C++ library) to check spreadlet's deep
scanline reader and writer against.

    python deep_openexr.py write DIR    # deep files written by the library + DIR/expected.json
    python deep_openexr.py read FILE    # FILE's samples as JSON on stdout

JSON per file: {"width", "height", "channels": [names], "pixels": [[[values per channel] per
sample] per pixel, row-major]}.
"""
import json
import sys

import numpy as np
import OpenEXR

# The channels, in the order the JSON lists them.
CHANNELS = ["R", "G", "B", "A", "Z", "ZBack", "motion.x", "motion.y"]


def pattern(width, height):
    """0 to 3 samples per pixel, front to back, with values that are exact in half."""
    pixels = []
    for y in range(height):
        for x in range(width):
            samples = []
            for k in range((x + 2 * y) % 4):
                a = 0.25 + 0.25 * k
                z = 1.0 + 0.5 * k + 0.125 * x
                samples.append([0.5 * a, 0.25 * a * (x % 3), 0.125 * a * y, a, z,
                                z + 0.25 * (k % 2), x - 2.0, 0.5 * y])
            pixels.append(samples)
    return pixels


def write(directory):
    width, height = 7, 5
    pixels = pattern(width, height)
    expected = {}
    for name, compression, half in [
        ("lib_none.exr", OpenEXR.NO_COMPRESSION, False),
        ("lib_rle.exr", OpenEXR.RLE_COMPRESSION, False),
        ("lib_zips.exr", OpenEXR.ZIPS_COMPRESSION, False),
        ("lib_half_rle.exr", OpenEXR.RLE_COMPRESSION, True),
    ]:
        channels = {}
        for c, channel in enumerate(CHANNELS):
            dtype = np.float16 if half and channel in "RGBA" else np.float32
            plane = np.empty((height, width), dtype=object)
            for i, samples in enumerate(pixels):
                plane[i // width, i % width] = np.array([s[c] for s in samples], dtype=dtype)
            channels[channel] = OpenEXR.Channel(plane)
        header = {"type": OpenEXR.deepscanline, "compression": compression}
        OpenEXR.File(header, channels).write(f"{directory}/{name}")
        expected[name] = {"width": width, "height": height, "channels": CHANNELS,
                          "pixels": pixels}
    with open(f"{directory}/expected.json", "w") as f:
        json.dump(expected, f)


def read(path):
    f = OpenEXR.File(path, separate_channels=True)
    header = f.header()
    if header["type"] != OpenEXR.deepscanline:
        raise SystemExit(f"{path} is not deep scanline: {header['type']}")
    (x0, y0), (x1, y1) = header["dataWindow"]
    width, height = int(x1 - x0 + 1), int(y1 - y0 + 1)
    planes = f.channels()
    names = [n for n in CHANNELS if n in planes]
    pixels = []
    for y in range(height):
        for x in range(width):
            per_channel = [planes[n].pixels[y, x] for n in names]
            count = 0 if per_channel[0] is None else len(per_channel[0])
            pixels.append([[float(per_channel[c][k]) for c in range(len(names))]
                           for k in range(count)])
    json.dump({"width": width, "height": height, "channels": names, "pixels": pixels},
              sys.stdout)


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "write":
        write(sys.argv[2])
    elif len(sys.argv) == 3 and sys.argv[1] == "read":
        read(sys.argv[2])
    else:
        raise SystemExit(__doc__)
