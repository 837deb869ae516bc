//! Small numeric tools for shape matching, in f64: symmetric eigen-decomposition (Jacobi), the
//! closed-form best rigid/similarity fit of corresponding points (Horn's quaternion method), the
//! second/third moments of a point set and a static k-d tree for nearest-point queries.
//!
//! Written here rather than pulled in: glam has no eigen solver or SVD, and the sizes are 3×3 and
//! 4×4, where cyclic Jacobi is exact to rounding and a few dozen lines.

use glam::{DMat3, DMat4, DQuat, DVec3};

/// Eigenvalues (descending) and unit eigenvectors (same order) of a symmetric N×N matrix.
// Matrix code reads best with explicit indices.
#[allow(clippy::needless_range_loop)]
pub fn sym_eigen<const N: usize>(m: [[f64; N]; N]) -> ([f64; N], [[f64; N]; N]) {
    let mut a = m;
    // v[i] is the i-th eigenvector once converged (rows of the accumulated rotation).
    let mut v = [[0.0; N]; N];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for _sweep in 0..64 {
        let mut off = 0.0;
        let mut diag = 0.0;
        for (i, row) in a.iter().enumerate() {
            for (j, x) in row.iter().enumerate() {
                if i != j {
                    off += x * x;
                } else {
                    diag += x * x;
                }
            }
        }
        // Converged to rounding (relative): further rotations change nothing meaningful.
        if off <= 1e-30 * diag.max(f64::MIN_POSITIVE) {
            break;
        }
        for p in 0..N {
            for q in p + 1..N {
                let apq = a[p][q];
                if apq.abs() < 1e-300 {
                    continue;
                }
                let theta = (a[q][q] - a[p][p]) / (2.0 * apq);
                // The smaller root of t² + 2θt − 1 = 0 (rotation angle ≤ 45°, stable); θ = 0 gives 1.
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for k in 0..N {
                    let (akp, akq) = (a[k][p], a[k][q]);
                    a[k][p] = c * akp - s * akq;
                    a[k][q] = s * akp + c * akq;
                }
                for k in 0..N {
                    let (apk, aqk) = (a[p][k], a[q][k]);
                    a[p][k] = c * apk - s * aqk;
                    a[q][k] = s * apk + c * aqk;
                }
                for k in 0..N {
                    let (vpk, vqk) = (v[p][k], v[q][k]);
                    v[p][k] = c * vpk - s * vqk;
                    v[q][k] = s * vpk + c * vqk;
                }
            }
        }
    }
    let mut order: [usize; N] = [0; N];
    for (i, o) in order.iter_mut().enumerate() {
        *o = i;
    }
    order.sort_by(|&i, &j| a[j][j].total_cmp(&a[i][i]));
    let mut vals = [0.0; N];
    let mut vecs = [[0.0; N]; N];
    for (k, &i) in order.iter().enumerate() {
        vals[k] = a[i][i];
        vecs[k] = v[i];
    }
    (vals, vecs)
}

/// A similarity transform x ↦ s·R·x + t (R a proper rotation, s > 0), in the scene frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Similarity {
    pub rotation: DMat3,
    pub scale: f64,
    pub translation: DVec3,
}

impl Similarity {
    pub const IDENTITY: Similarity = Similarity {
        rotation: DMat3::IDENTITY,
        scale: 1.0,
        translation: DVec3::ZERO,
    };
    pub fn apply(&self, x: DVec3) -> DVec3 {
        self.rotation * x * self.scale + self.translation
    }
    pub fn to_mat4(&self) -> DMat4 {
        DMat4::from_translation(self.translation) * DMat4::from_mat3(self.rotation * self.scale)
    }
}

