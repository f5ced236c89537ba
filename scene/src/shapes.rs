//! Analytic shapes (sphere, box, quad, infinite plane) and their rigid motion over the shutter.
//!
//! Every shape is described at the frame time t = 0 ("rest" frame). Its motion maps a rest
//! point `x0` to the world point at time `t` (frames):
//! `x(t) = pivot + velocity * t + R(axis, radians_per_frame * t) (x0 - pivot)`,
//! so a spinning object moves differently at every point. Rays are intersected by mapping
//! them back into the rest frame (a rigid map: ray distances are unchanged).

use glam::{DMat3, DQuat, DVec2, DVec3};
use serde::{Deserialize, Serialize};

use crate::camera::Ray;
use crate::error::{invalid, Result};

/// A fixed rotation: `degrees` about `axis` (right-handed).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxisAngle {
    /// Rotation axis (any length but zero).
    pub axis: DVec3,
    /// Angle in degrees.
    pub degrees: f64,
}

/// The geometry of an object at the frame time, in metres.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum Shape {
    /// A sphere.
    Sphere {
        /// Centre, metres.
        center: DVec3,
        /// Radius, metres.
        radius: f64,
    },
    /// A box: axis-aligned, or oriented by `rotation` about its centre.
    Box {
        /// Centre, metres.
        center: DVec3,
        /// Half the edge lengths along the box's own axes, metres.
        half_size: DVec3,
        /// Orientation of the box's axes (none: axis-aligned).
        #[serde(default)]
        rotation: Option<AxisAngle>,
    },
    /// A parallelogram `corner + a * edge_u + b * edge_v`, a and b in [0, 1]; two-sided.
    Quad {
        /// One corner, metres.
        corner: DVec3,
        /// First edge, metres (texture u).
        edge_u: DVec3,
        /// Second edge, metres (texture v).
        edge_v: DVec3,
    },
    /// An infinite plane through `point` with normal `normal`; two-sided. Texture
    /// coordinates are metres along two tangents.
    Plane {
        /// A point on the plane, metres.
        point: DVec3,
        /// The normal (any length but zero).
        normal: DVec3,
    },
}

/// A spin about an axis through `pivot`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Spin {
    /// Rotation axis (any length but zero), right-handed.
    pub axis: DVec3,
    /// Angular velocity in radians per frame.
    pub radians_per_frame: f64,
    /// A point on the axis, metres; defaults to the shape's centre.
    #[serde(default)]
    pub pivot: Option<DVec3>,
}

/// Rigid motion over the shutter: translation plus an optional spin.
#[derive(Clone, Debug, PartialEq)]
pub struct Motion {
    /// Linear velocity, metres per frame.
    pub velocity: DVec3,
    /// Unit spin axis (zero when not spinning).
    pub axis: DVec3,
    /// Angular velocity, radians per frame.
    pub radians_per_frame: f64,
    /// Point on the spin axis, metres.
    pub pivot: DVec3,
}

impl Motion {
    /// Motion from the scene file's fields; `centre` is the default pivot.
    pub fn new(velocity: DVec3, spin: Option<&Spin>, centre: DVec3, context: &str) -> Result<Self> {
        if !velocity.is_finite() {
            return Err(invalid(context, "velocity must be finite"));
        }
        let Some(spin) = spin else {
            return Ok(Self {
                velocity,
                axis: DVec3::ZERO,
                radians_per_frame: 0.0,
                pivot: centre,
            });
        };
        let axis = spin.axis.normalize_or_zero();
        if axis == DVec3::ZERO || !spin.radians_per_frame.is_finite() {
            return Err(invalid(
                context,
                "spin needs a non-zero axis and a finite radians_per_frame",
            ));
        }
        let pivot = spin.pivot.unwrap_or(centre);
        if !pivot.is_finite() {
            return Err(invalid(context, "spin pivot must be finite"));
        }
        Ok(Self {
            velocity,
            axis,
            radians_per_frame: spin.radians_per_frame,
            pivot,
        })
    }

    fn rotation(&self, time: f64) -> DQuat {
        if self.radians_per_frame == 0.0 {
            DQuat::IDENTITY
        } else {
            DQuat::from_axis_angle(self.axis, self.radians_per_frame * time)
        }
    }

    /// World position at `time` (frames) of the rest point `rest`.
    pub fn place(&self, rest: DVec3, time: f64) -> DVec3 {
        self.pivot + self.velocity * time + self.rotation(time) * (rest - self.pivot)
    }

    /// World direction at `time` of the rest direction `dir` (normals).
    pub fn rotate(&self, dir: DVec3, time: f64) -> DVec3 {
        self.rotation(time) * dir
    }

