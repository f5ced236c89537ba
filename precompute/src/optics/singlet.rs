//! A biconvex spherical singlet with an aperture stop in front of it, traced with Snell's law.
//!
//! Coordinates in millimetres: the optical axis is +z, light travels towards +z. The stop (a
//! disk of radius `stop_radius_mm`) lies in the plane z = 0 and is the entrance pupil; the
//! front vertex is at z = `stop_gap_mm`, the back vertex `thickness_mm` behind it, the sensor
//! plane at z = `sensor_z_mm`. Rays are blocked by the stop, by the lens rim (clear radius
//! `rim_radius_mm`, checked at both surfaces, i.e. the barrel), and by total internal
//! reflection.

use glam::DVec3;
use psf_db::Dispersion;

use super::glass::refractive_index;
use crate::PrecomputeError;

/// The singlet, its stop and its sensor.
#[derive(Clone, Debug, PartialEq)]
pub struct Singlet {
    /// Signed radius of the front surface, mm (> 0: centre behind it).
    pub radius_front_mm: f64,
    /// Signed radius of the back surface, mm (< 0 for a biconvex lens).
    pub radius_back_mm: f64,
    /// Centre thickness, mm.
    pub thickness_mm: f64,
    /// Clear (rim) radius of both surfaces, mm.
    pub rim_radius_mm: f64,
    /// Radius of the aperture stop, mm.
    pub stop_radius_mm: f64,
    /// Distance from the stop to the front vertex, mm (>= 0).
    pub stop_gap_mm: f64,
    /// The glass.
    pub glass: Dispersion,
    /// Axial position of the sensor plane, mm from the stop (set by [`Singlet::focus`]).
    pub sensor_z_mm: f64,
}

/// A ray after the lens: a point on the back surface and a unit direction.
#[derive(Clone, Copy, Debug)]
pub struct ExitRay {
    /// Point on the back surface, mm.
    pub point: DVec3,
    /// Unit direction.
    pub dir: DVec3,
}

impl Singlet {
    /// Checks the prescription: finite values, biconvex surfaces whose sag fits the thickness,
    /// positive stop and rim.
    pub fn validate(&self) -> Result<(), PrecomputeError> {
        let bad = |m: String| Err(PrecomputeError::InvalidLens(m));
        let vals = [
            self.radius_front_mm,
            self.radius_back_mm,
            self.thickness_mm,
            self.rim_radius_mm,
            self.stop_radius_mm,
            self.stop_gap_mm,
        ];
        if !vals.iter().all(|v| v.is_finite()) {
            return bad(format!("non-finite value in {vals:?}"));
        }
        if !(self.radius_front_mm > 0.0 && self.radius_back_mm < 0.0) {
            return bad("a biconvex lens needs radius_front > 0 and radius_back < 0".into());
        }
        if !(self.thickness_mm > 0.0 && self.rim_radius_mm > 0.0 && self.stop_radius_mm > 0.0) {
            return bad("thickness, lens diameter and stop diameter must be positive".into());
        }
        if self.stop_gap_mm < 0.0 {
            return bad("the stop must lie in front of the lens (stop position <= 0)".into());
        }
        if self.rim_radius_mm >= self.radius_front_mm.min(-self.radius_back_mm) {
            return bad("the lens diameter exceeds a surface's sphere".into());
        }
        let sag = |r: f64| r.abs() - (r * r - self.rim_radius_mm * self.rim_radius_mm).sqrt();
        if sag(self.radius_front_mm) + sag(self.radius_back_mm) >= self.thickness_mm {
            return bad("the surfaces cross inside the lens diameter (edge thickness <= 0)".into());
        }
        Ok(())
    }

    /// Refractive index of the glass at `lambda_um`.
    pub fn index(&self, lambda_um: f64) -> f64 {
        refractive_index(&self.glass, lambda_um)
    }