/// The similarity (or rigid motion, when `allow_scale` is false) that best maps `from[i]` onto
/// `to[i]` in the least-squares sense (Horn 1987, closed form with unit quaternions). Always a
/// proper rotation: a mirrored point set gets a poor fit instead of a reflection, which is what
/// keeps mirrored copies from matching. None when there are no points or the input is not finite.
pub fn fit_similarity(
    from: impl Iterator<Item = DVec3> + Clone,
    to: impl Iterator<Item = DVec3> + Clone,
    allow_scale: bool,
) -> Option<Similarity> {
    let mut n = 0usize;
    let (mut cf, mut ct) = (DVec3::ZERO, DVec3::ZERO);
    for (a, b) in from.clone().zip(to.clone()) {
        cf += a;
        ct += b;
        n += 1;
    }
    if n == 0 {
        return None;
    }
    cf /= n as f64;
    ct /= n as f64;
    // Cross-covariance S[i][j] = Σ a_i b_j over centred points.
    let mut s = [[0.0f64; 3]; 3];
    let mut ss_from = 0.0;
    for (a, b) in from.zip(to) {
        let (a, b) = ((a - cf).to_array(), (b - ct).to_array());
        for i in 0..3 {
            for j in 0..3 {
                s[i][j] += a[i] * b[j];
            }
            ss_from += a[i] * a[i];
        }
    }
    let [[sxx, sxy, sxz], [syx, syy, syz], [szx, szy, szz]] = s;
    let nmat = [
        [sxx + syy + szz, syz - szy, szx - sxz, sxy - syx],
        [syz - szy, sxx - syy - szz, sxy + syx, szx + sxz],
        [szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy],
        [sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz],
    ];
    if nmat.iter().flatten().any(|x| !x.is_finite()) {
        return None;
    }
    let (_, vecs) = sym_eigen(nmat);
    let [w, x, y, z] = vecs[0];
    let q = DQuat::from_xyzw(x, y, z, w);
    let q = if q.length_squared() > 0.0 {
        q.normalize()
    } else {
        DQuat::IDENTITY
    };
    let rotation = DMat3::from_quat(q);
    let scale = if allow_scale && ss_from > 0.0 {
        // Least squares s for fixed R: Σ b·(R a) / Σ |a|².
        let num: f64 = (0..3)
            .map(|i| (0..3).map(|j| rotation.col(j)[i] * s[j][i]).sum::<f64>())
            .sum();
        let s = num / ss_from;
        if s > 0.0 && s.is_finite() {
            s
        } else {
            return None;
        }
    } else {
        1.0
    };
    let translation = ct - rotation * cf * scale;
    Some(Similarity {
        rotation,
        scale,
        translation,
    })
}

/// Centroid, principal axes and moments of a point set (each point weighted 1).
#[derive(Debug, Clone)]
pub struct Moments {
    pub centroid: DVec3,
    /// Square roots of the covariance eigenvalues, descending: the RMS extent along each principal
    /// axis. Moving every point by at most δ moves each of these by at most 2δ (Weyl), which is
    /// what makes them safe bucket keys.
    pub sigma: [f64; 3],
    /// Unit principal axes, same order as `sigma` (sign arbitrary).
    pub axes: [DVec3; 3],
    /// Mean cubed coordinate along each axis: its sign fixes the axis direction when the shape is
    /// not symmetric about the plane through the centroid normal to that axis.
    pub third: [f64; 3],
    pub count: usize,
}

impl Moments {
    #[allow(clippy::needless_range_loop)]
    pub fn of(points: &[DVec3]) -> Option<Moments> {
        let n = points.len();
        if n == 0 {
            return None;
        }
        let centroid = points.iter().copied().sum::<DVec3>() / n as f64;
        let mut c = [[0.0f64; 3]; 3];
        for p in points {
            let d = (*p - centroid).to_array();
            for i in 0..3 {
                for j in i..3 {
                    c[i][j] += d[i] * d[j];
                }
            }
        }
        for i in 0..3 {
            for j in i..3 {
                c[i][j] /= n as f64;
                c[j][i] = c[i][j];
            }
        }
        if c.iter().flatten().any(|x| !x.is_finite()) {
            return None;
        }
        let (vals, vecs) = sym_eigen(c);
        let axes = vecs.map(|v| DVec3::from_array(v).normalize_or_zero());
        let sigma = vals.map(|v| v.max(0.0).sqrt());
        let mut third = [0.0; 3];
        for p in points {
            let d = *p - centroid;
            for k in 0..3 {
                third[k] += d.dot(axes[k]).powi(3);
            }
        }
        for t in &mut third {
            *t /= n as f64;
        }
        Some(Moments {
            centroid,
            sigma,
            axes,
            third,
            count: n,
        })
    }
}

/// A static k-d tree over points, for nearest-point and radius queries (ICP correspondences and
/// triangle matching). Built once per shape, O(n log n).
pub struct KdTree {
    points: Vec<DVec3>,
    /// Point indices, arranged so that every node is a contiguous range split at its median.
    idx: Vec<u32>,
    nodes: Vec<KdNode>,
}

#[derive(Clone, Copy)]
struct KdNode {
    start: u32,
    end: u32,
    axis: u8,
    /// Children node indices (0 = none; the root is 0 and is never a child).
    left: u32,
    right: u32,
    split: f64,
}

