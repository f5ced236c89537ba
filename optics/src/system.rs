//! Sequential ray tracing through a prescription's spherical surfaces.
//!
//! Lens coordinates, millimetres: the optical axis is +z and light from the scene travels
//! towards +z; the first surface's vertex is at z = 0, each next vertex one thickness further;
//! the sensor plane is at z = `sensor_z_mm`. Every surface blocks rays outside its clear
//! aperture (the barrel and the stop: vignetting, cat-eye bokeh off axis) and rays that are
//! totally reflected.
//!
//! The scene side is described from the entrance pupil (the stop as seen from the scene, found
//! paraxially): the equivalent pinhole camera of a G-buffer sits at its centre, and depths are
//! measured from it. Focusing moves the lens against the sensor (here: the sensor against the
//! lens, which is the same relative motion), so the image scale changes with focus (focus
//! breathing), as with a real lens.

use glam::DVec3;

use crate::prescription::{Medium, Prescription, PrescriptionError};
use crate::spectrum::LAMBDA_DESIGN_NM;

/// A ray: a point and a unit direction, lens coordinates (mm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LensRay {
    /// Point, mm.
    pub origin: DVec3,
    /// Unit direction.
    pub dir: DVec3,
}

/// A prescription placed in front of a sensor.
#[derive(Clone, Debug, PartialEq)]
pub struct LensSystem {
    /// The lens.
    pub prescription: Prescription,
    vertex_z: Vec<f64>,
    /// Axial position of the sensor, mm (set by [`LensSystem::focus`]).
    pub sensor_z_mm: f64,
}

/// Design wavelength, um.
pub const LAMBDA_DESIGN_UM: f64 = LAMBDA_DESIGN_NM * 1e-3;

impl LensSystem {
    /// The lens with its sensor at the prescription's nominal image plane.
    pub fn new(prescription: Prescription) -> Result<LensSystem, PrescriptionError> {
        prescription.validate()?;
        let mut vertex_z = Vec::with_capacity(prescription.surfaces.len());
        let mut z = 0.0;
        for s in &prescription.surfaces {
            vertex_z.push(z);
            z += s.thickness_mm;
        }
        Ok(LensSystem {
            prescription,
            vertex_z,
            sensor_z_mm: z,
        })
    }

    /// `prescription` stopped down to `f_stop` (paraxial focal length over entrance pupil
    /// diameter; `None`: wide open) and focused on an axial point `focus_distance_mm` in front
    /// of its entrance pupil, at the design wavelength.
    pub fn focused(
        prescription: Prescription,
        f_stop: Option<f64>,
        focus_distance_mm: f64,
    ) -> Result<LensSystem, PrescriptionError> {
        let open = LensSystem::new(prescription)?;
        let mut system = match f_stop {
            None => open,
            Some(n) => {
                let widest = open.f_number(LAMBDA_DESIGN_UM)?;
                if !(n.is_finite() && n >= widest * (1.0 - 1e-9)) {
                    return Err(open.invalid(format!(
                        "f/{n} is wider than the lens opens (f/{widest:.3})"
                    )));
                }
                // The entrance pupil scales with the stop (paraxially).
                LensSystem::new(open.prescription.with_stop_scaled(widest / n))?
            }
        };
        system.focus(focus_distance_mm, LAMBDA_DESIGN_UM)?;
        Ok(system)
    }

    fn invalid(&self, message: impl Into<String>) -> PrescriptionError {
        PrescriptionError::Invalid {
            name: self.prescription.name.clone(),
            message: message.into(),
        }
    }

    /// Axial position of surface `i`'s vertex, mm.
    pub fn vertex_z(&self, i: usize) -> f64 {
        self.vertex_z[i]
    }

    /// Axial position of the last surface's vertex, mm.
    pub fn rear_vertex_z(&self) -> f64 {
        self.vertex_z.last().copied().unwrap_or(0.0)
    }

    /// Clear aperture radius of the last surface, mm.
    pub fn rear_aperture_radius(&self) -> f64 {
        self.prescription
            .surfaces
            .last()
            .map_or(0.0, |s| 0.5 * s.aperture_diameter_mm)
    }

    /// Radius of the aperture stop, mm.
    pub fn stop_radius(&self) -> f64 {
        0.5 * self.prescription.surfaces[self.prescription.stop_index()].aperture_diameter_mm
    }

