"""Reconstruction against OIDN at equal paths, in SSIM and FLIP, on stochastic frames with guides.

    python3 bench/oidn_quality.py --camera CAMERA.json --reference REF.exr --out DIR FRAMES.exr...

For each stochastic-frames file (docs/STOCHASTIC.md; the scene renderer writes them with
`spreadlet-scene render SCENE --stochastic F.exr --spp N`, guides included) it writes and
scores against the reference, with `spreadlet compare`:
- `spreadlet reconstruct` of the frames;
- OIDN (filter RT, hdr, albedo and normal guides, quality high, as
  `../shared/tools/oidn_peer.py` runs it on Cycles' renders) on the frames' plain per-pixel
  average, with the samples' mean albedo and normal as guides: what a renderer's user gets
  from the same samples with the real lens and shutter and a denoiser;
- the plain average itself.

Prints a Markdown table (SSIM / FLIP mean / FLIP p99 / mean luminance ratio). Needs numpy,
OpenEXR and pyoidn (`pip install pyoidn`).
"""
import argparse
import os
import re
import subprocess
import sys

import numpy as np
import OpenEXR


def read_frames(path):
    """Per-pixel means of a stochastic-frames file: colour (RGBA), albedo, normal; and spp."""
    part = OpenEXR.File(path).parts[0]
    fields = dict(f.split("=") for f in str(part.header.get("spreadlet", "")).split()[1:] if "=" in f)
    w, h, spp = int(fields["width"]), int(fields["height"]), int(fields["spp"])
    ch = part.channels

    def channel(name):
        # The OpenEXR module groups R, G, B, A and albedo.R, .G, .B into one array each.
        if name in ch:
            return ch[name].pixels.astype(np.float32)
        base, _, c = name.rpartition(".")
        group = ch.get(base or "RGBA")
        if group is None:
            sys.exit(f"{path}: no channel {name}")
        return group.pixels[..., ("RGBA" if not base else "RGB").index(c or name)].astype(np.float32)

    def mean(names):
        stacked = np.stack([channel(n) for n in names], -1)
        return stacked.reshape(spp, h, w, len(names)).mean(axis=0)

    if "albedo" not in ch and "albedo.R" not in ch:
        sys.exit(f"{path}: no denoiser guides (albedo, normal)")
    rgba = mean(["R", "G", "B", "A"])
    albedo = mean(["albedo.R", "albedo.G", "albedo.B"])
    normal = mean(["normal.X", "normal.Y", "normal.Z"])
    return rgba, albedo, normal, spp


def write_rgba(path, rgba):
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    chans = {k: np.ascontiguousarray(rgba[..., i].astype(np.float32)) for i, k in enumerate("RGBA")}
    OpenEXR.File(header, chans).write(path)


def oidn(rgba, albedo, normal):
    import pyoidn

    rgb = np.ascontiguousarray(np.nan_to_num(np.maximum(rgba[..., :3], 0)).astype(np.float32))
    albedo = np.ascontiguousarray(np.clip(albedo, 0, 1).astype(np.float32))
    normal = np.ascontiguousarray(np.clip(normal, -1, 1).astype(np.float32))
    out = pyoidn.denoise(rgb, albedo, normal, hdr=True, clean_aux=False, quality="high")
    return np.concatenate([out, rgba[..., 3:4]], -1)


def score(spreadlet, image, reference):
    line = subprocess.run(
        [spreadlet, "compare", image, reference], check=True, capture_output=True, text=True
    ).stdout.strip().splitlines()[-1]
    get = lambda key: float(re.search(key + r" ([0-9.]+)", line).group(1))
    return get("SSIM"), get("FLIP mean"), get("p99"), get("mean luminance ratio")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("frames", nargs="+")
    ap.add_argument("--camera", required=True)
    ap.add_argument("--reference", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--spreadlet", default="target/release/spreadlet")
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    print("| frames | spp | method | SSIM | FLIP mean | FLIP p99 | mean ratio |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for frames in args.frames:
        name = os.path.splitext(os.path.basename(frames))[0]
        rgba, albedo, normal, spp = read_frames(frames)
        outputs = {
            "spreadlet reconstruct": os.path.join(args.out, f"{name}_reconstruct.exr"),
            "OIDN on the average": os.path.join(args.out, f"{name}_oidn.exr"),
            "plain average": os.path.join(args.out, f"{name}_average.exr"),
        }
        subprocess.run(
            [args.spreadlet, "reconstruct", "--input", frames, "--camera", args.camera,
             "--out", outputs["spreadlet reconstruct"]],
            check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )
        write_rgba(outputs["OIDN on the average"], oidn(rgba, albedo, normal))
        write_rgba(outputs["plain average"], rgba)
        for method, path in outputs.items():
            s, fm, fp, lum = score(args.spreadlet, path, args.reference)
            print(f"| {name} | {spp} | {method} | {s:.4f} | {fm:.4f} | {fp:.3f} | {lum:.3f} |", flush=True)


if __name__ == "__main__":
    main()