const LEAF: usize = 8;

impl KdTree {
    pub fn new(points: Vec<DVec3>) -> KdTree {
        let mut t = KdTree {
            idx: (0..points.len() as u32).collect(),
            points,
            nodes: Vec::new(),
        };
        if !t.points.is_empty() {
            t.build(0, t.points.len());
        }
        t
    }

    pub fn point(&self, i: u32) -> DVec3 {
        self.points[i as usize]
    }

    fn build(&mut self, start: usize, end: usize) -> u32 {
        let id = self.nodes.len() as u32;
        self.nodes.push(KdNode {
            start: start as u32,
            end: end as u32,
            axis: 0,
            left: 0,
            right: 0,
            split: 0.0,
        });
        if end - start <= LEAF {
            return id;
        }
        let mut lo = DVec3::splat(f64::INFINITY);
        let mut hi = DVec3::splat(f64::NEG_INFINITY);
        for &i in &self.idx[start..end] {
            lo = lo.min(self.points[i as usize]);
            hi = hi.max(self.points[i as usize]);
        }
        let ext = hi - lo;
        let axis = if ext.x >= ext.y && ext.x >= ext.z {
            0
        } else if ext.y >= ext.z {
            1
        } else {
            2
        };
        let mid = (start + end) / 2;
        let pts = &self.points;
        self.idx[start..end].select_nth_unstable_by(mid - start, |&a, &b| {
            pts[a as usize][axis].total_cmp(&pts[b as usize][axis])
        });
        let split = self.points[self.idx[mid] as usize][axis];
        let left = self.build(start, mid);
        let right = self.build(mid, end);
        let n = &mut self.nodes[id as usize];
        n.axis = axis as u8;
        n.split = split;
        n.left = left;
        n.right = right;
        id
    }

    /// Index and squared distance of the point nearest to `q`.
    pub fn nearest(&self, q: DVec3) -> Option<(u32, f64)> {
        if self.nodes.is_empty() {
            return None;
        }
        let mut best = (u32::MAX, f64::INFINITY);
        self.nearest_in(0, q, &mut best);
        Some(best)
    }

    fn nearest_in(&self, node: u32, q: DVec3, best: &mut (u32, f64)) {
        let n = self.nodes[node as usize];
        if n.left == 0 {
            for &i in &self.idx[n.start as usize..n.end as usize] {
                let d = self.points[i as usize].distance_squared(q);
                // Ties go to the lowest index, so the answer does not depend on tree layout.
                if d < best.1 || (d == best.1 && i < best.0) {
                    *best = (i, d);
                }
            }
            return;
        }
        let diff = q[n.axis as usize] - n.split;
        let (near, far) = if diff < 0.0 {
            (n.left, n.right)
        } else {
            (n.right, n.left)
        };
        self.nearest_in(near, q, best);
        if diff * diff <= best.1 {
            self.nearest_in(far, q, best);
        }
    }

    /// Calls `f` with every point index within `r` of `q` (any order).
    pub fn within(&self, q: DVec3, r: f64, f: &mut impl FnMut(u32)) {
        if !self.nodes.is_empty() {
            self.within_in(0, q, r, f);
        }
    }

