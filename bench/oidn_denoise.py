"""One OIDN denoise as a process of its own: read a noisy render with its guides, denoise, write.

    python3 bench/oidn_denoise.py IN.exr OUT.exr

IN.exr holds the colour (R, G, B) and the denoiser's guides (albedo.R/G/B, normal.X/Y/Z), as a
renderer's output with its denoising passes does. The filter is OIDN's RT, hdr, with both
guides, quality high (as `../shared/tools/oidn_peer.py` runs it). Prints one line of JSON: the
first (cold) denoise call's seconds and the script's own seconds from its first line; the
caller times the whole process (interpreter, imports, reading and writing included), which is
what a farm job that denoises a frame pays. Needs numpy, OpenEXR and pyoidn.
"""
import time

SCRIPT_START = time.perf_counter()

import json  # noqa: E402
import sys  # noqa: E402

import numpy as np  # noqa: E402
import OpenEXR  # noqa: E402
import pyoidn  # noqa: E402


def channel(channels, name):
    """One channel as float32; the OpenEXR module groups R, G, B and albedo.R/G/B into one array
    each."""
    if name in channels:
        return channels[name].pixels.astype(np.float32)
    base, _, c = name.rpartition(".")
    group = channels.get(base) if base else channels.get("RGB") or channels.get("RGBA")
    if group is None:
        sys.exit(f"no channel {name}")
    return group.pixels[..., ("RGBA" if not base else "RGB").index(c or name)].astype(np.float32)


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    src, dst = sys.argv[1], sys.argv[2]
    channels = OpenEXR.File(src).parts[0].channels
    stack = lambda names: np.ascontiguousarray(np.stack([channel(channels, n) for n in names], -1))
    rgb = np.maximum(np.nan_to_num(stack(["R", "G", "B"])), 0)
    albedo = np.clip(stack(["albedo.R", "albedo.G", "albedo.B"]), 0, 1)
    normal = np.clip(stack(["normal.X", "normal.Y", "normal.Z"]), -1, 1)
    start = time.perf_counter()
    out = pyoidn.denoise(rgb, albedo, normal, hdr=True, clean_aux=False, quality="high")
    call_s = time.perf_counter() - start
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    out = np.asarray(out, dtype=np.float32)
    chans = {k: np.ascontiguousarray(out[..., i]) for i, k in enumerate("RGB")}
    OpenEXR.File(header, chans).write(dst)
    print(json.dumps({"call_s": call_s, "script_s": time.perf_counter() - SCRIPT_START}))


if __name__ == "__main__":
    main()
