"""Reconstruction's time against Intel Open Image Denoise (OIDN) on the same machine, interleaved.

    python3 bench/reconstruct_vs_oidn.py FRAMES.exr CAMERA.json [--rounds N] [--spreadlet BIN] \
        [--backend cpu|auto]

Both tools are timed alike, three ways, each round in turn:
- **per process** (what a farm job pays per frame): `spreadlet reconstruct --input FRAMES
  --camera CAMERA --backend cpu --stats` as a process (reading the frames, the databases from
  the cache, writing the image), against `bench/oidn_denoise.py` as a process (the interpreter
  and its imports, reading a 512 x 512 render with its albedo and normal passes, the denoise,
  writing the image);
- **first call** (a fresh process's first frame): spreadlet's `--stats` total of that process,
  against the first `pyoidn.denoise` call of the OIDN process (which includes OIDN making its
  device and filter);
- **warm call** (what a library or add-on caller waits for from the second call on):
  spreadlet's `--stats` totals of frames 2 and 3 of a three-frame `--frames` run over the same
  file, against a `pyoidn.denoise` call in this script after a warm-up call.

spreadlet runs on the CPU (`--backend cpu`), as OIDN runs here and as `against_blender.py` times
synthesis: `auto` first looks for a GPU, and on a machine with only Mesa's software Vulkan
adapter that look alone costs tens of ms a process. OIDN's input is the frames' plain
per-pixel mean, with their mean albedo and normal as guides (RT filter, hdr, quality high, as
`../shared/tools/oidn_peer.py` runs it); its time does not depend on the image's content.

Prints each round and the medians, ranges and ratios spreadlet / OIDN. Needs numpy, OpenEXR and
pyoidn (`pip install pyoidn`; the wheel ships libOpenImageDenoise).
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

from oidn_quality import read_frames  # the frames' per-pixel means, beside this script


def oidn_seconds(rgb, albedo, normal):
    import pyoidn

    rgb = np.ascontiguousarray(np.nan_to_num(np.maximum(rgb, 0)).astype(np.float32))
    albedo = np.ascontiguousarray(np.clip(albedo, 0, 1).astype(np.float32))
    normal = np.ascontiguousarray(np.clip(normal, -1, 1).astype(np.float32))
    start = time.perf_counter()
    pyoidn.denoise(rgb, albedo, normal, hdr=True, clean_aux=False, quality="high")
    return time.perf_counter() - start


def write_render(path, rgb, albedo, normal):
    """The noisy render a renderer's user denoises: colour with albedo and normal passes."""
    import OpenEXR

    chans = {}
    for prefix, image, names in (("", rgb, "RGB"), ("albedo.", albedo, "RGB"),
                                 ("normal.", normal, "XYZ")):
        for i, c in enumerate(names):
            chans[prefix + c] = np.ascontiguousarray(image[..., i].astype(np.float32))
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, chans).write(path)


def oidn_process_seconds(render, workdir):
    """(process wall, first call) of bench/oidn_denoise.py on `render`."""
    script = os.path.join(os.path.dirname(os.path.abspath(__file__)), "oidn_denoise.py")
    start = time.perf_counter()
    out = subprocess.run([sys.executable, script, render, os.path.join(workdir, "oidn.exr")],
                         check=True, capture_output=True, text=True)
    wall = time.perf_counter() - start
    return wall, json.loads(out.stdout.strip().splitlines()[-1])["call_s"]


def spreadlet_seconds(binary, frames, camera, workdir, backend):
    """(process wall, first call) of one `spreadlet reconstruct` process."""
    out, stats = os.path.join(workdir, "out.exr"), os.path.join(workdir, "stats.json")
    start = time.perf_counter()
    subprocess.run(
        [binary, "reconstruct", "--input", frames, "--camera", camera, "--out", out, "--stats", stats,
         "--backend", backend],
        check=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    wall = time.perf_counter() - start
    total_ms = json.load(open(stats))["reconstruction"]["times"]["total_ms"]
    return wall, total_ms / 1000.0


def spreadlet_warm_seconds(binary, sequence, camera, workdir, backend):
    """The calls after the first of a three-frame run over `sequence` (a #### pattern)."""
    subprocess.run(
        [binary, "reconstruct", "--input", sequence, "--frames", "1-3", "--camera", camera,
         "--out", os.path.join(workdir, "warm_####.exr"),
         "--stats", os.path.join(workdir, "warm_####.json"), "--backend", backend],
        check=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    stats = lambda k: json.load(open(os.path.join(workdir, f"warm_{k:04d}.json")))
    return [stats(k)["reconstruction"]["times"]["total_ms"] / 1000.0 for k in (2, 3)]


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
    times = {k: [] for k in ("process", "first", "warm", "oidn_process", "oidn_first",
                             "oidn_warm")}
    with tempfile.TemporaryDirectory() as workdir:
        render = os.path.join(workdir, "render.exr")
        write_render(render, rgb, albedo, normal)
        for k in (1, 2, 3):
            os.symlink(os.path.abspath(args.frames), os.path.join(workdir, f"frames_{k:04d}.exr"))
        sequence = os.path.join(workdir, "frames_####.exr")
        for r in range(args.rounds):
            wall, first = spreadlet_seconds(args.spreadlet, args.frames, args.camera, workdir,
                                            args.backend)
            times["process"].append(wall)
            times["first"].append(first)
            wall, first = oidn_process_seconds(render, workdir)
            times["oidn_process"].append(wall)
            times["oidn_first"].append(first)
            warm = spreadlet_warm_seconds(args.spreadlet, sequence, args.camera, workdir,
                                          args.backend)
            times["warm"].extend(warm)
            times["oidn_warm"].append(oidn_seconds(rgb, albedo, normal))
            print(f"round {r + 1}: spreadlet process {times['process'][-1]:.3f} s, first call "
                  f"{times['first'][-1]:.3f} s, warm calls {warm[0]:.3f} {warm[1]:.3f} s; OIDN "
                  f"process {times['oidn_process'][-1]:.3f} s, first call "
                  f"{times['oidn_first'][-1]:.3f} s, warm call {times['oidn_warm'][-1]:.3f} s",
                  flush=True)
    med = lambda v: sorted(v)[len(v) // 2]
    for what, ours, theirs in (("per process", "process", "oidn_process"),
                               ("first call", "first", "oidn_first"),
                               ("warm call", "warm", "oidn_warm")):
        print(f"{what}: spreadlet {summary(times[ours])}, OIDN {summary(times[theirs])}, "
              f"ratio {med(times[ours]) / med(times[theirs]):.2f}")


if __name__ == "__main__":
    main()
