//! Screen-space error, as the tile builder needs it.
//!
//! 1. The 3D Tiles client's rule: `sse = geometricError * screenHeight / (2 * distance *
//!    tan(fovY / 2))` ([`sse_px`]), a tile refining while it is above the limit (16 px by
//!    default); the error that frames a bounding sphere at that limit ([`framed_error_m`]) and the
//!    distance at which a tile switches ([`switch_distance_m`]). Reading a written tileset back
//!    with this rule is [`crate::inspect::first_view`].
//! 2. The paper's own formulation (III.C(3), formulas (1) and (2), Table I): the on-screen length
//!    of a collapsed ("folding") edge of length L at distance d, `SSE(x) = L x / (2 d tan(θ/2))`,
//!    and the mesh error `Δ(mesh) = Weight·Height / (2xy) · SSE(x) · SSE(y)`
//!    ([`paper_sse_px`], [`paper_delta_mesh_px`]), and the geometricError that makes a 3D Tiles
//!    client switch where Δ(mesh) reaches [`PAPER_MAX_DELTA_PX`] ([`paper_geometric_error_m`]).

use serde::Serialize;

/// The screen and the limit a view is judged by (CesiumJS's defaults on a 1920x1080 screen).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ViewOptions {
    pub width_px: u32,
    pub height_px: u32,
    pub fov_y_deg: f64,
    pub max_sse_px: f64,
}

impl Default for ViewOptions {
    fn default() -> Self {
        ViewOptions {
            width_px: 1920,
            height_px: 1080,
            fov_y_deg: 60.0,
            max_sse_px: 16.0,
        }
    }
}

/// The largest Δ(mesh) (formula (2), pixels) the paper accepts: Table I's coarsest level was
/// chosen at Δ(mesh) = 16 ("the LOD level with the largest error within an acceptable range").
pub const PAPER_MAX_DELTA_PX: f64 = 16.0;

/// Formula (1) of the paper: the on-screen length (pixels) of an edge of `edge_m` metres seen at
/// `distance_m`, on a screen side of `screen_px` pixels spanning the field of view `fov_deg`:
/// `SSE(x) = L x / (2 d tan(θ/2))`. The paper uses one θ for both screen sides.
pub fn paper_sse_px(edge_m: f64, distance_m: f64, screen_px: f64, fov_deg: f64) -> f64 {
    edge_m * screen_px / (2.0 * distance_m * (fov_deg.to_radians() / 2.0).tan())
}

/// Formula (2) of the paper: `Δ(mesh) = Weight·Height / (2xy) · SSE(x) · SSE(y)`, the pixels a
/// triangle with edge `edge_m` covers at `distance_m`. `x`, `y` are the screen's sides in pixels
/// (`v.width_px`, `v.height_px`); Weight and Height, the viewport's, are the same here (the canvas
/// fills the screen), so `Δ = SSE(x) SSE(y) / 2`, the area of a right triangle with those legs.
pub fn paper_delta_mesh_px(edge_m: f64, distance_m: f64, v: &ViewOptions) -> f64 {
    let (x, y) = (v.width_px as f64, v.height_px as f64);
    let (weight, height) = (x, y);
    let sse_x = paper_sse_px(edge_m, distance_m, x, v.fov_y_deg);
    let sse_y = paper_sse_px(edge_m, distance_m, y, v.fov_y_deg);
    weight * height / (2.0 * x * y) * sse_x * sse_y
}

/// The nearest distance (metres) at which a level whose longest collapsed edge is `edge_m` is
/// acceptable by the paper: where Δ(mesh) falls to `max_delta_px` (the paper's "range of
/// visibility"). From (2): `Δ = W H L² / (8 d² tan²(θ/2))`.
pub fn paper_visibility_distance_m(edge_m: f64, v: &ViewOptions, max_delta_px: f64) -> f64 {
    let (w, h) = (v.width_px as f64, v.height_px as f64);
    edge_m * (w * h / (8.0 * max_delta_px)).sqrt() / (v.fov_y_deg.to_radians() / 2.0).tan()
}

/// The `geometricError` (metres) under which a 3D Tiles client (screen-space error limit
/// `v.max_sse_px`) switches a level away exactly where the paper would:
/// at [`paper_visibility_distance_m`]. Solving `e h / (2 d tan(θ/2)) = max_sse_px` there gives
/// `e = L · max_sse_px · sqrt(W / (2 H Δmax))`, 3.77 L at 1920x1080, 16 px and Δmax = 16. It is a
/// multiple of the longest collapsed edge, not a measured distance: a surface moved by several
/// collapses can lie farther than that from full detail (not honest in general).
pub fn paper_geometric_error_m(edge_m: f64, v: &ViewOptions, max_delta_px: f64) -> f64 {
    limit_error_m(paper_visibility_distance_m(edge_m, v, max_delta_px), v)
}