    /// The ray mapped into the rest frame of time `ray.time`.
    pub fn to_rest(&self, ray: &Ray) -> Ray {
        if self.radians_per_frame == 0.0 {
            // Pure translation (the common case): no rotation to undo.
            return Ray {
                origin: ray.origin - self.velocity * ray.time,
                ..*ray
            };
        }
        let inverse = self.rotation(ray.time).inverse();
        Ray {
            origin: self.pivot + inverse * (ray.origin - self.pivot - self.velocity * ray.time),
            direction: inverse * ray.direction,
            time: ray.time,
        }
    }
}

/// A hit in the rest frame of a shape.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RestHit {
    /// Ray distance, metres (the ray direction is unit length).
    pub distance: f64,
    /// Hit point in the rest frame, metres.
    pub point: DVec3,
    /// Geometric unit normal in the rest frame (outward; for two-sided shapes, facing the ray).
    pub normal: DVec3,
    /// Texture coordinates (see [`Shape`]).
    pub uv: DVec2,
}

/// A shape with its derived data, ready for intersection.
#[derive(Clone, Debug)]
pub struct PreparedShape {
    shape: Shape,
    /// Box orientation: world-from-box rotation (identity otherwise).
    basis: DMat3,
    plane_normal: DVec3,
    plane_tangents: (DVec3, DVec3),
}

impl PreparedShape {
    /// Validates the shape and precomputes its frames.
    pub fn new(shape: Shape, context: &str) -> Result<Self> {
        let mut basis = DMat3::IDENTITY;
        let mut plane_normal = DVec3::Z;
        match &shape {
            Shape::Sphere { center, radius } => {
                if !(center.is_finite() && radius.is_finite() && *radius > 0.0) {
                    return Err(invalid(
                        context,
                        "sphere needs a finite centre and radius > 0",
                    ));
                }
            }
            Shape::Box {
                center,
                half_size,
                rotation,
            } => {
                if !center.is_finite() || !half_size.is_finite() || half_size.min_element() <= 0.0 {
                    return Err(invalid(
                        context,
                        "box needs a finite centre and half_size > 0 along every axis",
                    ));
                }
                if let Some(r) = rotation {
                    let axis = r.axis.normalize_or_zero();
                    if axis == DVec3::ZERO || !r.degrees.is_finite() {
                        return Err(invalid(context, "box rotation needs a non-zero axis"));
                    }
                    basis = DMat3::from_axis_angle(axis, r.degrees.to_radians());
                }
            }
            Shape::Quad {
                corner,
                edge_u,
                edge_v,
            } => {
                let n = edge_u.cross(*edge_v);
                if !corner.is_finite() || !n.is_finite() || n.length() < 1e-12 {
                    return Err(invalid(
                        context,
                        "quad needs finite, non-parallel, non-zero edges",
                    ));
                }
                plane_normal = n.normalize();
            }
            Shape::Plane { point, normal } => {
                let n = normal.normalize_or_zero();
                if !point.is_finite() || n == DVec3::ZERO || !n.is_finite() {
                    return Err(invalid(
                        context,
                        "plane needs a finite point and non-zero normal",
                    ));
                }
                plane_normal = n;
            }
        }
        let plane_tangents = plane_normal.any_orthonormal_pair();
        Ok(Self {
            shape,
            basis,
            plane_normal,
            plane_tangents,
        })
    }

    /// The shape as described.
    pub fn shape(&self) -> &Shape {
        &self.shape
    }

    /// The default spin pivot: the shape's centre (a plane's point, a quad's centre).
    pub fn centre(&self) -> DVec3 {
        match &self.shape {
            Shape::Sphere { center, .. } | Shape::Box { center, .. } => *center,
            Shape::Quad {
                corner,
                edge_u,
                edge_v,
            } => *corner + 0.5 * (*edge_u + *edge_v),
            Shape::Plane { point, .. } => *point,
        }
    }

    /// Closest intersection of a rest-frame ray with distance in (t_min, t_max).
    pub fn intersect(&self, ray: &Ray, t_min: f64, t_max: f64) -> Option<RestHit> {
        match &self.shape {
            Shape::Sphere { center, radius } => {
                intersect_sphere(ray, *center, *radius, t_min, t_max)
            }
            Shape::Box {
                center, half_size, ..
            } => self.intersect_box(ray, *center, *half_size, t_min, t_max),
            Shape::Quad {
                corner,
                edge_u,
                edge_v,
            } => self.intersect_quad(ray, *corner, *edge_u, *edge_v, t_min, t_max),
            Shape::Plane { point, .. } => self.intersect_plane(ray, *point, t_min, t_max),
        }
    }

