//! Garland–Heckbert quadric error metric: a symmetric 4x4 matrix stored as
//! 10 `f64`s plus the accumulated weight, with optimal placement by solving
//! the 3x3 linear system (and a documented fallback when it is singular).

use glam::DVec3;

/// A quadric `Q(x) = x^T A x + 2 b^T x + c`, accumulated with weights.
///
/// `weight` is the sum of the weights of the planes added, so that
/// [`Quadric::distance2`] (= `Q(x) / weight`) is a weighted *mean squared
/// distance* to the planes, in square metres.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Quadric {
    /// a00 a01 a02 a11 a12 a22
    pub a: [f64; 6],
    /// b0 b1 b2
    pub b: [f64; 3],
    /// constant term
    pub c: f64,
    /// sum of weights
    pub weight: f64,
}

impl Quadric {
    /// Quadric of the plane `n . x + d = 0` (`n` unit length) with weight `w`.
    pub fn from_plane(n: DVec3, d: f64, w: f64) -> Self {
        Quadric {
            a: [
                w * n.x * n.x,
                w * n.x * n.y,
                w * n.x * n.z,
                w * n.y * n.y,
                w * n.y * n.z,
                w * n.z * n.z,
            ],
            b: [w * n.x * d, w * n.y * d, w * n.z * d],
            c: w * d * d,
            weight: w,
        }
    }

    /// Area-weighted quadric of the plane of triangle `(p0, p1, p2)`.
    /// Returns `None` for a degenerate triangle.
    pub fn from_triangle(p0: DVec3, p1: DVec3, p2: DVec3) -> Option<Self> {
        let n = (p1 - p0).cross(p2 - p0);
        let len = n.length();
        if len.is_nan() || len <= 0.0 || !len.is_finite() {
            return None;
        }
        let n = n / len;
        let area = 0.5 * len;
        Some(Self::from_plane(n, -n.dot(p0), area))
    }

    /// Adds `other` into `self`.
    #[inline]
    pub fn add(&mut self, other: &Quadric) {
        for i in 0..6 {
            self.a[i] += other.a[i];
        }
        for i in 0..3 {
            self.b[i] += other.b[i];
        }
        self.c += other.c;
        self.weight += other.weight;
    }

    /// Sum of two quadrics.
    #[inline]
    pub fn sum(a: &Quadric, b: &Quadric) -> Quadric {
        let mut q = *a;
        q.add(b);
        q
    }

    /// Raw (weighted) quadric error `Q(x)`, clamped at 0.
    #[inline]
    pub fn eval(&self, x: DVec3) -> f64 {
        let a = &self.a;
        let ax = DVec3::new(
            a[0] * x.x + a[1] * x.y + a[2] * x.z,
            a[1] * x.x + a[3] * x.y + a[4] * x.z,
            a[2] * x.x + a[4] * x.y + a[5] * x.z,
        );
        let v = x.dot(ax) + 2.0 * (self.b[0] * x.x + self.b[1] * x.y + self.b[2] * x.z) + self.c;
        v.max(0.0)
    }

    /// Weighted mean squared distance to the accumulated planes (m²).
    #[inline]
    pub fn distance2(&self, x: DVec3) -> f64 {
        if self.weight > 0.0 {
            self.eval(x) / self.weight
        } else {
            0.0
        }
    }

