"""spreadlet synth against Blender's compositor on the same inputs, timed side by side.

For every input (both shared Blender examples, the built-in scenes rendered at 512 x 512 —
`rain` through its double Gauss, which Blender's Defocus takes as the thin lens of the same focal
length and f-number — and the hard cases with motion: a car on a road, a spinning ball, a fast
box, a slanted floor, a camera pan and a rolling wheel), each round runs the whole `spreadlet synth` process (EXR read, database load,
synthesis, EXR write) and then Blender's compositor on the same G-buffer
(`bench/blender_compositor.py`: Vector Blur, then Defocus, calibrated to the lens): the
Blender application (3.4 from Debian) and, with `--bpy`, current Blender as the `bpy` module
(5.x, its rewritten compositor). Inputs go round-robin and the tools alternate, so a change of
the machine's load hits all alike. Reports medians, spreads (min-max) and the ratios of medians
from one run, per call (spreadlet's synthesis against Blender's render call) and per process,
each against the faster Blender; spreadlet's per-stage breakdown (from its --stats); and every
result's SSIM and FLIP against the reference. With `--warm-calls`, each tool's warm calls too
(the second and third in one process, as an add-on caller rendering a sequence waits for each
frame after the first), timed in processes of their own so the per-process figures stay whole.

    python3 bench/against_blender.py --out target/against-blender [--rounds 3] [--ref-spp 256] \
        [--cycles OUT] \
        [--bpy target/bpy-env/bin/python] [--warm-calls]

Needs `target/release/{spreadlet,spreadlet-scene}` (cargo build --release), Blender
(`apt-get install blender`) and, for `--bpy`, a Python with `bpy` (`pip install bpy==5.0.1` on
Python 3.11, as `.ci/run` installs it in target/bpy-env) and numpy and OpenEXR in the Python
that runs this script (5.x's Defocus searches a window of its "Max Blur" around every pixel,
so it gets the frame's largest CoC radius, read from the depth pass, instead of 3.4's 128).
Writes OUT/results.json and OUT/results.md.
"""

import argparse
import json
import math
import os
import re
import statistics
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
HARD = os.path.join(ROOT, "scene", "scenes", "hard")
SCENES = ["bokeh", "crossing", "occluder", "rotating", "physical", "studio", "rain"] + [
    os.path.join(HARD, f"{name}.json")
    for name in ("car-on-road", "spinning-disc", "fast-box", "slanted-floor", "camera-pan",
                 "rolling-wheel", "approaching-car")]
STAGES = ["read_input", "database", "classify", "splat", "integrate", "composite",
          "write_output"]


def run(cmd, **kw):
    out = subprocess.run(cmd, capture_output=True, text=True, **kw)
    if out.returncode != 0:
        sys.exit(f"failed ({out.returncode}): {' '.join(cmd)}\n{out.stderr[-2000:]}")
    return out


def inputs(args, bin_dir, work):
    """(name, G-buffer, camera.json, reference) of every input, rendering the scenes once."""
    found = []
    shared = args.shared
    wanted = lambda name: not args.only or name in args.only.split(",")
    for name in ("comets", "fence"):
        if not wanted(name):
            continue
        d = os.path.join(shared, name)
        if os.path.exists(os.path.join(d, "input.exr")):
            found.append((name, os.path.join(d, "input.exr"), os.path.join(d, "camera.json"),
                          os.path.join(d, "reference.exr")))
        else:
            print(f"no {d}/input.exr: {name} is skipped", file=sys.stderr)
    for scene in SCENES:
        name = os.path.splitext(os.path.basename(scene))[0]
        if not wanted(name):
            continue
        d = os.path.join(work, name)
        os.makedirs(d, exist_ok=True)
        g, cam, ref = (os.path.join(d, f) for f in ("g.exr", "camera.json", "reference.exr"))
        if not (os.path.exists(g) and os.path.exists(ref)):
            print(f"rendering {name} at {args.size} px ({args.ref_spp} spp reference)",
                  file=sys.stderr)
            run([os.path.join(bin_dir, "spreadlet-scene"), "render", scene, "--width",
                 str(args.size), "--height", str(args.size), "--gbuffer", g, "--reference", ref,
                 "--ref-spp", str(args.ref_spp), "--camera-out", cam, "--quiet"])
        found.append((name, g, cam, ref))
    # Cycles scenes of our own (bench/cycles/cycles_frames.sh): each folder's pinhole input.exr,
    # camera.json and reference.exr.
    for d in sorted(os.listdir(args.cycles)) if args.cycles else []:
        d = os.path.join(args.cycles, d)
        files = [os.path.join(d, f) for f in ("input.exr", "camera.json", "reference.exr")]
        name = "cycles-" + os.path.basename(d)
        if all(os.path.exists(f) for f in files) and wanted(name):
            found.append((name, *files))
    return found