    fn intersect_box(
        &self,
        ray: &Ray,
        center: DVec3,
        half: DVec3,
        t_min: f64,
        t_max: f64,
    ) -> Option<RestHit> {
        // Into box coordinates: box-from-world is the transpose of the orientation.
        let inv = self.basis.transpose();
        let o = inv * (ray.origin - center);
        let d = inv * ray.direction;
        let mut near = t_min;
        let mut far = t_max;
        let mut near_axis = usize::MAX;
        let mut far_axis = usize::MAX;
        for axis in 0..3 {
            let (oa, da, ha) = (o[axis], d[axis], half[axis]);
            if da.abs() < 1e-300 {
                if oa.abs() > ha {
                    return None;
                }
                continue;
            }
            let t0 = (-ha - oa) / da;
            let t1 = (ha - oa) / da;
            let (lo, hi) = if t0 < t1 { (t0, t1) } else { (t1, t0) };
            if lo > near {
                near = lo;
                near_axis = axis;
            }
            if hi < far {
                far = hi;
                far_axis = axis;
            }
            if near > far {
                return None;
            }
        }
        // Entering hit if the ray starts outside, else the exit (inside a box).
        let (distance, axis) = if near_axis != usize::MAX && near > t_min {
            (near, near_axis)
        } else if far_axis != usize::MAX && far < t_max {
            (far, far_axis)
        } else {
            return None;
        };
        let local = o + d * distance;
        let mut n_local = DVec3::ZERO;
        n_local[axis] = local[axis].signum();
        let (ua, va) = ((axis + 1) % 3, (axis + 2) % 3);
        let uv = DVec2::new(local[ua] + half[ua], local[va] + half[va]);
        Some(RestHit {
            distance,
            point: ray.origin + ray.direction * distance,
            normal: self.basis * n_local,
            uv,
        })
    }

    fn intersect_quad(
        &self,
        ray: &Ray,
        corner: DVec3,
        edge_u: DVec3,
        edge_v: DVec3,
        t_min: f64,
        t_max: f64,
    ) -> Option<RestHit> {
        let n = self.plane_normal;
        let denom = ray.direction.dot(n);
        if denom.abs() < 1e-15 {
            return None;
        }
        let distance = (corner - ray.origin).dot(n) / denom;
        if !(distance > t_min && distance < t_max) {
            return None;
        }
        let p = ray.origin + ray.direction * distance;
        // Solve p - corner = a edge_u + b edge_v in the plane.
        let w = p - corner;
        let cross = edge_u.cross(edge_v);
        let inv = 1.0 / cross.length_squared();
        let a = w.cross(edge_v).dot(cross) * inv;
        let b = edge_u.cross(w).dot(cross) * inv;
        if !(0.0..=1.0).contains(&a) || !(0.0..=1.0).contains(&b) {
            return None;
        }
        Some(RestHit {
            distance,
            point: p,
            normal: if denom < 0.0 { n } else { -n },
            uv: DVec2::new(a, b),
        })
    }

    fn intersect_plane(&self, ray: &Ray, point: DVec3, t_min: f64, t_max: f64) -> Option<RestHit> {
        let n = self.plane_normal;
        let denom = ray.direction.dot(n);
        if denom.abs() < 1e-15 {
            return None;
        }
        let distance = (point - ray.origin).dot(n) / denom;
        if !(distance > t_min && distance < t_max) {
            return None;
        }
        let p = ray.origin + ray.direction * distance;
        let w = p - point;
        Some(RestHit {
            distance,
            point: p,
            normal: if denom < 0.0 { n } else { -n },
            uv: DVec2::new(w.dot(self.plane_tangents.0), w.dot(self.plane_tangents.1)),
        })
    }
}

