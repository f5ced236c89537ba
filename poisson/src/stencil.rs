//! The one discrete Laplacian of the project: the 5-point stencil with zero outside the plane,
//! `L f(x,y) = f(x-1,y) + f(x+1,y) + f(x,y-1) + f(x,y+1) - 4 f(x,y)`.

use rayon::prelude::*;

use crate::plane::{Plane, PlaneOf};

fn laplacian_generic<T>(src: &[T], w: usize, h: usize, dst: &mut [T])
where
    T: Copy + Default + Send + Sync + std::ops::Add<Output = T> + std::ops::Sub<Output = T>,
{
    assert_eq!(src.len(), w * h, "laplacian: source is not {w}x{h}");
    assert_eq!(dst.len(), w * h, "laplacian: destination is not {w}x{h}");
    if w == 0 || h == 0 {
        return;
    }
    let zero = T::default();
    dst.par_chunks_mut(w).enumerate().for_each(|(y, out)| {
        let row = &src[y * w..(y + 1) * w];
        let up = (y > 0).then(|| &src[(y - 1) * w..y * w]);
        let down = (y + 1 < h).then(|| &src[(y + 1) * w..(y + 2) * w]);
        for x in 0..w {
            let c = row[x];
            let mut s = if x > 0 { row[x - 1] } else { zero };
            if x + 1 < w {
                s = s + row[x + 1];
            }
            if let Some(u) = up {
                s = s + u[x];
            }
            if let Some(d) = down {
                s = s + d[x];
            }
            out[x] = s - (c + c + c + c);
        }
    });
}

/// The 5-point Laplacian of `f` (zero outside the plane), same size as `f`.
pub fn laplacian(f: &Plane) -> Plane {
    let mut out = Plane::new(f.width, f.height);
    laplacian_generic(&f.data, f.width, f.height, &mut out.data);
    out
}

/// [`laplacian`] into an existing plane of the same size (panics when sizes differ).
pub fn laplacian_into(f: &Plane, out: &mut Plane) {
    laplacian_generic(&f.data, f.width, f.height, &mut out.data);
}

/// [`laplacian`] in f64 on a row-major `w x h` slice.
pub fn laplacian_f64(f: &[f64], w: usize, h: usize) -> Vec<f64> {
    let mut out = vec![0.0; w * h];
    laplacian_generic(f, w, h, &mut out);
    out
}

/// [`laplacian`] for any plane of f32 or f64.
pub fn laplacian_of<T>(f: &PlaneOf<T>) -> PlaneOf<T>
where
    T: Copy + Default + Send + Sync + std::ops::Add<Output = T> + std::ops::Sub<Output = T>,
{
    let mut out = PlaneOf::new(f.width, f.height);
    laplacian_generic(&f.data, f.width, f.height, &mut out.data);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn impulse_gives_the_stencil() {
        let mut f = Plane::new(3, 3);
        f.set(1, 1, 1.0);
        let l = laplacian(&f);
        assert_eq!(l.data, vec![0.0, 1.0, 0.0, 1.0, -4.0, 1.0, 0.0, 1.0, 0.0]);
    }

    #[test]
    fn zero_outside_and_quadratic() {
        // f = x^2 has L f = 2 in the interior.
        let f = laplacian_f64(
            &(0..25)
                .map(|i| ((i % 5) as f64).powi(2))
                .collect::<Vec<_>>(),
            5,
            5,
        );
        assert_eq!(f[2 * 5 + 2], 2.0);
        // Corner (0,0): neighbours right 1, down 0, value 0: 1.
        assert_eq!(f[0], 1.0);
    }
}