    fn medium_before(&self, i: usize) -> &Medium {
        if i == 0 {
            &Medium::Air
        } else {
            &self.prescription.surfaces[i - 1].medium
        }
    }

    /// Where a ray from `o` along `d` meets surface `i` inside its clear aperture.
    #[inline]
    fn intersect(&self, i: usize, o: DVec3, d: DVec3) -> Option<(DVec3, DVec3)> {
        let s = &self.prescription.surfaces[i];
        let v = self.vertex_z[i];
        let (p, normal) = if s.radius_mm == 0.0 {
            if d.z == 0.0 {
                return None;
            }
            let t = (v - o.z) / d.z;
            if t < 0.0 {
                return None;
            }
            (o + t * d, DVec3::NEG_Z)
        } else {
            let r = s.radius_mm;
            // From far away (a scene point metres off), first step onto the vertex plane:
            // the quadratic loses every digit to cancellation when |o - c| >> r.
            let (o, t_plane) = if d.z != 0.0 && (o.z - v).abs() > 4.0 * r.abs() {
                let t = (v - o.z) / d.z;
                (o + t * d, t)
            } else {
                (o, 0.0)
            };
            let c = DVec3::new(0.0, 0.0, v + r);
            let oc = o - c;
            let b = oc.dot(d);
            let disc = b * b - (oc.length_squared() - r * r);
            if disc < 0.0 {
                return None;
            }
            let root = disc.sqrt();
            // The root on the vertex's side of the sphere: the nearer one when the ray runs
            // into the sphere's convex face.
            let closer = (d.z > 0.0) ^ (r < 0.0);
            let t = if closer { -b - root } else { -b + root };
            if t + t_plane < 0.0 {
                return None;
            }
            let p = o + t * d;
            (p, (p - c) / r.abs())
        };
        let half = 0.5 * s.aperture_diameter_mm;
        if p.x * p.x + p.y * p.y > half * half {
            return None;
        }
        Some((p, normal))
    }

    /// Traces a ray from the scene side (`d.z > 0`) through every surface; the ray behind the
    /// last one, or `None` when blocked.
    #[inline]
    pub fn trace_forward(&self, o: DVec3, d: DVec3, lambda_um: f64) -> Option<LensRay> {
        let (mut o, mut d) = (o, d);
        for (i, s) in self.prescription.surfaces.iter().enumerate() {
            let (p, normal) = self.intersect(i, o, d)?;
            let n1 = self.medium_before(i).index(lambda_um);
            let n2 = s.medium.index(lambda_um);
            if n1 != n2 {
                d = refract(d, normal, n1 / n2)?;
            }
            o = p;
        }
        Some(LensRay { origin: o, dir: d })
    }

    /// Traces a ray from the sensor side (`d.z < 0`) back through every surface; the ray in
    /// front of the first one (travelling towards the scene), or `None` when blocked.
    #[inline]
    pub fn trace_backward(&self, o: DVec3, d: DVec3, lambda_um: f64) -> Option<LensRay> {
        let (mut o, mut d) = (o, d);
        for i in (0..self.prescription.surfaces.len()).rev() {
            let (p, normal) = self.intersect(i, o, d)?;
            let n1 = self.prescription.surfaces[i].medium.index(lambda_um);
            let n2 = self.medium_before(i).index(lambda_um);
            if n1 != n2 {
                d = refract(d, normal, n1 / n2)?;
            }
            o = p;
        }
        Some(LensRay { origin: o, dir: d })
    }

    /// Where a scene-side ray lands on the sensor, mm (`[x, y]`), or `None` if blocked.
    #[inline]
    pub fn trace_to_sensor(&self, o: DVec3, d: DVec3, lambda_um: f64) -> Option<[f64; 2]> {
        let exit = self.trace_forward(o, d, lambda_um)?;
        if exit.dir.z <= 0.0 {
            return None;
        }
        let t = (self.sensor_z_mm - exit.origin.z) / exit.dir.z;
        let p = exit.origin + t * exit.dir;
        Some([p.x, p.y])
    }

    /// Paraxial (effective) focal length at `lambda_um`, mm.
    pub fn focal_length(&self, lambda_um: f64) -> f64 {
        let h = 1e-3 * self.stop_radius();
        let o = DVec3::new(h, 0.0, -1.0);
        match self.trace_forward(o, DVec3::Z, lambda_um) {
            Some(e) if e.dir.x != 0.0 => -h / (e.dir.x / e.dir.z),
            _ => f64::NAN,
        }
    }