fn intersect_sphere(
    ray: &Ray,
    center: DVec3,
    radius: f64,
    t_min: f64,
    t_max: f64,
) -> Option<RestHit> {
    // |o + t d - c|^2 = r^2 with |d| = 1; the numerically stable half-b form.
    let oc = ray.origin - center;
    let half_b = oc.dot(ray.direction);
    let c = oc.length_squared() - radius * radius;
    let disc = half_b * half_b - c;
    if disc < 0.0 {
        return None;
    }
    let root = disc.sqrt();
    let q = if half_b > 0.0 {
        -half_b - root
    } else {
        -half_b + root
    };
    let (mut t0, mut t1) = (q, if q != 0.0 { c / q } else { 0.0 });
    if t0 > t1 {
        std::mem::swap(&mut t0, &mut t1);
    }
    let distance = if t0 > t_min && t0 < t_max {
        t0
    } else if t1 > t_min && t1 < t_max {
        t1
    } else {
        return None;
    };
    let point = ray.origin + ray.direction * distance;
    let normal = (point - center) / radius;
    // Latitude-longitude texture coordinates (u around +y, v from +y down).
    let u = 0.5 + normal.z.atan2(normal.x) / (2.0 * std::f64::consts::PI);
    let v = normal.y.clamp(-1.0, 1.0).acos() / std::f64::consts::PI;
    Some(RestHit {
        distance,
        point,
        normal,
        uv: DVec2::new(u, v),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ray(o: DVec3, d: DVec3) -> Ray {
        Ray {
            origin: o,
            direction: d.normalize(),
            time: 0.0,
        }
    }

    #[test]
    fn sphere_box_quad_plane_hits() {
        let r = ray(DVec3::ZERO, DVec3::new(0.0, 0.0, -1.0));
        let sphere = PreparedShape::new(
            Shape::Sphere {
                center: DVec3::new(0.0, 0.0, -5.0),
                radius: 1.0,
            },
            "s",
        )
        .expect("sphere");
        let hit = sphere.intersect(&r, 1e-9, f64::INFINITY).expect("hit");
        assert!((hit.distance - 4.0).abs() < 1e-12);
        assert!((hit.normal - DVec3::Z).length() < 1e-12);

        let boxed = PreparedShape::new(
            Shape::Box {
                center: DVec3::new(0.0, 0.0, -5.0),
                half_size: DVec3::splat(1.0),
                rotation: Some(AxisAngle {
                    axis: DVec3::Y,
                    degrees: 45.0,
                }),
            },
            "b",
        )
        .expect("box");
        let hit = boxed.intersect(&r, 1e-9, f64::INFINITY).expect("hit");
        assert!((hit.distance - (5.0 - 2f64.sqrt())).abs() < 1e-12);

        let quad = PreparedShape::new(
            Shape::Quad {
                corner: DVec3::new(-1.0, -1.0, -2.0),
                edge_u: DVec3::new(2.0, 0.0, 0.0),
                edge_v: DVec3::new(0.0, 2.0, 0.0),
            },
            "q",
        )
        .expect("quad");
        let hit = quad.intersect(&r, 1e-9, f64::INFINITY).expect("hit");
        assert!((hit.distance - 2.0).abs() < 1e-12);
        assert!((hit.uv - DVec2::splat(0.5)).length() < 1e-12);
        assert!(hit.normal.dot(r.direction) < 0.0);
        let off = ray(DVec3::new(1.5, 0.0, 0.0), DVec3::new(0.0, 0.0, -1.0));
        assert!(quad.intersect(&off, 1e-9, f64::INFINITY).is_none());

        let plane = PreparedShape::new(
            Shape::Plane {
                point: DVec3::new(0.0, 0.0, -10.0),
                normal: DVec3::new(0.0, 0.0, 3.0),
            },
            "p",
        )
        .expect("plane");
        let hit = plane.intersect(&r, 1e-9, f64::INFINITY).expect("hit");
        assert!((hit.distance - 10.0).abs() < 1e-12);
    }

    #[test]
    fn spin_moves_points_on_a_circle() {
        let motion = Motion::new(
            DVec3::new(1.0, 0.0, 0.0),
            Some(&Spin {
                axis: DVec3::Z,
                radians_per_frame: std::f64::consts::FRAC_PI_2,
                pivot: None,
            }),
            DVec3::ZERO,
            "m",
        )
        .expect("motion");
        let p = motion.place(DVec3::new(1.0, 0.0, 0.0), 1.0);
        assert!((p - DVec3::new(1.0, 1.0, 0.0)).length() < 1e-12);
        let r = Ray {
            origin: DVec3::new(3.0, 2.0, 1.0),
            direction: DVec3::new(0.0, 1.0, 0.0),
            time: 0.5,
        };
        let rest = motion.to_rest(&r);
        let back = motion.place(rest.origin, 0.5);
        assert!((back - r.origin).length() < 1e-12);
    }

    #[test]
    fn degenerate_shapes_are_rejected() {
        let bad = Shape::Sphere {
            center: DVec3::ZERO,
            radius: -1.0,
        };
        assert!(PreparedShape::new(bad, "s").is_err());
        let bad = Shape::Quad {
            corner: DVec3::ZERO,
            edge_u: DVec3::X,
            edge_v: DVec3::X * 2.0,
        };
        assert!(PreparedShape::new(bad, "q").is_err());
    }
}
