#!/usr/bin/env python3
"""Side-by-side crops of OpenEXR images, labelled, for looking at a quality change.

    python3 scripts/crops.py --out crops.png --rect X Y W H [--scale 4] [--exposure 0] \
        input.exr:input before.exr:before after.exr:after reference.exr:reference

Each argument is PATH or PATH:LABEL. Colour is linear premultiplied RGB(A) (Blender multilayer
or plain channels); it is shown over black, scaled by 2^exposure, sRGB-encoded, clamped, and
enlarged by nearest neighbour so pixels stay visible. Needs numpy, OpenEXR and Pillow
(`pip install numpy OpenEXR pillow`).
"""
import argparse

import numpy as np
import OpenEXR
from PIL import Image, ImageDraw, ImageFont


def read_rgb(path):
    channels = OpenEXR.File(path).channels()
    for name, channel in channels.items():
        if channel.pixels.ndim == 3:
            return channel.pixels[..., :3].astype(np.float64)
    def plane(suffix):
        for name, channel in channels.items():
            if name == suffix or name.endswith("Combined." + suffix):
                return channel.pixels.astype(np.float64)
        raise SystemExit(f"{path}: no {suffix} channel (has {', '.join(channels)})")
    return np.stack([plane("R"), plane("G"), plane("B")], -1)


def srgb(x):
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", required=True)
    parser.add_argument("--rect", nargs=4, type=int, metavar=("X", "Y", "W", "H"))
    parser.add_argument("--scale", type=int, default=4)
    parser.add_argument("--exposure", type=float, default=0.0)
    parser.add_argument("--title", default="")
    parser.add_argument("images", nargs="+")
    args = parser.parse_args()
    try:
        font = ImageFont.truetype("DejaVuSans.ttf", 14)
    except OSError:
        font = ImageFont.load_default()
    panels = []
    for spec in args.images:
        path, _, label = spec.partition(":")
        rgb = read_rgb(path) * 2.0 ** args.exposure
        if args.rect:
            x, y, w, h = args.rect
            rgb = rgb[y : y + h, x : x + w]
        pixels = (srgb(rgb) * 255 + 0.5).astype(np.uint8)
        tile = Image.fromarray(pixels).resize(
            (pixels.shape[1] * args.scale, pixels.shape[0] * args.scale), Image.NEAREST
        )
        panels.append((label or path, tile))
    header = 22 if not args.title else 42
    width = sum(t.width for _, t in panels) + 4 * (len(panels) - 1)
    height = max(t.height for _, t in panels) + header
    sheet = Image.new("RGB", (width, height), (40, 40, 40))
    draw = ImageDraw.Draw(sheet)
    if args.title:
        draw.text((4, 2), args.title, fill=(255, 255, 255), font=font)
    x = 0
    for label, tile in panels:
        draw.text((x + 4, header - 19), label, fill=(255, 255, 255), font=font)
        sheet.paste(tile, (x, header))
        x += tile.width + 4
    sheet.save(args.out)


if __name__ == "__main__":
    main()
