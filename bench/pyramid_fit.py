"""Re-fits the convolution pyramid's filters to the project's 5-point Laplacian, in NumPy.

    python3 bench/pyramid_fit.py [--taps 5|7] [--iters N]

`poisson::integrate_pyramid` uses Farbman, Fattal and Lischinski's (2011) Poisson filter set
(`H1 = H2 = [0.15, 0.5, 0.7, 0.5, 0.15]`, `G = [0.175, 0.547, 0.175]`) with one scale calibrated
against the exact lattice inverse. This script transcribes the pyramid stage by stage as
`poisson/src/pyramid.rs` documents it (zero-padded levels, `PAD` = 5, two extra coarse levels),
then fits symmetric `H1`, `H2` and `G` (5, 5 and 3 taps, or 7, 7 and 5 with `--taps 7`) by
Nelder-Mead, the scale by least squares, to integrate the Laplacians of a set of images back
to the images themselves (which the exact integrator does to rounding): anti-aliased disks of
radius 1.5-60 px, a Gaussian blob and smoothed noise. It prints the relative mean squared error
over the set, each image's mean and largest absolute error, and the same for a disk with a
hard edge (r = 30 in 160 x 160, as `poisson/tests/pyramid.rs` measures it), which the fit
does not see. Needs numpy only.
"""
import argparse

import numpy as np

PAD = 5


def correlate(a, h, axis):
    """`out[x] = sum_k h[k] a[x + k - len(h) // 2]`, zero outside, the same size as `a`."""
    out = np.zeros_like(a)
    n, c = a.shape[axis], len(h) // 2
    for k, hk in enumerate(h):
        s = k - c
        src = [slice(None)] * a.ndim
        dst = [slice(None)] * a.ndim
        src[axis] = slice(max(s, 0), n + min(s, 0))
        dst[axis] = slice(max(-s, 0), n - max(s, 0))
        out[tuple(dst)] += hk * a[tuple(src)]
    return out


def filter2(a, h):
    return correlate(correlate(a, h, 1), h, 0)


def level_count(w, h):
    m, levels = max(w, h, 1), 0
    while (1 << levels) < m:
        levels += 1
    return max(levels, 1) + 2


def pyramid(laplacian, h1, h2, g):
    """The raw pyramid output (before the scale) for a Laplacian plane."""
    height, width = laplacian.shape
    analysis = [np.pad(laplacian, PAD)]
    for _ in range(level_count(width, height) - 1):
        down = correlate(correlate(analysis[-1], h1, 1)[:, ::2], h1, 0)[::2, :]
        analysis.append(np.pad(down, PAD))
    f = filter2(analysis[-1], g)
    for a in reversed(analysis[:-1]):
        up = np.zeros_like(a)
        up[::2, ::2] = f[PAD:-PAD, PAD:-PAD]
        f = filter2(up, h2) + filter2(a, g)
    return f[PAD:-PAD, PAD:-PAD]


def laplacian(image):
    """The project's 5-point stencil, zero outside the plane."""
    p = np.pad(image, 1)
    return p[:-2, 1:-1] + p[2:, 1:-1] + p[1:-1, :-2] + p[1:-1, 2:] - 4 * image


def disk(height, width, cx, cy, r, supersample=4):
    y, x = np.mgrid[0:height, 0:width]
    acc = np.zeros((height, width))
    for sy in range(supersample):
        for sx in range(supersample):
            ox, oy = (sx + 0.5) / supersample, (sy + 0.5) / supersample
            acc += (x + ox - cx) ** 2 + (y + oy - cy) ** 2 <= r * r
    return acc / supersample**2


def fit_set():
    images = [disk(160, 160, 80, 80, 30)]
    a = np.zeros((256, 256))
    for cx, cy, r in [(40.3, 50.2, 3), (120.7, 60.1, 8), (180, 170, 20), (70, 180, 45), (230, 30, 5)]:
        a += disk(256, 256, cx, cy, r)
    images.append(a)
    y, x = np.mgrid[0:200, 0:320]
    b = np.exp(-((x - 100) ** 2 + (y - 90) ** 2) / (2 * 15**2))
    b += 0.5 * disk(200, 320, 230, 100, 60) + 2 * disk(200, 320, 160, 160, 1.5)
    images.append(b)
    c = np.zeros((128, 128))
    c[20:108, 20:108] = np.random.default_rng(1).random((88, 88))
    fx, fy = np.fft.fftfreq(128)[None, :], np.fft.fftfreq(128)[:, None]
    c = np.real(np.fft.ifft2(np.fft.fft2(c) * np.exp(-(fx**2 + fy**2) * 200)))
    c[:10], c[-10:], c[:, :10], c[:, -10:] = 0, 0, 0, 0
    images.append(c)
    return images


