"""spreadlet synth against Blender's compositor on the same inputs, timed side by side.

For every input (both shared Blender examples and the built-in scenes rendered at 512 x 512,
plus the hard car-on-road scene), each round runs the whole `spreadlet synth` process (EXR
read, database load, synthesis, EXR write) and then Blender's compositor on the same G-buffer
(`bench/blender_compositor.py`: Vector Blur, then Defocus, calibrated to the lens), inputs
round-robin and the two tools alternating (A B A B), so a change of the machine's load hits
both alike. Reports medians, spreads (min-max) and the ratio of medians from one run,
spreadlet's per-stage breakdown (from its --stats), and both results' SSIM and FLIP against
the reference.

    python3 bench/against_blender.py --out target/against-blender [--rounds 5] [--ref-spp 256]

Needs `target/release/{spreadlet,spreadlet-scene}` (cargo build --release) and Blender
(`apt-get install blender`). Writes OUT/results.json and OUT/results.md.
"""

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENES = ["bokeh", "crossing", "occluder", "rotating", "physical",
          os.path.join(ROOT, "scene", "scenes", "hard", "car-on-road.json")]
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
    for name in ("comets", "fence"):
        d = os.path.join(shared, name)
        if os.path.exists(os.path.join(d, "input.exr")):
            found.append((name, os.path.join(d, "input.exr"), os.path.join(d, "camera.json"),
                          os.path.join(d, "reference.exr")))
        else:
            print(f"no {d}/input.exr: {name} is skipped", file=sys.stderr)
    for scene in SCENES:
        name = os.path.splitext(os.path.basename(scene))[0]
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
    return wall, stages


def time_blender(blender, g, cam, out):
    t = time.perf_counter()
    done = run([blender, "-b", "--factory-startup", "--python-exit-code", "1", "--python",
                os.path.join(ROOT, "bench", "blender_compositor.py"), "--", "--input", g,
                "--camera", cam, "--out", out])
    wall = time.perf_counter() - t
    m = re.search(r"composite ([0-9.]+) s \(render call\)", done.stdout + done.stderr)
    if not m:
        sys.exit(f"no render-call time in Blender's output:\n{done.stdout[-2000:]}")
    return wall, float(m.group(1))


def scores(bin_dir, image, reference):
    out = run([os.path.join(bin_dir, "spreadlet"), "compare", image, reference, "--json"])
    d = json.loads(out.stdout)
    return {"ssim": d["ssim"], "flip_mean": d["flip_mean"], "flip_p99": d["flip_p99"]}


def summary(values):
    return {"median": statistics.median(values), "min": min(values), "max": max(values)}


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True)
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--size", type=int, default=512)
    p.add_argument("--ref-spp", type=int, default=256)
    p.add_argument("--blender", default="blender")
    p.add_argument("--bin", default=os.path.join(ROOT, "target", "release"))
    p.add_argument("--shared", default=os.path.join(ROOT, "..", "shared", "examples"))
    args = p.parse_args()
    os.makedirs(args.out, exist_ok=True)
    items = inputs(args, args.bin, os.path.join(args.out, "inputs"))
    times = {name: {"spreadlet": [], "blender_call": [], "blender_process": [], "stages": []}
             for name, *_ in items}
    # One warm-up of each (file caches, the databases built once), not timed.
    for name, g, cam, _ in items:
        d = os.path.join(args.out, name)
        os.makedirs(d, exist_ok=True)
        time_spreadlet(args.bin, g, cam, os.path.join(d, "spreadlet.exr"),
                       os.path.join(d, "stats.json"))
        time_blender(args.blender, g, cam, os.path.join(d, "blender.exr"))
    for r in range(args.rounds):
        for name, g, cam, _ in items:
            d = os.path.join(args.out, name)
            wall, stages = time_spreadlet(args.bin, g, cam, os.path.join(d, "spreadlet.exr"),
                                          os.path.join(d, "stats.json"))
            process, call = time_blender(args.blender, g, cam, os.path.join(d, "blender.exr"))
            t = times[name]
            t["spreadlet"].append(wall)
            t["blender_call"].append(call)
            t["blender_process"].append(process)
            t["stages"].append(stages)
        print(f"round {r + 1}/{args.rounds} done", file=sys.stderr)
    results = []
    for name, g, cam, ref in items:
        t = times[name]
        d = os.path.join(args.out, name)
        s, bc, bp = (summary(t[k]) for k in ("spreadlet", "blender_call", "blender_process"))
        stages = {k: statistics.median([x[k] for x in t["stages"] if x.get(k) is not None] or [0])
                  for k in STAGES}
        results.append({
            "input": name, "spreadlet_s": s, "blender_render_call_s": bc,
            "blender_process_s": bp, "ratio_to_render_call": s["median"] / bc["median"],
            "ratio_to_process": s["median"] / bp["median"], "spreadlet_stages_ms": stages,
            "spreadlet_scores": scores(args.bin, os.path.join(d, "spreadlet.exr"), ref),
            "blender_scores": scores(args.bin, os.path.join(d, "blender.exr"), ref),
        })
    with open(os.path.join(args.out, "results.json"), "w") as f:
        json.dump({"rounds": args.rounds, "size": args.size, "ref_spp": args.ref_spp,
                   "results": results}, f, indent=1)
    lines = [
        f"| {args.size} px input | spreadlet synth, whole process (s) | Blender render call (s) "
        "| ratio | Blender process (s) | spreadlet SSIM / FLIP | Blender SSIM / FLIP |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    fmt = lambda x: f"{x['median']:.2f} ({x['min']:.2f}-{x['max']:.2f})"
    for r in results:
        a, b = r["spreadlet_scores"], r["blender_scores"]
        lines.append(
            f"| {r['input']} | {fmt(r['spreadlet_s'])} | {fmt(r['blender_render_call_s'])} | "
            f"{r['ratio_to_render_call']:.2f} | {fmt(r['blender_process_s'])} | "
            f"{a['ssim']:.4f} / {a['flip_mean']:.4f} | {b['ssim']:.4f} / {b['flip_mean']:.4f} |")
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