    /// Minimiser of `Q` in space: solves `A x = -b`. Returns `None` when `A`
    /// is (near) singular, i.e. the planes do not pin down a single point
    /// (flat region, straight crease).
    pub fn optimize(&self) -> Option<DVec3> {
        let a = &self.a;
        let (a00, a01, a02, a11, a12, a22) = (a[0], a[1], a[2], a[3], a[4], a[5]);
        let c00 = a11 * a22 - a12 * a12;
        let c01 = a02 * a12 - a01 * a22;
        let c02 = a01 * a12 - a02 * a11;
        let det = a00 * c00 + a01 * c01 + a02 * c02;
        // Relative singularity test: det against the cube of the matrix scale.
        let scale = a00.abs().max(a11.abs()).max(a22.abs());
        if scale.is_nan() || scale <= 0.0 || det.abs() <= 1e-9 * scale * scale * scale {
            return None;
        }
        let c11 = a00 * a22 - a02 * a02;
        let c12 = a02 * a01 - a00 * a12;
        let c22 = a00 * a11 - a01 * a01;
        let inv = 1.0 / det;
        let rhs = DVec3::new(-self.b[0], -self.b[1], -self.b[2]);
        let x = DVec3::new(
            (c00 * rhs.x + c01 * rhs.y + c02 * rhs.z) * inv,
            (c01 * rhs.x + c11 * rhs.y + c12 * rhs.z) * inv,
            (c02 * rhs.x + c12 * rhs.y + c22 * rhs.z) * inv,
        );
        x.is_finite().then_some(x)
    }

    /// Minimiser of `Q` on the segment `[p, q]` (closed form of the 1-D
    /// quadratic, clamped to the segment).
    pub fn optimize_on_segment(&self, p: DVec3, q: DVec3) -> DVec3 {
        let d = q - p;
        // Q(p + t d) = t² dAd + 2t (dAp + b.d) + Q(p)
        let a = &self.a;
        let ad = DVec3::new(
            a[0] * d.x + a[1] * d.y + a[2] * d.z,
            a[1] * d.x + a[3] * d.y + a[4] * d.z,
            a[2] * d.x + a[4] * d.y + a[5] * d.z,
        );
        let dad = d.dot(ad);
        let lin = ad.dot(p) + self.b[0] * d.x + self.b[1] * d.y + self.b[2] * d.z;
        let t = if dad > 1e-300 {
            (-lin / dad).clamp(0.0, 1.0)
        } else {
            // Flat along the segment: any point is optimal; keep the midpoint.
            0.5
        };
        p + d * t
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plane_distance() {
        let q = Quadric::from_plane(DVec3::Z, -1.0, 1.0); // z = 1
        assert!((q.distance2(DVec3::new(3.0, 4.0, 3.0)) - 4.0).abs() < 1e-12);
        assert_eq!(q.distance2(DVec3::new(-2.0, 7.0, 1.0)), 0.0);
    }

    #[test]
    fn triangle_quadric_weight_is_area() {
        let q = Quadric::from_triangle(DVec3::ZERO, DVec3::X * 2.0, DVec3::Y * 2.0).unwrap();
        assert!((q.weight - 2.0).abs() < 1e-12);
        assert!(Quadric::from_triangle(DVec3::ZERO, DVec3::X, DVec3::X * 2.0).is_none());
    }

    #[test]
    fn corner_of_three_planes_is_optimum() {
        let mut q = Quadric::from_plane(DVec3::X, -1.0, 1.0);
        q.add(&Quadric::from_plane(DVec3::Y, -2.0, 1.0));
        q.add(&Quadric::from_plane(DVec3::Z, -3.0, 1.0));
        let x = q.optimize().unwrap();
        assert!((x - DVec3::new(1.0, 2.0, 3.0)).length() < 1e-9);
        assert!(q.eval(x) < 1e-12);
    }

    #[test]
    fn singular_falls_back() {
        // Two planes: a crease line, A is singular.
        let mut q = Quadric::from_plane(DVec3::X, 0.0, 1.0);
        q.add(&Quadric::from_plane(DVec3::Y, 0.0, 1.0));
        assert!(q.optimize().is_none());
        // The segment optimum projects onto the crease.
        let p = q.optimize_on_segment(DVec3::new(-1.0, 1.0, 0.0), DVec3::new(1.0, -1.0, 2.0));
        assert!(q.eval(p) < 1e-12, "{p:?}");
        // A single plane (flat region) is singular too.
        assert!(Quadric::from_plane(DVec3::Z, 0.0, 1.0).optimize().is_none());
    }
}