    fn within_in(&self, node: u32, q: DVec3, r: f64, f: &mut impl FnMut(u32)) {
        let n = self.nodes[node as usize];
        if n.left == 0 {
            for &i in &self.idx[n.start as usize..n.end as usize] {
                if self.points[i as usize].distance_squared(q) <= r * r {
                    f(i);
                }
            }
            return;
        }
        let diff = q[n.axis as usize] - n.split;
        if diff - r <= 0.0 {
            self.within_in(n.left, q, r, f);
        }
        if diff + r >= 0.0 {
            self.within_in(n.right, q, r, f);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    #[allow(clippy::needless_range_loop)]
    fn eigen_of_diagonal_and_rotated() {
        let (vals, vecs) = sym_eigen([[1.0, 0.0, 0.0], [0.0, 3.0, 0.0], [0.0, 0.0, 2.0]]);
        assert_eq!(vals, [3.0, 2.0, 1.0]);
        assert!((DVec3::from_array(vecs[0]).dot(DVec3::Y).abs() - 1.0).abs() < 1e-12);
        // R diag(5,2,1) Rᵀ has the same eigenvalues, eigenvectors the columns of R.
        let r = DMat3::from_quat(DQuat::from_euler(glam::EulerRot::XYZ, 0.3, -1.1, 2.0));
        let m = r * DMat3::from_diagonal(DVec3::new(5.0, 2.0, 1.0)) * r.transpose();
        let a = m.to_cols_array_2d();
        let (vals, vecs) = sym_eigen(a);
        for (v, e) in vals.iter().zip([5.0, 2.0, 1.0]) {
            assert!((v - e).abs() < 1e-12, "{vals:?}");
        }
        for k in 0..3 {
            assert!((DVec3::from_array(vecs[k]).dot(r.col(k)).abs() - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn horn_recovers_rotation_translation_and_scale() {
        let pts: Vec<DVec3> = (0..20)
            .map(|i| {
                let f = i as f64;
                DVec3::new(f.sin() * 3.0, (f * 0.7).cos(), f * 0.1)
            })
            .collect();
        let truth = Similarity {
            rotation: DMat3::from_quat(DQuat::from_axis_angle(
                DVec3::new(1.0, 2.0, 3.0).normalize(),
                2.5,
            )),
            scale: 1.7,
            translation: DVec3::new(100.0, -5.0, 3.0),
        };
        let moved: Vec<DVec3> = pts.iter().map(|&p| truth.apply(p)).collect();
        let fit = fit_similarity(pts.iter().copied(), moved.iter().copied(), true).unwrap();
        for (p, m) in pts.iter().zip(&moved) {
            assert!(fit.apply(*p).distance(*m) < 1e-9);
        }
        assert!((fit.scale - 1.7).abs() < 1e-12);
        // Rigid only: the fit cannot reach the scaled points.
        let rigid = fit_similarity(pts.iter().copied(), moved.iter().copied(), false).unwrap();
        assert_eq!(rigid.scale, 1.0);
        assert!(pts
            .iter()
            .zip(&moved)
            .any(|(p, m)| rigid.apply(*p).distance(*m) > 0.1));
        // A mirror image is never fitted exactly: R stays proper.
        let mirrored: Vec<DVec3> = pts.iter().map(|p| DVec3::new(-p.x, p.y, p.z)).collect();
        let m = fit_similarity(pts.iter().copied(), mirrored.iter().copied(), false).unwrap();
        assert!(m.rotation.determinant() > 0.0);
        assert!(pts
            .iter()
            .zip(&mirrored)
            .any(|(p, q)| m.apply(*p).distance(*q) > 0.01));
    }

    #[test]
    fn kdtree_matches_brute_force() {
        let pts: Vec<DVec3> = (0..500)
            .map(|i| {
                let f = i as f64;
                DVec3::new(
                    (f * 12.9898).sin() * 43.0,
                    (f * 78.233).sin() * 7.0,
                    f * 0.01,
                )
            })
            .collect();
        let t = KdTree::new(pts.clone());
        for k in 0..50 {
            let q = DVec3::new(k as f64 - 25.0, (k as f64).cos() * 5.0, 2.0);
            let (i, d) = t.nearest(q).unwrap();
            let best = pts
                .iter()
                .map(|p| p.distance_squared(q))
                .fold(f64::INFINITY, f64::min);
            assert_eq!(d, best);
            assert_eq!(pts[i as usize].distance_squared(q), best);
            let mut found = Vec::new();
            t.within(q, 6.0, &mut |i| found.push(i));
            found.sort_unstable();
            let brute: Vec<u32> = (0..pts.len() as u32)
                .filter(|&i| pts[i as usize].distance_squared(q) <= 36.0)
                .collect();
            assert_eq!(found, brute);
        }
        assert!(KdTree::new(Vec::new()).nearest(DVec3::ZERO).is_none());
    }

    #[test]
    fn moments_of_a_box() {
        let mut pts = Vec::new();
        for i in 0..8 {
            pts.push(DVec3::new(
                if i & 1 == 0 { 0.0 } else { 4.0 },
                if i & 2 == 0 { 0.0 } else { 2.0 },
                if i & 4 == 0 { 0.0 } else { 1.0 },
            ));
        }
        let m = Moments::of(&pts).unwrap();
        assert!(m.centroid.distance(DVec3::new(2.0, 1.0, 0.5)) < 1e-12);
        assert!((m.sigma[0] - 2.0).abs() < 1e-12);
        assert!((m.sigma[1] - 1.0).abs() < 1e-12);
        assert!((m.sigma[2] - 0.5).abs() < 1e-12);
        assert!(m.third.iter().all(|t| t.abs() < 1e-12));
    }
}
