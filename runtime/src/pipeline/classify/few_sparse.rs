//! Layers with few sparse records: each drawn from its PSF's image, the layer not integrated.
//!
//! A layer's Laplacian planes cost their integration whatever draws into them: the exact
//! lattice inverse of four padded planes, an FFT in f64 there and back. A layer that holds
//! the whole frame's background pays it gladly; one that holds a few dozen sparse records (the
//! far edge of a wall that reaches into the next depth layer, a handful of pixels in front of
//! the focus) pays as much. There, each sparse PSF the layer draws is integrated once on its
//! own small plane ([`psf_image`]) and the records draw that image in the layer's direct
//! planes; the layer then has no Laplacian plane. It pays where drawing the records' images
//! and building them ([`super::turned::IMAGE_BUILD_COST`] per pixel) costs less than
//! integrating the layer ([`LAYER_INTEGRATION_COST`] per padded pixel).
//!
//! Only upright records and those turned half a turn (a lens images its aperture so in front
//! of the focus plane) are drawn so: a half turn maps pixels onto pixels, so its image is the
//! upright one reversed. Records turned any other way keep the sparse path, and so does their
//! layer.

use std::sync::Arc;

use psf_db::PsfDatabase;
use rayon::prelude::*;

use super::turned::{count_paths_again, images_cost, LAYER_INTEGRATION_COST};
use super::ClassifyError;
use crate::motion_smear::{psf_image, PsfImage};
use crate::pipeline::types::{frame_psf_reach, Classified, SplatPath, SplatRecord};

/// How a sparse record of a layer drawn from images is turned.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
enum Turn {
    Upright,
    Half,
}

fn turn_of(r: &SplatRecord) -> Option<Turn> {
    match (r.rot_cos, r.rot_sin) {
        (c, s) if c == 1.0 && s == 0.0 => Some(Turn::Upright),
        (c, s) if c == -1.0 && s == 0.0 => Some(Turn::Half),
        _ => None,
    }
}

/// Whether the sparse records of one layer (`records`) are few enough to be drawn from their
/// PSFs' images: all upright or turned half a turn, and drawing them (each its PSF's box) plus
/// building each image costs less than integrating the layer (`plane` padded pixels).
fn layer_drawn_from_images(records: &[SplatRecord], reach: &[i32], plane: usize) -> bool {
    let most = LAYER_INTEGRATION_COST.saturating_mul(plane);
    let side = |psf: u32| 2 * reach.get(psf as usize).copied().unwrap_or(0).max(0) as usize + 1;
    let mut cost = 0usize;
    let mut keys = Vec::new();
    for r in records
        .iter()
        .filter(|r| r.path == SplatPath::Sparse as u32)
    {
        let Some(turn) = turn_of(r) else {
            return false;
        };
        cost += side(r.psf_index).pow(2);
        if cost > most {
            return false;
        }
        keys.push((r.psf_index, turn));
    }
    cost += images_cost(&mut keys, side);
    !keys.is_empty() && cost <= most
}

/// `image` turned half a turn about the PSF's centre: pixel `(x, y)` to `(-x, -y)`.
fn half_turned(image: &PsfImage) -> PsfImage {
    let (w, h, c) = (image.width, image.height, image.channels);
    let mut data = Vec::with_capacity(image.data.len());
    for pixel in image.data.chunks_exact(c.max(1)).rev() {
        data.extend_from_slice(pixel);
    }
    PsfImage {
        origin: [
            -(image.origin[0] + w as i32 - 1),
            -(image.origin[1] + h as i32 - 1),
        ],
        width: w,
        height: h,
        channels: c,
        data,
    }
}