    /// Traces a ray from `origin` along `dir` (unit, `dir.z > 0`) through both surfaces, for
    /// glass index `n`. `None` when it misses the stop, the rim, or totally reflects.
    #[inline]
    pub fn trace_through(&self, origin: DVec3, dir: DVec3, n: f64) -> Option<ExitRay> {
        if dir.z <= 0.0 {
            return None;
        }
        // Stop plane z = 0.
        let t0 = -origin.z / dir.z;
        let at_stop = origin + t0 * dir;
        if at_stop.x * at_stop.x + at_stop.y * at_stop.y > self.stop_radius_mm * self.stop_radius_mm
        {
            return None;
        }
        let front_vertex = self.stop_gap_mm;
        let back_vertex = self.stop_gap_mm + self.thickness_mm;
        let p1 = self.hit_sphere(at_stop, dir, front_vertex, self.radius_front_mm)?;
        let d1 = refract(
            dir,
            self.normal(p1, front_vertex, self.radius_front_mm),
            1.0 / n,
        )?;
        let p2 = self.hit_sphere(p1, d1, back_vertex, self.radius_back_mm)?;
        let d2 = refract(d1, self.normal(p2, back_vertex, self.radius_back_mm), n)?;
        Some(ExitRay { point: p2, dir: d2 })
    }

    /// Where a ray lands on the sensor plane, mm (`[x, y]`), or `None` if blocked.
    #[inline]
    pub fn trace_to_sensor(&self, origin: DVec3, dir: DVec3, n: f64) -> Option<[f64; 2]> {
        let exit = self.trace_through(origin, dir, n)?;
        if exit.dir.z <= 0.0 {
            return None;
        }
        let t = (self.sensor_z_mm - exit.point.z) / exit.dir.z;
        let p = exit.point + t * exit.dir;
        Some([p.x, p.y])
    }

    /// The intersection of a ray with the spherical surface whose vertex is at z = `vertex`
    /// with signed radius `r`, inside the rim; the root on the vertex's side of the sphere.
    #[inline]
    fn hit_sphere(&self, o: DVec3, d: DVec3, vertex: f64, r: f64) -> Option<DVec3> {
        let c = DVec3::new(0.0, 0.0, vertex + r);
        let oc = o - c;
        let b = oc.dot(d);
        let q = oc.length_squared() - r * r;
        let disc = b * b - q;
        if disc < 0.0 {
            return None;
        }
        let s = disc.sqrt();
        // r > 0: the surface faces -z, the nearer root; r < 0: it faces +z, the farther one.
        let t = if r > 0.0 { -b - s } else { -b + s };
        if t < 0.0 {
            return None;
        }
        let p = o + t * d;
        if p.x * p.x + p.y * p.y > self.rim_radius_mm * self.rim_radius_mm {
            return None;
        }
        Some(p)
    }

    #[inline]
    fn normal(&self, p: DVec3, vertex: f64, r: f64) -> DVec3 {
        (p - DVec3::new(0.0, 0.0, vertex + r)) / r.abs()
    }

    /// A paraxial ray from the axis point at `object_z` (mm, < 0) through the stop at height
    /// `h` mm: where it leaves the lens.
    fn paraxial_exit(&self, object_z: f64, h: f64, lambda_um: f64) -> Option<ExitRay> {
        let o = DVec3::new(0.0, 0.0, object_z);
        let d = (DVec3::new(h, 0.0, 0.0) - o).normalize();
        self.trace_through(o, d, self.index(lambda_um))
    }

    /// Moves the sensor to where an axial object `object_distance_mm` in front of the stop
    /// comes to a paraxial focus at `lambda_um`.
    pub fn focus(
        &mut self,
        object_distance_mm: f64,
        lambda_um: f64,
    ) -> Result<(), PrecomputeError> {
        let h = 1e-3 * self.stop_radius_mm;
        let exit = self
            .paraxial_exit(-object_distance_mm, h, lambda_um)
            .ok_or_else(|| PrecomputeError::InvalidLens("the axial ray is blocked".into()))?;
        if exit.dir.x.is_nan() || exit.dir.x >= 0.0 {
            return Err(PrecomputeError::InvalidLens(format!(
                "the focus distance {object_distance_mm} mm does not form a real image \
                 (it lies inside the focal length)"
            )));
        }
        let t = -exit.point.x / exit.dir.x;
        self.sensor_z_mm = exit.point.z + t * exit.dir.z;
        Ok(())
    }