    /// The entrance pupil at `lambda_um`: the axial position of its centre (mm, lens
    /// coordinates) and its radius (mm): the paraxial image of the stop through the surfaces
    /// in front of it.
    pub fn entrance_pupil(&self, lambda_um: f64) -> Result<(f64, f64), PrescriptionError> {
        let k = self.prescription.stop_index();
        let stop_z = self.vertex_z[k];
        let stop_r = self.stop_radius();
        if k == 0 {
            return Ok((stop_z, stop_r));
        }
        let front = LensSystem {
            prescription: Prescription {
                surfaces: self.prescription.surfaces[..k].to_vec(),
                ..self.prescription.clone()
            },
            vertex_z: self.vertex_z[..k].to_vec(),
            sensor_z_mm: stop_z,
        };
        let eps = 1e-4;
        // The chief ray: from the stop centre, out through the front group.
        let chief = front
            .trace_backward_unclipped(
                DVec3::new(0.0, 0.0, stop_z),
                DVec3::new(eps, 0.0, -1.0).normalize(),
                lambda_um,
            )
            .ok_or_else(|| self.invalid("the chief ray does not leave the lens"))?;
        if chief.dir.x == 0.0 {
            return Err(self.invalid("the front group images the stop at infinity"));
        }
        let ep_z = chief.origin.z - chief.origin.x * chief.dir.z / chief.dir.x;
        // A ray from the stop's rim parallel to the axis passes through the rim's image.
        let h = 1e-3 * stop_r;
        let rim = front
            .trace_backward_unclipped(DVec3::new(h, 0.0, stop_z), DVec3::NEG_Z, lambda_um)
            .ok_or_else(|| self.invalid("the marginal ray does not leave the lens"))?;
        let height = rim.origin.x + (ep_z - rim.origin.z) * rim.dir.x / rim.dir.z;
        let radius = stop_r * height.abs() / h;
        if !(ep_z.is_finite() && radius.is_finite() && radius > 0.0) {
            return Err(self.invalid("the entrance pupil is degenerate"));
        }
        Ok((ep_z, radius))
    }

    /// [`LensSystem::trace_backward`] for paraxial rays, ignoring the clear apertures.
    fn trace_backward_unclipped(&self, o: DVec3, d: DVec3, lambda_um: f64) -> Option<LensRay> {
        let mut open = self.clone();
        for s in &mut open.prescription.surfaces {
            s.aperture_diameter_mm = f64::MAX.sqrt();
        }
        open.trace_backward(o, d, lambda_um)
    }

    /// Paraxial f-number at `lambda_um`: focal length over entrance pupil diameter.
    pub fn f_number(&self, lambda_um: f64) -> Result<f64, PrescriptionError> {
        let (_, r) = self.entrance_pupil(lambda_um)?;
        Ok(self.focal_length(lambda_um) / (2.0 * r))
    }

    /// Moves the sensor to where an axial point `object_distance_mm` in front of the entrance
    /// pupil comes to a paraxial focus at `lambda_um` (moving the lens against the sensor).
    pub fn focus(
        &mut self,
        object_distance_mm: f64,
        lambda_um: f64,
    ) -> Result<(), PrescriptionError> {
        let (ep_z, ep_r) = self.entrance_pupil(lambda_um)?;
        let o = DVec3::new(0.0, 0.0, ep_z - object_distance_mm);
        let d = (DVec3::new(1e-3 * ep_r, 0.0, ep_z) - o).normalize();
        let exit = self
            .trace_forward(o, d, lambda_um)
            .ok_or_else(|| self.invalid("the axial ray is blocked"))?;
        if exit.dir.x.is_nan() || exit.dir.x >= 0.0 {
            return Err(self.invalid(format!(
                "the focus distance {object_distance_mm} mm does not form a real image \
                 (it lies inside the focal length)"
            )));
        }
        let t = -exit.origin.x / exit.dir.x;
        self.sensor_z_mm = exit.origin.z + t * exit.dir.z;
        Ok(())
    }

    /// Image distance of the equivalent pinhole camera at the entrance pupil's centre, mm:
    /// chief rays from points `object_distance_mm` in front of the pupil at slope `tan(theta)`
    /// land (paraxially) `D tan(theta)` from the sensor centre, on the other side of the axis.
    pub fn pinhole_distance(&self, object_distance_mm: f64, lambda_um: f64) -> f64 {
        let Ok((ep_z, _)) = self.entrance_pupil(lambda_um) else {
            return f64::NAN;
        };
        let slope = 1e-4;
        let o = DVec3::new(-slope * object_distance_mm, 0.0, ep_z - object_distance_mm);
        let d = (DVec3::new(0.0, 0.0, ep_z) - o).normalize();
        match self.trace_to_sensor(o, d, lambda_um) {
            Some(p) => p[0] / slope,
            None => f64::NAN,
        }
    }