/// Redirects the sparse records of every layer of `classified` whose sparse records are few
/// ([`layer_drawn_from_images`]) to their PSF's image, upright or turned half a turn, drawn
/// dense; `base` is the database the records index now. The frame's database becomes `base`
/// followed by the images. Returns how many records are drawn so.
pub(super) fn draw_few_sparse_from_images(
    classified: &mut Classified,
    base: &PsfDatabase,
) -> Result<usize, ClassifyError> {
    if classified.counts.sparse == 0 {
        return Ok(0);
    }
    let reach = frame_psf_reach(base, classified.packed.as_deref());
    let plane = classified.frame.padded_width as usize * classified.frame.padded_height as usize;
    let chosen: Vec<usize> = classified
        .layers
        .iter()
        .enumerate()
        .filter(|(_, info)| info.sparse > 0)
        .filter(|(_, info)| {
            let records = &classified.records[info.first_record..][..info.record_count];
            layer_drawn_from_images(records, &reach, plane)
        })
        .map(|(l, _)| l)
        .collect();
    if chosen.is_empty() {
        return Ok(0);
    }
    let layer_records = |l: usize| {
        let info = &classified.layers[l];
        info.first_record..info.first_record + info.record_count
    };
    let mut keys: Vec<(u32, Turn)> = chosen
        .iter()
        .flat_map(|&l| classified.records[layer_records(l)].iter())
        .filter(|r| r.path == SplatPath::Sparse as u32)
        .filter_map(|r| Some((r.psf_index, turn_of(r)?)))
        .collect();
    keys.sort_unstable();
    keys.dedup();
    let images: Vec<Option<PsfImage>> = keys
        .par_iter()
        .map(|&(psf, turn)| {
            let image = psf_image(base, psf as usize)?;
            Some(match turn {
                Turn::Upright => image,
                Turn::Half => half_turned(&image),
            })
            .filter(|image| image.width > 0 && image.height > 0)
        })
        .collect();
    let mut boxes = Vec::new();
    let mut drawn: Vec<&PsfImage> = Vec::new();
    let first = base.psf_count() as u32;
    let index_of_key: Vec<Option<u32>> = images
        .iter()
        .map(|image| {
            let image = image.as_ref()?;
            boxes.push((image.origin, image.width, image.height));
            drawn.push(image);
            Some(first + drawn.len() as u32 - 1)
        })
        .collect();
    if drawn.is_empty() {
        return Ok(0);
    }
    let not_built = |e: psf_db::DbError| ClassifyError::FrameDatabase(e.to_string());
    let extension = crate::dbset::extend_with_dense(base, &boxes).map_err(not_built)?;
    let database = extension
        .fill(|i, out| out.copy_from_slice(&drawn[i].data))
        .map_err(not_built)?;
    let mut redirected = 0;
    for &l in &chosen {
        let range = layer_records(l);
        for r in &mut classified.records[range] {
            if r.path != SplatPath::Sparse as u32 {
                continue;
            }
            let Some(turn) = turn_of(r) else { continue };
            let Ok(k) = keys.binary_search(&(r.psf_index, turn)) else {
                continue;
            };
            if let Some(index) = index_of_key[k] {
                r.psf_index = index;
                (r.rot_cos, r.rot_sin) = (1.0, 0.0);
                r.path = SplatPath::Dense as u32;
                redirected += 1;
            }
        }
    }
    count_paths_again(classified);
    classified.database = Some(Arc::new(database));
    Ok(redirected)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A half turn sends the pixel at offset `(x, y)` from the centre to `(-x, -y)`, channels
    /// kept together.
    #[test]
    fn a_half_turn_sends_each_pixel_to_its_opposite() {
        // 3 x 2 pixels from (-1, 0), two channels: value (10 x + y, -(10 x + y)).
        let (origin, width, height) = ([-1, 0], 3usize, 2usize);
        let at = |x: i32, y: i32| (10 * x + y) as f32;
        let mut data = Vec::new();
        for y in 0..height as i32 {
            for x in 0..width as i32 {
                let (ox, oy) = (origin[0] + x, origin[1] + y);
                data.extend([at(ox, oy), -at(ox, oy)]);
            }
        }
        let image = PsfImage {
            origin,
            width,
            height,
            channels: 2,
            data,
        };
        let turned = half_turned(&image);
        assert_eq!(turned.origin, [-1, -1]);
        assert_eq!((turned.width, turned.height, turned.channels), (3, 2, 2));
        for y in 0..height as i32 {
            for x in 0..width as i32 {
                let (ox, oy) = (turned.origin[0] + x, turned.origin[1] + y);
                let k = (y as usize * width + x as usize) * 2;
                assert_eq!(
                    turned.data[k..k + 2],
                    [at(-ox, -oy), -at(-ox, -oy)],
                    "offset ({ox}, {oy})"
                );
            }
        }
    }
}
