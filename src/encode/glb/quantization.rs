//! Quantization of attributes (`KHR_mesh_quantization`, and the bits Draco gets): positions
//! on an i16 grid per mesh within the position error bound, normals as i8, UVs as u16 or by the
//! texels of the bound image.

use super::*;

/// Texels per texture repeat assumed when the image's size is unknown (no texture, unreadable
/// header): a step of 1/1024 is half a texel of a 512-pixel texture.
pub(super) const DEFAULT_UV_TEXELS: u32 = 512;

/// Draco bits for texture coordinates: a step of at most half a texel of the bound image
/// (`texels` along its longer side, full resolution) over the primitive's UV range (tiling UVs
/// span many repeats), so a texel lookup moves by at most half a texel. No more bits than that:
/// on textured models UVs are a large share of the Draco bytes (docs/benchmarks.md).
pub(super) fn uv_bits(uvs: &[[f32; 2]], texels: u32) -> u8 {
    let (mut lo, mut hi) = ([f32::MAX; 2], [f32::MIN; 2]);
    for t in uvs {
        for k in 0..2 {
            lo[k] = lo[k].min(t[k]);
            hi[k] = hi[k].max(t[k]);
        }
    }
    let range = (hi[0] - lo[0]).max(hi[1] - lo[1]).max(1.0) as f64;
    // step = range / (2^bits - 1) <= 1 / (2 texels), to within a factor 2^bits / (2^bits - 1).
    ((range * 2.0 * texels.max(1) as f64).log2().ceil() as u8).clamp(6, 20)
}

/// Texels along the longer side of the base colour image of `material` at full resolution, or
/// of the atlas the tile samples it from (`sampled_px`) when that is larger.
pub(super) fn texture_texels(
    scene: &Scene,
    material: Option<MaterialId>,
    sampled_px: &BTreeMap<ImageId, u32>,
) -> u32 {
    let t = material.and_then(|m| scene.materials[m.index()].base_color_texture.as_ref());
    let own = t
        .and_then(|t| crate::texture::codec::dimensions(&scene.images[t.image.index()].bytes).ok())
        .map_or(DEFAULT_UV_TEXELS, |(w, h)| w.max(h));
    own.max(
        t.and_then(|t| sampled_px.get(&t.image))
            .copied()
            .unwrap_or(0),
    )
}

/// The dequantization of a mesh's normalized i16 positions (glTF y-up, mesh frame): the node
/// transform `center + scale * (q / 32767)`, one uniform scale so normals need no change.
#[derive(Debug, Clone, Copy)]
pub(super) struct QuantFrame {
    pub(super) center: [f64; 3],
    pub(super) scale: f64,
}

/// Largest normalized i16 value.
pub(super) const I16_MAX: f64 = 32767.0;

impl QuantFrame {
    /// The frame of all positions of `prims` (scene frame), or `None` when the quantization step
    /// would move a vertex by more than `max_error_m` on an axis (the mesh stays float) or the
    /// mesh is empty. The step is the coarsest within `max_error_m`, not the finest the extent
    /// allows: fewer distinct values cost the meshopt codec and gzip fewer bytes (a simplified
    /// tile's bound is a share of its measured error, `lod::hlod::coarse_grid_m`).
    pub(super) fn of(prims: &[ContentPrimitive], max_error_m: f64) -> Option<QuantFrame> {
        let (mut lo, mut hi) = ([f64::MAX; 3], [f64::MIN; 3]);
        for p in prims.iter().flat_map(|m| y_up(&m.positions)) {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k] as f64);
                hi[k] = hi[k].max(p[k] as f64);
            }
        }
        if lo[0] > hi[0] {
            return None;
        }
        let center = [0, 1, 2].map(|k| (lo[k] + hi[k]) / 2.0);
        let half = (0..3).map(|k| (hi[k] - lo[k]) / 2.0).fold(0.0, f64::max);
        // Rounding to the nearest step moves a vertex by at most half a step; the step is at most
        // twice the bound (a hair less, so rounding in f64 keeps within it).
        let fits = half.max(1e-9) / I16_MAX / 2.0 <= max_error_m;
        let scale = half
            .max(1e-9)
            .max(2.0 * max_error_m * I16_MAX * (1.0 - 1e-6));
        fits.then_some(QuantFrame { center, scale })
    }

    pub(super) fn quantize(&self, p: [f32; 3]) -> [i32; 3] {
        [0, 1, 2].map(|k| {
            ((p[k] as f64 - self.center[k]) / self.scale * I16_MAX)
                .round()
                .clamp(-I16_MAX, I16_MAX) as i32
        })
    }

    pub(super) fn dequantize(&self, q: [i32; 3]) -> [f64; 3] {
        [0, 1, 2].map(|k| self.center[k] + self.scale * q[k] as f64 / I16_MAX)
    }

    /// The dequantized positions (glTF y-up, mesh frame).
    pub(super) fn decoded_positions(&self, positions: &[[f32; 3]]) -> Vec<DVec3> {
        y_up(positions)
            .into_iter()
            .map(|p| DVec3::from(self.dequantize(self.quantize(p))))
            .collect()
    }

    /// The node (or instance) transform that dequantizes (clients read a normalized i16 `q` as
    /// `q / 32767`).
    pub(super) fn matrix(&self) -> DMat4 {
        DMat4::from_scale_rotation_translation(
            DVec3::splat(self.scale),
            glam::DQuat::IDENTITY,
            DVec3::from(self.center),
        )
    }
}

/// A unit vector as normalized i8 (`round(x * 127)`).
pub(super) fn normal_i8(n: [f32; 3]) -> [i32; 3] {
    n.map(|x| (x.clamp(-1.0, 1.0) * 127.0).round() as i32)
}

/// Whether every UV lies inside [0, 1] (16-bit normalized UVs hold them).
pub(super) fn uvs_in_unit_square(uvs: &[[f32; 2]]) -> bool {
    uvs.iter()
        .all(|t| t.iter().all(|x| (0.0..=1.0).contains(x)))
}

/// UVs inside [0, 1] as normalized u16, or `None` when they tile beyond it.
pub(super) fn uvs_u16(uvs: &[[f32; 2]]) -> Option<Vec<[i32; 2]>> {
    uvs_in_unit_square(uvs).then(|| {
        uvs.iter()
            .map(|t| t.map(|x| (x as f64 * 65535.0).round() as i32))
            .collect()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_frame_takes_the_coarsest_step_within_the_bound() {
        let prim = ContentPrimitive {
            positions: vec![[-3.0, 0.25, 1.0], [4.5, -2.0, 0.125], [0.3337, 1.777, -0.9]],
            ..Default::default()
        };
        for bound_m in [0.0001, 0.001, 0.02, 0.5] {
            let f = QuantFrame::of(std::slice::from_ref(&prim), bound_m).expect("fits");
            // A step of (nearly) twice the bound: no finer than it needs to be.
            let step_m = f.scale / I16_MAX;
            assert!(
                step_m <= 2.0 * bound_m && step_m > 1.999 * bound_m,
                "{bound_m}"
            );
            for (p, d) in y_up(&prim.positions)
                .iter()
                .zip(f.decoded_positions(&prim.positions))
            {
                for k in 0..3 {
                    assert!(
                        (p[k] as f64 - d[k]).abs() <= bound_m,
                        "{bound_m}: {p:?} -> {d}"
                    );
                }
            }
        }
        // 7.5 m across: 16 bits hold no step under 0.11 mm, so a finer bound keeps floats.
        assert!(QuantFrame::of(&[prim], 0.00005).is_none());
    }
}