    /// Paraxial (effective) focal length at `lambda_um`, mm: `-h / slope` of a ray entering
    /// parallel to the axis at height `h`.
    pub fn focal_length(&self, lambda_um: f64) -> f64 {
        let h = 1e-3 * self.stop_radius_mm;
        let o = DVec3::new(h, 0.0, -1.0);
        match self.trace_through(o, DVec3::Z, self.index(lambda_um)) {
            Some(e) => -h / (e.dir.x / e.dir.z),
            None => f64::NAN,
        }
    }

    /// Image distance of the equivalent pinhole camera, mm: a pinhole at the stop centre
    /// projecting a chief ray of slope `tan(theta)` to sensor height `D tan(theta)` (on the
    /// other side of the axis), with `D` chosen so that paraxial chief rays land where the lens
    /// puts them.
    pub fn pinhole_distance(&self, lambda_um: f64) -> f64 {
        let slope = 1e-4;
        let o = DVec3::new(-slope * 1000.0, 0.0, -1000.0);
        let d = (DVec3::ZERO - o).normalize();
        match self.trace_to_sensor(o, d, self.index(lambda_um)) {
            Some(p) => p[0] / slope,
            None => f64::NAN,
        }
    }
}

/// Snell refraction of unit `d` at a surface with unit normal `n` (either orientation),
/// `eta = n_incident / n_transmitted`; `None` on total internal reflection.
#[inline]
pub fn refract(d: DVec3, n: DVec3, eta: f64) -> Option<DVec3> {
    let n = if n.dot(d) > 0.0 { -n } else { n };
    let cos_i = -n.dot(d);
    let sin2_t = eta * eta * (1.0 - cos_i * cos_i);
    if sin2_t > 1.0 {
        return None;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    Some(eta * d + (eta * cos_i - cos_t) * n)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::optics::glass::BK7;

    fn lens() -> Singlet {
        Singlet {
            radius_front_mm: 51.68,
            radius_back_mm: -51.68,
            thickness_mm: 6.0,
            rim_radius_mm: 8.0,
            stop_radius_mm: 6.0,
            stop_gap_mm: 15.0,
            glass: BK7,
            sensor_z_mm: 0.0,
        }
    }

    #[test]
    fn snell_law_holds() {
        let d = DVec3::new(0.5f64.sin(), 0.0, 0.5f64.cos());
        let t = refract(d, DVec3::new(0.0, 0.0, -1.0), 1.0 / 1.5).unwrap();
        assert!((t.length() - 1.0).abs() < 1e-12);
        assert!((t.x - 0.5f64.sin() / 1.5).abs() < 1e-12);
        // Total internal reflection from glass at a grazing angle.
        let g = DVec3::new(0.9f64.sin(), 0.0, 0.9f64.cos());
        assert!(refract(g, DVec3::Z, 1.5).is_none());
    }

    #[test]
    fn lensmaker_focal_length_and_thin_lens_focus() {
        let mut l = lens();
        l.validate().unwrap();
        let n = l.index(0.58756);
        // Thick-lens lensmaker: 1/f = (n-1) (1/R1 - 1/R2 + (n-1) t / (n R1 R2)).
        let (r1, r2, t) = (51.68, -51.68, 6.0);
        let f = 1.0 / ((n - 1.0) * (1.0 / r1 - 1.0 / r2 + (n - 1.0) * t / (n * r1 * r2)));
        assert!((l.focal_length(0.58756) - f).abs() < 1e-3 * f);
        // Blue focuses shorter than red (normal dispersion).
        assert!(l.focal_length(0.45) < l.focal_length(0.65));
        // Focused at infinity-ish, the sensor sits one focal length behind the rear
        // principal plane; focusing closer moves it back.
        l.focus(1e7, 0.58756).unwrap();
        let far = l.sensor_z_mm;
        l.focus(1000.0, 0.58756).unwrap();
        assert!(l.sensor_z_mm > far);
        // Newton: the extension is ~ f^2 / (object distance from the front focal point).
        let ext = l.sensor_z_mm - far;
        assert!(
            (ext - f * f / 1000.0).abs() < 0.1 * ext,
            "{ext} vs {}",
            f * f / 1000.0
        );
        assert!(l.focus(20.0, 0.58756).is_err());
    }
}