def time_spreadlet(bin_dir, g, cam, out, stats):
    t = time.perf_counter()
    run([os.path.join(bin_dir, "spreadlet"), "synth", "--input", g, "--camera", cam, "--out",
         out, "--backend", "cpu", "--stats", stats, "-q"])
    wall = time.perf_counter() - t
    with open(stats) as f:
        s = json.load(f)
    stages = {k: s["times_ms"].get(k) for k in ("read_input", "database", "write_output")}
    for k in ("classify", "splat", "integrate", "composite"):
        stages[k] = s["synthesis"]["times"].get(f"{k}_ms")
    return wall, stages, s["synthesis"]["times"]["total_ms"] / 1000.0


def time_spreadlet_warm(bin_dir, g, cam, work):
    """spreadlet's warm calls: frames 2 and 3 of one `--frames 1-3` process over the same
    G-buffer (its `--stats` totals), what an add-on or library caller waits for on each frame
    after the first; seconds."""
    os.makedirs(work, exist_ok=True)
    for frame in (1, 2, 3):
        link = os.path.join(work, f"g{frame:04}.exr")
        if os.path.lexists(link):
            os.remove(link)
        os.symlink(os.path.abspath(g), link)
    run([os.path.join(bin_dir, "spreadlet"), "synth", "--input", os.path.join(work, "g####.exr"),
         "--frames", "1-3", "--camera", cam, "--out", os.path.join(work, "o####.exr"),
         "--backend", "cpu", "--stats", os.path.join(work, "s####.json"), "-q"])
    calls = []
    for frame in (2, 3):
        with open(os.path.join(work, f"s{frame:04}.json")) as f:
            calls.append(json.load(f)["synthesis"]["times"]["total_ms"] / 1000.0)
    return calls


def time_blender_warm(command, g, cam, out, extra=()):
    """Blender's warm render calls: the second and third of three in one process; seconds."""
    done = run(command + [os.path.join(ROOT, "bench", "blender_compositor.py"), "--",
                          "--input", g, "--camera", cam, "--out", out, "--calls", "3", *extra])
    m = re.search(r"further render calls ([0-9. ]+) s", done.stdout + done.stderr)
    if not m:
        sys.exit(f"no further render-call times in Blender's output:\n{done.stdout[-2000:]}")
    return [float(v) for v in m.group(1).split()]


def time_blender(command, g, cam, out, extra=()):
    """Runs bench/blender_compositor.py with `command` (the Blender application with its
    flags, or a Python with bpy); (process wall time, render call time), seconds."""
    t = time.perf_counter()
    done = run(command + [os.path.join(ROOT, "bench", "blender_compositor.py"), "--",
                          "--input", g, "--camera", cam, "--out", out, *extra])
    wall = time.perf_counter() - t
    m = re.search(r"composite ([0-9.]+) s \(render call\)", done.stdout + done.stderr)
    if not m:
        sys.exit(f"no render-call time in Blender's output:\n{done.stdout[-2000:]}")
    return wall, float(m.group(1))