    /// The bounding box, on the plane `z = plane_z`, of the rays from `origin` through that
    /// plane that pass the whole lens (forward when `origin` is on the scene side, backward
    /// from the sensor side), searched on a `grid x grid` lattice over `[-half, half]^2`
    /// at each of `lambdas_um`, padded by one lattice cell; `None` when no ray passes.
    pub fn passing_box(
        &self,
        origin: DVec3,
        plane_z: f64,
        half: f64,
        grid: usize,
        lambdas_um: &[f64],
    ) -> Option<[f64; 4]> {
        let cell = 2.0 * half / grid as f64;
        let mut b = [
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ];
        let forward = origin.z < plane_z;
        for j in 0..grid {
            for i in 0..grid {
                let x = -half + (i as f64 + 0.5) * cell;
                let y = -half + (j as f64 + 0.5) * cell;
                let d = (DVec3::new(x, y, plane_z) - origin).normalize();
                let passes = lambdas_um.iter().any(|&l| {
                    if forward {
                        self.trace_to_sensor(origin, d, l).is_some()
                    } else {
                        self.trace_backward(origin, d, l).is_some()
                    }
                });
                if passes {
                    b = [b[0].min(x), b[1].max(x), b[2].min(y), b[3].max(y)];
                }
            }
        }
        (b[0] <= b[1]).then(|| [b[0] - cell, b[1] + cell, b[2] - cell, b[3] + cell])
    }
}

/// Bounds of the rays that pass a lens, per radial bin of where they start (pbrt's exit pupil
/// bounds): the rays from a point at radius `r` along +x pass through the box of `r`'s bin on
/// the plane `z = plane_z`; for a point at angle `phi`, turn the box by `phi`.
#[derive(Clone, Debug, PartialEq)]
pub struct PupilBounds {
    /// Plane the boxes lie on, mm.
    pub plane_z: f64,
    /// Largest radius covered, mm.
    pub max_radius: f64,
    /// `[x_min, x_max, y_min, y_max]` per bin, mm; `None` where nothing passes.
    pub boxes: Vec<Option<[f64; 4]>>,
}

impl PupilBounds {
    /// Bins `bins` radii over `[0, max_radius]`; `origins(r)` gives the start points standing
    /// for radius `r` (at +x), and each bin is the union of the boxes of its two edges and its
    /// centre.
    pub fn build(
        lens: &LensSystem,
        bins: usize,
        max_radius: f64,
        plane_z: f64,
        half: f64,
        grid: usize,
        origins: &dyn Fn(f64) -> Vec<DVec3>,
    ) -> PupilBounds {
        let lambdas = [0.40, LAMBDA_DESIGN_UM, 0.70];
        let boxes = (0..bins)
            .map(|k| {
                let mut out: Option<[f64; 4]> = None;
                for f in [0.0, 0.5, 1.0] {
                    let r = (k as f64 + f) / bins as f64 * max_radius;
                    for o in origins(r) {
                        if let Some(b) = lens.passing_box(o, plane_z, half, grid, &lambdas) {
                            out = Some(match out {
                                None => b,
                                Some(a) => [
                                    a[0].min(b[0]),
                                    a[1].max(b[1]),
                                    a[2].min(b[2]),
                                    a[3].max(b[3]),
                                ],
                            });
                        }
                    }
                }
                out
            })
            .collect();
        PupilBounds {
            plane_z,
            max_radius,
            boxes,
        }
    }

