//! The shared front end of the tile-based motion blur filters (McGuire et al. 2012, Guertin et
//! al. 2014): velocity clamping, TileMax and NeighborMax.

/// Length of a 2D vector.
pub(crate) fn len2(v: [f32; 2]) -> f32 {
    (v[0] * v[0] + v[1] * v[1]).sqrt()
}

/// Clamped half-velocity in pixels (thesis Eq. 2.4 and Sec. 3.5): the blur of a pixel spans
/// `[-V, +V]` around it, so `V` is half the motion over the shutter; its length is clamped to
/// `[0.5, r]` (a zero vector stays zero), with `eps = 1e-5` as in the thesis.
pub(crate) fn clamp_half_velocity(motion_over_shutter: [f32; 2], r: f32) -> [f32; 2] {
    let h = [0.5 * motion_over_shutter[0], 0.5 * motion_over_shutter[1]];
    let l = len2(h);
    let s = l.min(r).max(0.5) / (l + 1e-5);
    [h[0] * s, h[1] * s]
}

/// Tile grid of `r x r` pixel tiles over a `width x height` image.
#[derive(Debug, Clone)]
pub(crate) struct TileGrid {
    pub r: usize,
    pub tw: usize,
    pub th: usize,
    /// Per tile: the velocity of largest length (TileMax), then after `neighbor_max`, the
    /// dominant neighbourhood velocity.
    pub v: Vec<[f32; 2]>,
}

/// TileMax (thesis Eq. 2.5): per `r x r` tile, the clamped velocity of largest length.
/// Ties keep the first in raster order, so the result is deterministic.
pub(crate) fn tile_max(width: usize, height: usize, vel: &[[f32; 2]], r: usize) -> TileGrid {
    let tw = width.div_ceil(r);
    let th = height.div_ceil(r);
    let mut v = vec![[0.0f32; 2]; tw * th];
    for ty in 0..th {
        for tx in 0..tw {
            let mut best = [0.0f32; 2];
            let mut best_len = -1.0f32;
            for y in ty * r..((ty + 1) * r).min(height) {
                for x in tx * r..((tx + 1) * r).min(width) {
                    let c = vel[y * width + x];
                    let l = len2(c);
                    if l > best_len {
                        best_len = l;
                        best = c;
                    }
                }
            }
            v[ty * tw + tx] = best;
        }
    }
    TileGrid { r, tw, th, v }
}

/// NeighborMax (thesis Eq. 2.6): the velocity of largest length among a tile and its 8
/// neighbours. With `diagonal_cos = Some(c)` (Guertin, Sec. 3.4.4), a diagonal neighbour only
/// counts if its velocity's line points at the centre tile: `|cos(angle(v, diagonal))| >= c`.
/// The thesis gives no threshold; `c = cos 45 deg` (the default) accepts exactly the
/// velocities whose line runs into the quadrant of the centre tile.
pub(crate) fn neighbor_max(tiles: &TileGrid, diagonal_cos: Option<f32>) -> TileGrid {
    let (tw, th) = (tiles.tw as isize, tiles.th as isize);
    let mut v = vec![[0.0f32; 2]; tiles.v.len()];
    for ty in 0..th {
        for tx in 0..tw {
            let mut best = [0.0f32; 2];
            let mut best_len = -1.0f32;
            for dy in -1isize..=1 {
                for dx in -1isize..=1 {
                    let (nx, ny) = (tx + dx, ty + dy);
                    if nx < 0 || ny < 0 || nx >= tw || ny >= th {
                        continue;
                    }
                    let c = tiles.v[(ny * tw + nx) as usize];
                    let l = len2(c);
                    if dx != 0 && dy != 0 {
                        if let Some(min_cos) = diagonal_cos {
                            if l <= 0.0 {
                                continue;
                            }
                            // Unit diagonal from the neighbour to the centre.
                            let d = [-dx as f32, -dy as f32];
                            let cos = (c[0] * d[0] + c[1] * d[1]) / (l * std::f32::consts::SQRT_2);
                            if cos.abs() <= min_cos + 1e-6 {
                                continue;
                            }
                        }
                    }
                    if l > best_len {
                        best_len = l;
                        best = c;
                    }
                }
            }
            v[(ty * tw + tx) as usize] = best;
        }
    }
    TileGrid {
        r: tiles.r,
        tw: tiles.tw,
        th: tiles.th,
        v,
    }
}

/// Clamped half-velocities of a whole G-buffer.
pub(crate) fn half_velocities(motion: &[[f32; 2]], r: f32) -> Vec<[f32; 2]> {
    motion.iter().map(|m| clamp_half_velocity(*m, r)).collect()
}

/// `1 - smoothstep(0.95 l, 1.05 l, |t|)`: McGuire's cylinder.
pub(crate) fn cylinder(t: f32, l: f32) -> f32 {
    let (e0, e1) = (0.95 * l, 1.05 * l);
    let x = ((t.abs() - e0) / (e1 - e0).max(1e-12)).clamp(0.0, 1.0);
    1.0 - x * x * (3.0 - 2.0 * x)
}

/// `clamp(1 - |t| / l, 0, 1)`: McGuire's cone.
pub(crate) fn cone(t: f32, l: f32) -> f32 {
    (1.0 - t.abs() / l.max(1e-12)).clamp(0.0, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clamp_keeps_direction_and_bounds_length() {
        let v = clamp_half_velocity([200.0, 0.0], 40.0);
        assert!((v[0] - 40.0).abs() < 1e-3 && v[1] == 0.0);
        let v = clamp_half_velocity([0.0, 0.2], 40.0);
        assert!((len2(v) - 0.5).abs() < 1e-3 && v[1] > 0.0);
        assert_eq!(clamp_half_velocity([0.0, 0.0], 40.0), [0.0, 0.0]);
    }

    #[test]
    fn diagonal_test_drops_tiles_that_cannot_reach_the_centre() {
        // 3x3 tiles; the top-left tile moves along +x (cannot reach the centre), the
        // bottom-right along the diagonal (can).
        let mut g = TileGrid {
            r: 4,
            tw: 3,
            th: 3,
            v: vec![[0.0; 2]; 9],
        };
        g.v[0] = [10.0, 0.0];
        let mcguire = neighbor_max(&g, None);
        let guertin = neighbor_max(&g, Some(std::f32::consts::FRAC_1_SQRT_2));
        assert_eq!(mcguire.v[4], [10.0, 0.0]);
        assert_eq!(guertin.v[4], [0.0, 0.0]);
        g.v[8] = [-3.0, -3.0];
        let guertin = neighbor_max(&g, Some(std::f32::consts::FRAC_1_SQRT_2));
        assert_eq!(guertin.v[4], [-3.0, -3.0]);
    }
}