def largest_coc_px(g, cam_path):
    """The largest thin-lens CoC radius (px, Blender's fixed field of view) over the depth
    pass of G-buffer `g`, or None without defocus: what a careful Blender 5 user sets as the
    Defocus node's Max Blur."""
    with open(cam_path) as f:
        cam = json.load(f)
    if not cam.get("focus_distance") or not cam.get("f_stop"):
        return None
    try:
        import numpy as np
        import OpenEXR
    except ImportError:
        sys.exit("--bpy needs numpy and OpenEXR in this Python (pip install numpy OpenEXR)")
    channels = OpenEXR.File(g).parts[0].channels
    name = next((n for n in channels if n == "Z" or n.endswith("Depth.Z")), None)
    if name is None:
        sys.exit(f"{g}: no depth channel")
    z = np.maximum(channels[name].pixels.astype(np.float64), 1e-6)
    f_m, n, zf = cam["focal_length_mm"] * 1e-3, cam["f_stop"], cam["focus_distance"]
    unit_m = cam.get("scene_unit_mm", 1000.0) * 1e-3
    r = 0.5 * (f_m / n) * f_m * np.abs(z * unit_m - zf * unit_m) / (z * unit_m * zf * unit_m)
    return float(r.max() / (cam["sensor_width_mm"] * 1e-3) * cam["width"])


def scores(bin_dir, image, reference):
    out = run([os.path.join(bin_dir, "spreadlet"), "compare", image, reference, "--json"])
    d = json.loads(out.stdout)
    return {"ssim": d["ssim"], "flip_mean": d["flip_mean"], "flip_p99": d["flip_p99"]}