def filters(p, taps):
    half = taps // 2 + 1
    h1, h2, g = p[:half], p[half : 2 * half], p[2 * half :]
    mirror = lambda v: list(v) + list(v[-2::-1])
    return mirror(h1), mirror(h2), mirror(g)


def errors(p, taps, images):
    h1, h2, g = filters(p, taps)
    outs = [pyramid(laplacian(i), h1, h2, g) for i in images]
    den = sum(np.sum(o * o) for o in outs)
    scale = sum(np.sum(o * i) for o, i in zip(outs, images)) / den if den > 0 else 0.0
    return scale, [scale * o - i for o, i in zip(outs, images)]


def nelder_mead(f, x0, iters, step=0.05):
    points = [np.array(x0, float)]
    for i in range(len(x0)):
        x = np.array(x0, float)
        x[i] += step * (abs(x[i]) if x[i] != 0 else 1)
        points.append(x)
    values = [f(p) for p in points]
    for it in range(iters):
        order = np.argsort(values)
        points, values = [points[i] for i in order], [values[i] for i in order]
        if it % 250 == 0:
            print(f"  iteration {it}: relative MSE {values[0]:.3e}", flush=True)
        centre = np.mean(points[:-1], axis=0)
        reflected = centre + (centre - points[-1])
        fr = f(reflected)
        if fr < values[0]:
            expanded = centre + 2 * (centre - points[-1])
            fe = f(expanded)
            points[-1], values[-1] = (expanded, fe) if fe < fr else (reflected, fr)
        elif fr < values[-2]:
            points[-1], values[-1] = reflected, fr
        else:
            contracted = centre + 0.5 * (points[-1] - centre)
            fc = f(contracted)
            if fc < values[-1]:
                points[-1], values[-1] = contracted, fc
            else:
                for i in range(1, len(points)):
                    points[i] = points[0] + 0.5 * (points[i] - points[0])
                    values[i] = f(points[i])
    best = int(np.argmin(values))
    return points[best], values[best]


def report(name, p, taps, images, norms, hard):
    scale, errs = errors(p, taps, images)
    rel = np.mean([np.mean(e * e) / n for e, n in zip(errs, norms)])
    h1, h2, g = filters(p, taps)
    hard_err = scale * pyramid(laplacian(hard), h1, h2, g) - hard
    print(f"{name}: H1 {np.round(h1, 6).tolist()} H2 {np.round(h2, 6).tolist()} G {np.round(g, 6).tolist()} scale {scale:.6f}")
    print(f"  fit set: relative MSE {rel:.3e}; mean / max |error| per image: "
          + ", ".join(f"{np.mean(np.abs(e)):.5f} / {np.max(np.abs(e)):.4f}" for e in errs))
    print(f"  hard-edged disk r = 30 in 160 x 160: mean |error| {np.mean(np.abs(hard_err)):.5f}, max {np.max(np.abs(hard_err)):.4f}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--taps", type=int, choices=[5, 7], default=5, help="taps of H1 and H2 (G has two fewer)")
    ap.add_argument("--iters", type=int, default=2000)
    args = ap.parse_args()
    images = fit_set()
    norms = [np.mean(i * i) for i in images]
    hard = disk(160, 160, 80, 80, 30, supersample=1)
    farbman = [0.15, 0.5, 0.7, 0.15, 0.5, 0.7, 0.175, 0.547]
    report("Farbman et al. 2011", farbman, 5, images, norms, hard)
    x0 = farbman if args.taps == 5 else [0.0, 0.15, 0.5, 0.7, 0.0, 0.15, 0.5, 0.7, 0.0, 0.175, 0.547]

    def objective(p):
        scale, errs = errors(p, args.taps, images)
        if not np.isfinite(scale):
            return 1e9
        return float(np.mean([np.mean(e * e) / n for e, n in zip(errs, norms)]))

    print(f"fitting {args.taps}-tap H1 and H2, {args.taps - 2}-tap G:")
    best, _ = nelder_mead(objective, x0, args.iters)
    report("re-fitted", best, args.taps, images, norms, hard)


if __name__ == "__main__":
    main()