    /// The box for radius `r`, mm (clamped to the covered range).
    #[inline]
    pub fn at(&self, r: f64) -> Option<[f64; 4]> {
        let n = self.boxes.len();
        if n == 0 {
            return None;
        }
        let k = ((r / self.max_radius * n as f64) as usize).min(n - 1);
        self.boxes[k]
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

    fn singlet() -> LensSystem {
        LensSystem::new(Prescription::builtin("singlet-51mm").expect("builtin")).expect("lens")
    }

    #[test]
    fn snell_law_holds() {
        let d = DVec3::new(0.5f64.sin(), 0.0, 0.5f64.cos());
        let t = refract(d, DVec3::new(0.0, 0.0, -1.0), 1.0 / 1.5).expect("refracts");
        assert!((t.length() - 1.0).abs() < 1e-12);
        assert!((t.x - 0.5f64.sin() / 1.5).abs() < 1e-12);
        let g = DVec3::new(0.9f64.sin(), 0.0, 0.9f64.cos());
        assert!(refract(g, DVec3::Z, 1.5).is_none());
    }

    #[test]
    fn singlet_focal_length_is_the_lensmakers() {
        let mut l = singlet();
        let n = l.prescription.surfaces[1].medium.index(LAMBDA_DESIGN_UM);
        // Thick-lens lensmaker: 1/f = (n-1) (1/R1 - 1/R2 + (n-1) t / (n R1 R2)).
        let (r1, r2, t) = (51.68, -51.68, 6.0);
        let f = 1.0 / ((n - 1.0) * (1.0 / r1 - 1.0 / r2 + (n - 1.0) * t / (n * r1 * r2)));
        assert!((l.focal_length(LAMBDA_DESIGN_UM) - f).abs() < 1e-3 * f);
        assert!(l.focal_length(0.45) < l.focal_length(0.65));
        // The stop is the first surface: it is the entrance pupil.
        let (z, r) = l.entrance_pupil(LAMBDA_DESIGN_UM).expect("pupil");
        assert!(z.abs() < 1e-12 && (r - 6.0).abs() < 1e-12);
        l.focus(1e7, LAMBDA_DESIGN_UM).expect("focus");
        let far = l.sensor_z_mm;
        l.focus(1000.0, LAMBDA_DESIGN_UM).expect("focus");
        assert!(l.sensor_z_mm > far);
        assert!(l.focus(20.0, LAMBDA_DESIGN_UM).is_err());
    }

    /// Published focal lengths: the double Gauss is scaled to 50 mm, the wide angle to 22 mm
    /// (the tables' scaling is nominal: within 3 %).
    #[test]
    fn multi_element_lenses_have_their_published_focal_lengths() {
        for (name, f, fno) in [
            ("double-gauss-50mm", 50.0, 2.0),
            ("wide-angle-22mm", 22.0, 4.0),
        ] {
            let l = LensSystem::new(Prescription::builtin(name).expect("builtin")).expect("lens");
            let efl = l.focal_length(LAMBDA_DESIGN_UM);
            assert!((efl - f).abs() < 0.03 * f, "{name}: f = {efl}");
            let n = l.f_number(LAMBDA_DESIGN_UM).expect("pupil");
            assert!(n > 0.6 * fno && n < 1.6 * fno, "{name}: f/{n}");
            // Focused at infinity, the pinhole distance is the focal length.
            let mut l = l;
            l.focus(1e9, LAMBDA_DESIGN_UM).expect("focus");
            let d = l.pinhole_distance(1e9, LAMBDA_DESIGN_UM);
            assert!((d - efl).abs() < 1e-3 * efl, "{name}: D = {d}, f = {efl}");
            // Focusing closer moves the lens out: the image grows (focus breathing).
            l.focus(500.0, LAMBDA_DESIGN_UM).expect("focus");
            assert!(l.pinhole_distance(500.0, LAMBDA_DESIGN_UM) > 1.02 * efl);
        }
    }

    /// A forward ray and the backward ray from where it lands retrace the same path.
    #[test]
    fn forward_and_backward_tracing_are_reversible() {
        let mut l =
            LensSystem::new(Prescription::builtin("double-gauss-50mm").expect("b")).expect("l");
        l.focus(2000.0, LAMBDA_DESIGN_UM).expect("focus");
        let o = DVec3::new(-300.0, 120.0, -2000.0);
        let d = (DVec3::new(3.0, -2.0, 10.0) - o).normalize();
        let exit = l.trace_forward(o, d, 0.5).expect("passes");
        let on_sensor = exit.origin + (l.sensor_z_mm - exit.origin.z) / exit.dir.z * exit.dir;
        let back = l
            .trace_backward(on_sensor, -exit.dir, 0.5)
            .expect("passes back");
        // Back in front of the lens, the ray runs along the original line, reversed.
        assert!((back.dir + d).length() < 1e-9, "{:?} vs {:?}", back.dir, d);
        let along = (back.origin - o).cross(d).length();
        assert!(along < 1e-6, "{along}");
    }
}