def summary(values):
    return {"median": statistics.median(values), "min": min(values), "max": max(values)}


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--size", type=int, default=512)
    p.add_argument("--ref-spp", type=int, default=256)
    p.add_argument("--blender", default="blender")
    p.add_argument("--bpy", help="a Python with the bpy module (Blender 5.x) to time as well")
    p.add_argument("--only", help="comma-separated input names to run (default: all)")
    p.add_argument("--cycles", help="a folder of Cycles scenes (bench/cycles/cycles_frames.sh's "
                   "OUT): each SCENE/ with input.exr, camera.json and reference.exr joins as "
                   "cycles-SCENE")
    p.add_argument("--bin", default=os.path.join(ROOT, "target", "release"))
    p.add_argument("--shared", default=os.path.join(ROOT, "..", "shared", "examples"))
    p.add_argument("--warm-calls", action="store_true",
                   help="also time each tool's warm calls (the second and third in one process: "
                   "spreadlet frames 2-3 of a --frames run, Blender's render call twice more), "
                   "in processes of their own, and report their ratio")
    args = p.parse_args()
    os.makedirs(args.out, exist_ok=True)
    items = inputs(args, args.bin, os.path.join(args.out, "inputs"))
    if not items:
        sys.exit("no inputs (see --only and --shared)")
    tools = {"blender": [args.blender, "-b", "--factory-startup", "--python-exit-code", "1",
                         "--python"]}
    if args.bpy:
        tools["blender5"] = [args.bpy]
    extra = {name: {} for name, *_ in items}
    if args.bpy:
        for name, g, cam, _ in items:
            coc = largest_coc_px(g, cam)
            if coc is not None:
                extra[name]["blender5"] = ["--blur-max", f"{math.ceil(coc) + 1:.0f}"]
    kinds = ("call", "process", "warm") if args.warm_calls else ("call", "process")
    times = {name: {"spreadlet": [], "spreadlet_call": [], "stages": [],
                    **({"spreadlet_warm": []} if args.warm_calls else {}),
                    **{f"{t}_{k}": [] for t in tools for k in kinds}}
             for name, *_ in items}

    def one_round(record):
        for name, g, cam, _ in items:
            d = os.path.join(args.out, name)
            os.makedirs(d, exist_ok=True)
            wall, stages, call = time_spreadlet(args.bin, g, cam,
                                                os.path.join(d, "spreadlet.exr"),
                                                os.path.join(d, "stats.json"))
            t = times[name]
            if record:
                t["spreadlet"].append(wall)
                t["spreadlet_call"].append(call)
                t["stages"].append(stages)
            for tool, command in tools.items():
                process, call = time_blender(command, g, cam, os.path.join(d, f"{tool}.exr"),
                                             extra[name].get(tool, ()))
                if record:
                    t[f"{tool}_process"].append(process)
                    t[f"{tool}_call"].append(call)
            if not args.warm_calls:
                continue
            warm = time_spreadlet_warm(args.bin, g, cam, os.path.join(d, "warm"))
            if record:
                t["spreadlet_warm"] += warm
            for tool, command in tools.items():
                warm = time_blender_warm(command, g, cam, os.path.join(d, f"{tool}_warm.exr"),
                                         extra[name].get(tool, ()))
                if record:
                    t[f"{tool}_warm"] += warm

    # One warm-up of each (file caches, the databases built once), not timed.
    one_round(False)
    for r in range(args.rounds):
        one_round(True)
        print(f"round {r + 1}/{args.rounds} done", file=sys.stderr)
    results = []
    for name, g, cam, ref in items:
        t = times[name]
        d = os.path.join(args.out, name)
        summaries = {k: summary(v) for k, v in t.items() if k != "stages"}
        faster_call = min(summaries[f"{tool}_call"]["median"] for tool in tools)
        faster_process = min(summaries[f"{tool}_process"]["median"] for tool in tools)
        stages = {k: statistics.median([x[k] for x in t["stages"] if x.get(k) is not None] or [0])
                  for k in STAGES}
        results.append({
            "input": name, "times_s": summaries,
            "ratio_per_call": summaries["spreadlet_call"]["median"] / faster_call,
            "ratio_per_process": summaries["spreadlet"]["median"] / faster_process,
            **({"ratio_per_warm_call": summaries["spreadlet_warm"]["median"]
                / min(summaries[f"{tool}_warm"]["median"] for tool in tools)}
               if args.warm_calls else {}),
            "spreadlet_stages_ms": stages,
            "scores": {tool: scores(args.bin, os.path.join(d, f"{tool}.exr"), ref)
                       for tool in ["spreadlet", *tools]},
        })
    with open(os.path.join(args.out, "results.json"), "w") as f:
        json.dump({"rounds": args.rounds, "size": args.size, "ref_spp": args.ref_spp,
                   "tools": list(tools), "results": results}, f, indent=1)
    label = {"blender": "Blender 3.4", "blender5": "Blender 5"}
    fmt = lambda x: f"{x['median']:.2f} ({x['min']:.2f}-{x['max']:.2f})"
    head = (f"| {args.size} px input | spreadlet call (s) | "
            + " | ".join(f"{label.get(t, t)} call (s)" for t in tools)
            + " | ratio to the faster | spreadlet process (s) | "
            + " | ".join(f"{label.get(t, t)} process (s)" for t in tools)
            + " | ratio to the faster |")
    lines = [head, "|" + " --- |" * (5 + 2 * len(tools))]
    for r in results:
        ts = r["times_s"]
        lines.append(
            f"| {r['input']} | {fmt(ts['spreadlet_call'])} | "
            + " | ".join(fmt(ts[f"{t}_call"]) for t in tools)
            + f" | {r['ratio_per_call']:.2f} | {fmt(ts['spreadlet'])} | "
            + " | ".join(fmt(ts[f"{t}_process"]) for t in tools)
            + f" | {r['ratio_per_process']:.2f} |")
    if args.warm_calls:
        lines += ["", f"| {args.size} px input | spreadlet warm call (s) | "
                  + " | ".join(f"{label.get(t, t)} warm call (s)" for t in tools)
                  + " | ratio to the faster |", "|" + " --- |" * (3 + len(tools))]
        for r in results:
            ts = r["times_s"]
            lines.append(f"| {r['input']} | {fmt(ts['spreadlet_warm'])} | "
                         + " | ".join(fmt(ts[f"{t}_warm"]) for t in tools)
                         + f" | {r['ratio_per_warm_call']:.2f} |")
    names = ["spreadlet", *tools]
    lines += ["", "| input (SSIM / FLIP mean / FLIP p99) | "
              + " | ".join(label.get(n, n) for n in names) + " |",
              "| --- |" + " --- |" * len(names)]
    for r in results:
        sc = r["scores"]
        lines.append(f"| {r['input']} | " + " | ".join(
            f"{sc[n]['ssim']:.4f} / {sc[n]['flip_mean']:.4f} / {sc[n]['flip_p99']:.3f}"
            for n in names) + " |")
    lines += ["", "| input | " + " | ".join(STAGES) + " (ms, medians) |",
              "| --- |" + " --- |" * len(STAGES)]
    for r in results:
        st = r["spreadlet_stages_ms"]
        lines.append(f"| {r['input']} | " + " | ".join(f"{st[k]:.0f}" for k in STAGES) + " |")
    with open(os.path.join(args.out, "results.md"), "w") as f:
        f.write("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
