"""Reconstruction's time against Intel Open Image Denoise (OIDN) on the same machine, interleaved.

    python3 bench/reconstruct_vs_oidn.py FRAMES.exr CAMERA.json [--rounds N] [--spreadlet BIN] \
        [--backend cpu|auto]

For each round, in turn:
- spreadlet: `spreadlet reconstruct --input FRAMES --camera CAMERA --backend cpu --stats` as a
  process (on the CPU, as OIDN runs here, and as `against_blender.py` times synthesis: `auto`
  first looks for a GPU, and on a machine with only Mesa's software Vulkan adapter that look
  alone costs about 60 ms a process before it settles on the CPU); its
  wall time (the whole process: reading, databases from the cache, writing) and the `--stats`
  total (what a library caller waits for per call, the databases already loaded);
- OIDN: one `pyoidn.denoise` call (filter RT, hdr, albedo and normal guides, quality high, as
  `../shared/tools/oidn_peer.py` runs it) on an image of the frames' size, its colour the mean of
  the frames' samples and its guides their mean albedo and normal, after one warm-up call on a
  small image. OIDN's time does not depend on the image's content.

Prints each run and the medians, ranges and the ratio spreadlet / OIDN. Needs numpy, OpenEXR
and pyoidn (`pip install pyoidn`; the wheel ships libOpenImageDenoise).
"""
import argparse
import json
import os
import subprocess
import tempfile
import time

import numpy as np

from oidn_quality import read_frames  # the frames' per-pixel means, beside this script


def oidn_seconds(rgb, albedo, normal):
    import pyoidn

    rgb = np.ascontiguousarray(np.nan_to_num(np.maximum(rgb, 0)).astype(np.float32))
    albedo = np.ascontiguousarray(np.clip(albedo, 0, 1).astype(np.float32))
    normal = np.ascontiguousarray(np.clip(normal, -1, 1).astype(np.float32))
    start = time.time()
    pyoidn.denoise(rgb, albedo, normal, hdr=True, clean_aux=False, quality="high")
    return time.time() - start


def spreadlet_seconds(binary, frames, camera, workdir, backend):
    out, stats = os.path.join(workdir, "out.exr"), os.path.join(workdir, "stats.json")
    start = time.time()
    subprocess.run(
        [binary, "reconstruct", "--input", frames, "--camera", camera, "--out", out, "--stats", stats,
         "--backend", backend],
        check=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    wall = time.time() - start
    total_ms = json.load(open(stats))["reconstruction"]["times"]["total_ms"]
    return wall, total_ms / 1000.0


def summary(values):
    v = sorted(values)
    return f"{v[len(v) // 2]:.3f} s ({v[0]:.3f}-{v[-1]:.3f})"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("frames")
    ap.add_argument("camera")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--spreadlet", default="target/release/spreadlet")
    ap.add_argument("--backend", default="cpu", choices=["cpu", "auto"],
                    help="spreadlet's backend (default cpu: both tools on the CPU)")
    args = ap.parse_args()
    rgba, albedo, normal, _ = read_frames(args.frames)
    rgb = rgba[..., :3]
    oidn_seconds(rgb[:64, :64].copy(), albedo[:64, :64].copy(), normal[:64, :64].copy())
    process, call, oidn = [], [], []
    with tempfile.TemporaryDirectory() as workdir:
        for r in range(args.rounds):
            wall, per_call = spreadlet_seconds(args.spreadlet, args.frames, args.camera, workdir,
                                               args.backend)
            process.append(wall)
            call.append(per_call)
            oidn.append(oidn_seconds(rgb, albedo, normal))
            print(f"round {r + 1}: spreadlet process {wall:.3f} s, per call {per_call:.3f} s; "
                  f"OIDN {oidn[-1]:.3f} s", flush=True)
    med = lambda v: sorted(v)[len(v) // 2]
    print(f"spreadlet per process {summary(process)}, per call {summary(call)}; OIDN {summary(oidn)}")
    print(f"ratio to OIDN: per call {med(call) / med(oidn):.2f}, per process {med(process) / med(oidn):.2f}")


if __name__ == "__main__":
    main()
