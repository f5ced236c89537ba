//! The background hidden behind the silhouettes of sharper occluders, continued from the
//! visible background beside them (so a blurred background does not darken along them).

use super::Fragment;
use crate::gbuffer::GBuffer;

/// The background hidden behind the silhouette of a sharper, nearer occluder, continued from
/// the visible background next to it.
///
/// A pinhole image holds no pixels of what an occluder hides, but a lens sees past the
/// occluder's edge: where the background is blurred more than the occluder, its layer would
/// otherwise lose the light of its hidden pixels and darken in a band along the silhouette.
/// As at the frame's edges, the background is taken to continue as it is: each background
/// pixel next to a nearer, sharper pixel is repeated into the occluder along that direction
/// (left, right, up, down), as far as its own blur reaches, under the occluder (which hides the
/// copies wherever it is opaque). A hidden pixel filled from several sides gets the mean of
/// them. `own(i)` is pixel `i`'s own fragment.
pub(super) fn hidden_background(
    g: &GBuffer,
    was_split: &[bool],
    signed_coc: &dyn Fn(f32) -> f32,
    depth_at: &dyn Fn(usize) -> f32,
    own: &dyn Fn(usize) -> Fragment,
) -> Vec<Fragment> {
    let (w, h) = (g.width as i32, g.height as i32);
    const DIRECTIONS: [(i32, i32); 4] = [(1, 0), (-1, 0), (0, 1), (0, -1)];
    // The walks: (background pixel, direction, steps), and how many walks reach each pixel.
    let mut walks: Vec<(usize, (i32, i32), i32)> = Vec::new();
    let mut fills = vec![0u16; (w * h) as usize];
    for y in 0..h {
        for x in 0..w {
            let b = (y * w + x) as usize;
            if was_split[b] || g.color[b] == [0.0; 4] {
                continue;
            }
            let (db, coc_b) = (depth_at(b), signed_coc(depth_at(b)));
            let reach = coc_b.abs().ceil() as i32;
            if reach < 2 {
                continue;
            }
            for d in DIRECTIONS {
                // Hidden: nearer than the background and sharper by more than a pixel. The
                // first step may be the silhouette's anti-aliased pixel, which carries the
                // background's depth.
                let hidden = |k: i32| -> bool {
                    let (qx, qy) = (x + d.0 * k, y + d.1 * k);
                    if qx < 0 || qy < 0 || qx >= w || qy >= h {
                        return false;
                    }
                    let q = (qy * w + qx) as usize;
                    let dq = depth_at(q);
                    dq < db && signed_coc(dq).abs() + 1.0 < coc_b.abs()
                };
                let first = if hidden(1) {
                    1
                } else if was_split
                    [((y + d.1).clamp(0, h - 1) * w + (x + d.0).clamp(0, w - 1)) as usize]
                    && hidden(2)
                {
                    2
                } else {
                    continue;
                };
                let mut steps = 0;
                for k in first..=reach {
                    if !hidden(k) {
                        break;
                    }
                    let q = ((y + d.1 * k) * w + x + d.0 * k) as usize;
                    fills[q] = fills[q].saturating_add(1);
                    steps = k;
                }
                if steps >= first {
                    walks.push((b, d, steps));
                }
            }
        }
    }
    let mut out = Vec::new();
    for (b, d, steps) in walks {
        let base = own(b);
        let (bx, by) = ((b as i32) % w, (b as i32) / w);
        for k in 1..=steps {
            let (qx, qy) = (bx + d.0 * k, by + d.1 * k);
            let q = (qy * w + qx) as usize;
            if fills[q] == 0 {
                continue;
            }
            out.push(Fragment {
                x: base.x + d.0 * k,
                y: base.y + d.1 * k,
                weight: 1.0 / f32::from(fills[q]),
                ..base
            });
        }
    }
    out
}
