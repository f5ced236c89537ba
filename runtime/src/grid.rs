//! Operations on row-major `width x height` grids shared by the frame-sized passes:
//! a separable Gaussian blur and a square dilation, both with the border clamped.

use rayon::prelude::*;

/// `plane` (`width x height`, row-major) blurred by a Gaussian of `sigma_px`, separably, each
/// channel on its own, the border clamped, each pass on every thread.
pub(crate) fn gaussian_blur<const N: usize>(
    plane: &mut [[f32; N]],
    width: usize,
    height: usize,
    sigma_px: f32,
) {
    let r = (3.0 * sigma_px).ceil() as isize;
    let kernel: Vec<f32> = (-r..=r)
        .map(|d| (-(d * d) as f32 / (2.0 * sigma_px * sigma_px)).exp())
        .collect();
    let norm: f32 = kernel.iter().sum();
    let kernel: Vec<f32> = kernel.iter().map(|k| k / norm).collect();
    let mut rows = vec![[0.0f32; N]; plane.len()];
    rows.par_chunks_mut(width)
        .zip(plane.par_chunks(width))
        .for_each(|(out, row)| {
            for (x, o) in out.iter_mut().enumerate() {
                for c in 0..N {
                    o[c] = (-r..=r)
                        .zip(&kernel)
                        .map(|(d, k)| {
                            let xx = (x as isize + d).clamp(0, width as isize - 1) as usize;
                            k * row[xx][c]
                        })
                        .sum();
                }
            }
        });
    plane
        .par_chunks_mut(width)
        .enumerate()
        .for_each(|(y, out)| {
            for (x, o) in out.iter_mut().enumerate() {
                for c in 0..N {
                    o[c] = (-r..=r)
                        .zip(&kernel)
                        .map(|(d, k)| {
                            let yy = (y as isize + d).clamp(0, height as isize - 1) as usize;
                            k * rows[yy * width + x][c]
                        })
                        .sum();
                }
            }
        });
}

/// `marks` (a `w x h` grid) grown by `radius` pixels each way: a square of side `2 radius + 1`
/// round every mark. Each pass counts the marks in a running window.
pub(crate) fn dilate(marks: &[bool], w: usize, h: usize, radius: usize) -> Vec<bool> {
    if w == 0 || h == 0 {
        return Vec::new();
    }
    let run = |line: &mut dyn Iterator<Item = bool>, n: usize| -> Vec<bool> {
        let mut prefix = Vec::with_capacity(n + 1);
        prefix.push(0u32);
        for m in line {
            prefix.push(prefix[prefix.len() - 1] + u32::from(m));
        }
        (0..n)
            .map(|i| prefix[(i + radius + 1).min(n)] > prefix[i.saturating_sub(radius)])
            .collect()
    };
    let across: Vec<bool> = marks
        .par_chunks(w)
        .flat_map_iter(|row| run(&mut row.iter().copied(), w))
        .collect();
    let columns: Vec<Vec<bool>> = (0..w)
        .into_par_iter()
        .map(|x| run(&mut (0..h).map(|y| across[y * w + x]), h))
        .collect();
    (0..w * h).map(|i| columns[i % w][i / w]).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One mark grows into the square of side `2 r + 1` round it, cut at the grid's edges.
    #[test]
    fn a_mark_dilates_into_a_square_cut_at_the_edges() {
        let (w, h) = (9, 7);
        let mut marks = vec![false; w * h];
        marks[w + 7] = true; // (7, 1)
        let grown = dilate(&marks, w, h, 2);
        for y in 0..h {
            for x in 0..w {
                let inside = (5..=8).contains(&x) && y <= 3;
                assert_eq!(grown[y * w + x], inside, "({x},{y})");
            }
        }
    }

    /// A constant grid stays constant (the kernel is normalised, the border clamped), and a
    /// single spike spreads symmetrically, keeping its sum away from the border.
    #[test]
    fn a_gaussian_keeps_a_constant_and_a_spikes_sum() {
        let (w, h) = (9, 9);
        let mut flat = vec![[0.25f32, 1.0]; w * h];
        gaussian_blur(&mut flat, w, h, 0.8);
        assert!(flat
            .iter()
            .all(|v| (v[0] - 0.25).abs() < 1e-6 && (v[1] - 1.0).abs() < 1e-6));
        let mut spike = vec![[0.0f32; 1]; w * h];
        spike[4 * w + 4] = [1.0];
        gaussian_blur(&mut spike, w, h, 0.8);
        let sum: f32 = spike.iter().map(|v| v[0]).sum();
        assert!((sum - 1.0).abs() < 1e-5, "{sum}");
        assert_eq!(spike[4 * w + 3], spike[4 * w + 5]);
        assert_eq!(spike[3 * w + 4], spike[4 * w + 3]);
    }
}
