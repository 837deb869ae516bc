//! Texture level matched to each tile's geometric level of detail (paper III.F).
//!
//! A tile's `geometricError` says how far its geometry may be from full detail (metres); texture
//! detail finer than that is not shown by the geometry either. So each tile gets the **coarsest
//! pyramid level whose texel size on the model is at most the tile's geometric error**: a texel
//! then covers at most the distance the geometry may be off, and at the next coarser level it
//! would cover more. Leaves (error 0) get level 0, full resolution.
//!
//! Texel size on the model, for one image in one tile: over the tile's triangles that sample the
//! image, `sqrt(world area / (UV area x texel count))` metres per texel, with the areas summed
//! over the triangles (an area-weighted mean, robust to slivers and to UV-degenerate triangles,
//! whose UV area is 0). Tiling UVs count every repeat, as they should: a brick texture repeated
//! 20 times over a wall has texels 20 times smaller on the model.

use crate::partition::content::ContentPrimitive;
use glam::{DVec2, DVec3};

/// World area (m²) and UV area (in UV units², repeats included) of a primitive's triangles.
pub fn areas(p: &ContentPrimitive) -> (f64, f64) {
    if p.uvs.len() != p.positions.len() {
        return (0.0, 0.0);
    }
    let (mut world, mut uv) = (0.0, 0.0);
    for t in p.indices.chunks_exact(3) {
        let v = |i: u32| {
            let q = p.positions[i as usize];
            DVec3::new(q[0] as f64, q[1] as f64, q[2] as f64)
        };
        let u = |i: u32| {
            let q = p.uvs[i as usize];
            DVec2::new(q[0] as f64, q[1] as f64)
        };
        world += (v(t[1]) - v(t[0])).cross(v(t[2]) - v(t[0])).length() * 0.5;
        uv += (u(t[1]) - u(t[0])).perp_dot(u(t[2]) - u(t[0])).abs() * 0.5;
    }
    (world, uv)
}

/// Metres per texel of a `width x height` image mapped with these areas; `None` without UV area.
pub fn texel_size_m(world_area: f64, uv_area: f64, width: u32, height: u32) -> Option<f64> {
    let texels = uv_area * width as f64 * height as f64;
    (texels > 0.0 && world_area > 0.0).then(|| (world_area / texels).sqrt())
}

/// The level for a tile: the coarsest of `sizes` (level 0 first) whose texel size is at most
/// `geometric_error_m`; 0 for full-detail tiles (error 0) and when the areas give no texel size.
pub fn choose_level(
    sizes: &[(u32, u32)],
    world_area: f64,
    uv_area: f64,
    geometric_error_m: f64,
) -> usize {
    if geometric_error_m <= 0.0 {
        return 0;
    }
    let mut best = 0;
    for (l, &(w, h)) in sizes.iter().enumerate() {
        match texel_size_m(world_area, uv_area, w, h) {
            Some(s) if s <= geometric_error_m => best = l,
            _ => break,
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::super::haar::level_sizes;
    use super::*;

    /// A 4 m x 4 m wall (two triangles) whose UVs span `repeats` x `repeats`.
    fn wall(repeats: f32) -> ContentPrimitive {
        ContentPrimitive {
            positions: vec![
                [0.0, 0.0, 0.0],
                [4.0, 0.0, 0.0],
                [4.0, 0.0, 4.0],
                [0.0, 0.0, 4.0],
            ],
            uvs: vec![
                [0.0, 0.0],
                [repeats, 0.0],
                [repeats, repeats],
                [0.0, repeats],
            ],
            indices: vec![0, 1, 2, 0, 2, 3],
            ..Default::default()
        }
    }

    #[test]
    fn texel_size_of_a_wall() {
        let (w, u) = areas(&wall(1.0));
        assert_eq!((w, u), (16.0, 1.0));
        // 512 texels over 4 m: 7.8 mm per texel.
        assert!((texel_size_m(w, u, 512, 512).unwrap() - 4.0 / 512.0).abs() < 1e-12);
        let (w2, u2) = areas(&wall(4.0));
        assert!((texel_size_m(w2, u2, 512, 512).unwrap() - 1.0 / 512.0).abs() < 1e-12);
        assert_eq!(texel_size_m(16.0, 0.0, 512, 512), None);
    }

    #[test]
    fn chosen_level_matches_the_geometric_error() {
        let sizes = level_sizes(512, 512); // 10 levels below 512: 256 ... 1
        let (w, u) = areas(&wall(1.0)); // level l: 4 m / (512 >> l) per texel
        let texel = |l: usize| 4.0 / (512 >> l) as f64;
        assert_eq!(
            choose_level(&sizes, w, u, 0.0),
            0,
            "leaves: full resolution"
        );
        assert_eq!(choose_level(&sizes, w, u, 0.001), 0, "finer than any level");
        for l in 0..=9 {
            // Exactly the texel size of level l, and just under the next one.
            assert_eq!(choose_level(&sizes, w, u, texel(l)), l);
            assert_eq!(choose_level(&sizes, w, u, texel(l + 1) * 0.999), l);
        }
        assert_eq!(choose_level(&sizes, w, u, 100.0), 9, "capped at 1x1");
        // 0.05 m error: 64 texels across would be 0.0625 m each (too coarse), 128 are 0.031 m.
        assert_eq!(choose_level(&sizes, w, u, 0.05), 2);
        // No UVs: full resolution.
        assert_eq!(choose_level(&sizes, w, 0.0, 0.05), 0);
        // Non-square, odd sizes: 600 x 800 on a 6 m x 8 m wall is 1 cm per texel.
        let sizes = level_sizes(600, 800);
        assert_eq!(choose_level(&sizes, 48.0, 1.0, 0.04), 2); // 150 x 200: 4 cm
        assert_eq!(choose_level(&sizes, 48.0, 1.0, 0.079), 2); // 75 x 100 is 8 cm
    }
}