/// The `geometricError` whose screen-space error at `distance_m` is exactly `v.max_sse_px` (the
/// inverse of [`switch_distance_m`]).
pub fn limit_error_m(distance_m: f64, v: &ViewOptions) -> f64 {
    2.0 * v.max_sse_px * distance_m * (v.fov_y_deg.to_radians() / 2.0).tan() / v.height_px as f64
}

/// The nearest distance (metres) at which a 3D Tiles client still draws a tile of `geometric_error_m`
/// instead of refining it (where its screen-space error equals `v.max_sse_px`).
pub fn switch_distance_m(geometric_error_m: f64, v: &ViewOptions) -> f64 {
    geometric_error_m * v.height_px as f64
        / (2.0 * v.max_sse_px * (v.fov_y_deg.to_radians() / 2.0).tan())
}

/// The geometricError at the screen-space limit for a tile framed on screen: its bounding sphere
/// (`radius_m`) fills the vertical field of view, and the distance is to the sphere's surface, as a
/// client measures it to a bounding volume. A tile with at most this error is drawn, not refined,
/// once the viewer has backed off far enough to see all of it; HLOD content need not be finer.
pub fn framed_error_m(radius_m: f64, v: &ViewOptions) -> f64 {
    let half_fov = (v.fov_y_deg.to_radians() / 2.0).max(1e-6);
    limit_error_m(radius_m / half_fov.sin() - radius_m, v)
}

/// Screen-space error (pixels) of a `geometric_error_m` at `distance_m`, as CesiumJS computes it.
pub fn sse_px(geometric_error_m: f64, distance_m: f64, v: &ViewOptions) -> f64 {
    geometric_error_m * v.height_px as f64
        / (2.0 * distance_m * (v.fov_y_deg.to_radians() / 2.0).tan())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() <= 1e-9 * b.abs().max(1.0)
    }

    #[test]
    fn a_framed_tile_at_its_error_is_at_the_limit() {
        let v = ViewOptions::default();
        let r = 40.0;
        let e = framed_error_m(r, &v);
        // 60°: the eye is 2r from the centre, r from the sphere.
        assert!(close(sse_px(e, r, &v), v.max_sse_px));
        assert!(close(
            e,
            16.0 * 2.0 * 40.0 * (30f64).to_radians().tan() / 1080.0
        ));
    }

    /// Formulas (1) and (2) against values computed by hand.
    #[test]
    fn paper_formulas_by_hand() {
        let v = ViewOptions::default(); // 1920 x 1080, 60 deg, 16 px
        let t = (30f64).to_radians().tan(); // 0.5773502691896257
                                            // (1): L = 0.05 m at d = 10 m on 1920 px: 0.05 * 1920 / (20 * 0.57735) = 8.3138 px.
        assert!(close(
            paper_sse_px(0.05, 10.0, 1920.0, 60.0),
            96.0 / (20.0 * t)
        ));
        assert!((paper_sse_px(0.05, 10.0, 1920.0, 60.0) - 8.313843876).abs() < 1e-8);
        // On 1080 px: 54 / 11.547 = 4.6765 px.
        assert!((paper_sse_px(0.05, 10.0, 1080.0, 60.0) - 4.676537180).abs() < 1e-8);
        // (2): Weight·Height / (2xy) = 1/2 here: 8.313843876 * 4.676537180 / 2 = 19.44 px.
        assert!((paper_delta_mesh_px(0.05, 10.0, &v) - 19.44).abs() < 1e-9);
        // No collapse, no error; twice as far, a quarter.
        assert_eq!(paper_delta_mesh_px(0.0, 10.0, &v), 0.0);
        assert!(close(
            paper_delta_mesh_px(0.05, 20.0, &v),
            paper_delta_mesh_px(0.05, 10.0, &v) / 4.0
        ));
        // Range of visibility at Δ = 16 px: d = 0.05 sqrt(1920 * 1080 / 128) / t = 11.0227 m,
        // where Δ is indeed 16.
        let d = paper_visibility_distance_m(0.05, &v, 16.0);
        assert!((d - 0.05 * 16200f64.sqrt() / t).abs() < 1e-9);
        assert!((d - 11.022703842).abs() < 1e-8);
        assert!(close(paper_delta_mesh_px(0.05, d, &v), 16.0));
        // The geometricError switching there: 3.771236 L = 0.188562 m, whose screen-space error
        // at d is the client's 16 px.
        let e = paper_geometric_error_m(0.05, &v, 16.0);
        assert!((e - 0.05 * 16.0 * (1920.0f64 / (2.0 * 1080.0 * 16.0)).sqrt()).abs() < 1e-12);
        assert!((e - 0.188561808).abs() < 1e-8);
        assert!(close(sse_px(e, d, &v), 16.0));
        assert!(close(switch_distance_m(e, &v), d));
    }
}
