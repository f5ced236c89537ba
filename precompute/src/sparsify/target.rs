//! What a PSF's sparsification works on: the pre-filtered PSF, its 5-point Laplacian
//! (`poisson::laplacian`, step 1 of the paper's procedure) and the pixels where it is non-zero.

use poisson::{laplacian, Plane};

use crate::image::PsfImage;

/// A PSF ready for sparsification.
#[derive(Clone, Debug)]
pub struct Target {
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
    /// The PSF, one plane per channel (`width * height`).
    pub psf: Vec<Vec<f32>>,
    /// Its 5-point Laplacian, per channel.
    pub lap: Vec<Vec<f32>>,
    /// Row-major indices of the pixels where some channel's Laplacian is non-zero.
    pub active: Vec<u32>,
    /// Importance of each active pixel: `sum_c |Laplacian_c|`.
    pub importance: Vec<f64>,
    /// Cell group of each active pixel: 0 when all pixels share the Voronoi cells (the
    /// paper), else 0 for a negative and 1 for a positive Laplacian (`sum_c Laplacian_c`).
    pub group: Vec<u8>,
    /// Number of groups (1 or 2).
    pub groups: usize,
}

impl Target {
    /// The target of a traced PSF; `split_signs` gives positive and negative Laplacian pixels
    /// separate Voronoi cells (so collapsing never cancels the two sides of an edge).
    pub fn new(image: &PsfImage, split_signs: bool) -> Self {
        let (w, h) = (image.width, image.height);
        let lap: Vec<Vec<f32>> = image
            .planes
            .iter()
            .map(|p| {
                let plane = Plane {
                    width: w,
                    height: h,
                    data: p.clone(),
                };
                laplacian(&plane).data
            })
            .collect();
        let mut active = Vec::new();
        let mut importance = Vec::new();
        let mut group = Vec::new();
        for i in 0..w * h {
            let m: f64 = lap.iter().map(|l| f64::from(l[i].abs())).sum();
            if m > 0.0 {
                active.push(i as u32);
                importance.push(m);
                let signed: f64 = lap.iter().map(|l| f64::from(l[i])).sum();
                group.push(u8::from(split_signs && signed >= 0.0));
            }
        }
        Target {
            width: w,
            height: h,
            psf: image.planes.clone(),
            lap,
            active,
            importance,
            group,
            groups: if split_signs { 2 } else { 1 },
        }
    }

    /// Number of channels.
    pub fn channels(&self) -> usize {
        self.psf.len()
    }

    /// Pixel coordinates `[x, y]` of active pixel `k`.
    #[inline]
    pub fn active_xy(&self, k: usize) -> [f64; 2] {
        let i = self.active[k] as usize;
        [(i % self.width) as f64, (i / self.width) as f64]
    }

    /// Laplacian of active pixel `k` in channel `c`.
    #[inline]
    pub fn active_lap(&self, k: usize, c: usize) -> f64 {
        f64::from(self.lap[c][self.active[k] as usize])
    }
}
