//! `Plane`: one channel of a float image, row-major, pixel (0,0) top-left, y down.

use std::ops::AddAssign;

use crate::PoissonError;

/// One image channel of `T` values, `width x height` pixels, row-major (`data[y * width + x]`),
/// pixel (0,0) top-left, y down. [`Plane`] (f32) is what the pipeline passes around; [`PlaneF64`]
/// is used where rounding matters (exact integration, tests).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PlaneOf<T> {
    /// Width, px.
    pub width: usize,
    /// Height, px.
    pub height: usize,
    /// `width * height` values, row-major.
    pub data: Vec<T>,
}

/// One f32 channel (linear values).
pub type Plane = PlaneOf<f32>;
/// One f64 channel.
pub type PlaneF64 = PlaneOf<f64>;

impl<T: Copy + Default> PlaneOf<T> {
    /// A plane of zeros.
    pub fn new(width: usize, height: usize) -> Self {
        PlaneOf {
            width,
            height,
            data: vec![T::default(); width * height],
        }
    }

    /// A plane over existing data; errors when `data.len() != width * height`.
    pub fn from_vec(width: usize, height: usize, data: Vec<T>) -> Result<Self, PoissonError> {
        if Some(data.len()) != width.checked_mul(height) {
            return Err(PoissonError::SizeMismatch {
                width,
                height,
                len: data.len(),
            });
        }
        Ok(PlaneOf {
            width,
            height,
            data,
        })
    }

    /// A plane whose pixel (x, y) is `f(x, y)`.
    pub fn from_fn(width: usize, height: usize, mut f: impl FnMut(usize, usize) -> T) -> Self {
        let mut data = Vec::with_capacity(width * height);
        for y in 0..height {
            for x in 0..width {
                data.push(f(x, y));
            }
        }
        PlaneOf {
            width,
            height,
            data,
        }
    }

    /// Number of pixels.
    pub fn len(&self) -> usize {
        self.data.len()
    }

    /// True when the plane has no pixels.
    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    /// Index of pixel (x, y) in `data`.
    #[inline]
    pub fn index(&self, x: usize, y: usize) -> usize {
        y * self.width + x
    }

    /// Value at (x, y); panics outside the plane.
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> T {
        self.data[y * self.width + x]
    }

    /// Value at signed (x, y), zero (`T::default()`) outside the plane.
    #[inline]
    pub fn get_or_zero(&self, x: isize, y: isize) -> T {
        if x < 0 || y < 0 || x as usize >= self.width || y as usize >= self.height {
            T::default()
        } else {
            self.data[y as usize * self.width + x as usize]
        }
    }

    /// Sets (x, y); panics outside the plane.
    #[inline]
    pub fn set(&mut self, x: usize, y: usize, v: T) {
        let w = self.width;
        self.data[y * w + x] = v;
    }

    /// Row `y`.
    #[inline]
    pub fn row(&self, y: usize) -> &[T] {
        &self.data[y * self.width..(y + 1) * self.width]
    }

    /// Row `y`, mutable.
    #[inline]
    pub fn row_mut(&mut self, y: usize) -> &mut [T] {
        let w = self.width;
        &mut self.data[y * w..(y + 1) * w]
    }

    /// Sets every pixel to zero.
    pub fn clear(&mut self) {
        self.data.fill(T::default());
    }

    /// Resizes to `width x height` and zeroes it (reuses the allocation when large enough).
    pub fn reset(&mut self, width: usize, height: usize) {
        self.width = width;
        self.height = height;
        self.data.clear();
        self.data.resize(width * height, T::default());
    }

    /// A `w x h` window starting at (x0, y0) (signed; zero outside this plane).
    pub fn crop(&self, x0: isize, y0: isize, w: usize, h: usize) -> Self {
        PlaneOf::from_fn(w, h, |x, y| {
            self.get_or_zero(x0 + x as isize, y0 + y as isize)
        })
    }
}

impl<T: Copy + Default + AddAssign> PlaneOf<T> {
    /// Adds `v` at (x, y); panics outside the plane.
    #[inline]
    pub fn add(&mut self, x: usize, y: usize, v: T) {
        let w = self.width;
        self.data[y * w + x] += v;
    }

    /// Adds `v` at signed (x, y) when inside the plane; returns whether it was inside.
    #[inline]
    pub fn add_clipped(&mut self, x: isize, y: isize, v: T) -> bool {
        if x < 0 || y < 0 || x as usize >= self.width || y as usize >= self.height {
            return false;
        }
        let w = self.width;
        self.data[y as usize * w + x as usize] += v;
        true
    }
}

impl Plane {
    /// The plane in f64.
    pub fn to_f64(&self) -> PlaneF64 {
        PlaneOf {
            width: self.width,
            height: self.height,
            data: self.data.iter().map(|&v| v as f64).collect(),
        }
    }

    /// Sum of all values (accumulated in f64).
    pub fn sum(&self) -> f64 {
        self.data.iter().map(|&v| v as f64).sum()
    }
}

impl PlaneF64 {
    /// The plane rounded to f32.
    pub fn to_f32(&self) -> Plane {
        PlaneOf {
            width: self.width,
            height: self.height,
            data: self.data.iter().map(|&v| v as f32).collect(),
        }
    }

    /// Sum of all values.
    pub fn sum(&self) -> f64 {
        self.data.iter().sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn indexing_and_helpers() {
        let mut p = Plane::new(3, 2);
        p.set(2, 1, 5.0);
        p.add(2, 1, 1.0);
        assert_eq!(p.get(2, 1), 6.0);
        assert_eq!(p.data[5], 6.0);
        assert_eq!(p.get_or_zero(-1, 0), 0.0);
        assert_eq!(p.get_or_zero(2, 1), 6.0);
        assert!(!p.add_clipped(3, 0, 1.0));
        assert_eq!(p.row(1), &[0.0, 0.0, 6.0]);
        assert!(Plane::from_vec(2, 2, vec![0.0; 3]).is_err());
        let c = p.crop(1, 0, 3, 3);
        assert_eq!(c.get(1, 1), 6.0);
        assert_eq!(c.get(2, 2), 0.0);
    }
}
