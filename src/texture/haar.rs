//! Haar wavelet pyramid of a texture (paper III.E, formulas (3) and (4)).
//!
//! One step is a row transform followed by a column transform. Each transform takes a pair of
//! neighbours (a, b) to a low band `(a + b) / 2` and a high band `(a - b) / 2`; the paper's
//! formulas write the outputs in place, lows in the first half of the row (column) and highs in
//! the second half. After both transforms the four quarter-size bands are LL (the image at half
//! resolution: each texel the mean of a 2x2 block), LH, HL and HH (horizontal, vertical and
//! diagonal detail). The next level is the LL band of this one.
//!
//! Sizes: an odd width (height) is handled by **edge replication**: the last column (row) is
//! paired with itself, so its high coefficient is 0 and its low coefficient is its own value; the
//! band is `ceil(w / 2)` wide. Any size works, non-powers of two included, down to 1x1.
//!
//! Colour and alpha: all four RGBA channels are transformed alike, as f32. Inputs are 8-bit
//! integers, so every coefficient of the first 8 levels is a dyadic rational that f32 holds
//! exactly: [`synthesize`] rebuilds a level from its LL band and detail bands *exactly* (tested).
//!
//! What is shipped: only the LL bands, rounded to 8 bits, each as a self-contained image (a tile
//! must be viewable alone, and glTF has no wavelet texture). The detail bands are not written;
//! [`analyze`]/[`synthesize`] exist to keep the transform honest (the LL we ship is the one the
//! full transform gives, and the transform is invertible). [`next_level`] computes the LL band
//! alone in one pass, holding the source and the quarter-size result.
//!
//! The pipeline uses [`RowPyramid`]: the same LL arithmetic fed one decoded row of level 0 at a
//! time, each level's finished rows feeding the next level at once, so only a row pair per level
//! is held in f32 and each level is kept only as the 8-bit RGBA that gets encoded (a third of
//! level 0's bytes for all of them). Its levels equal [`next_level`]'s bit for bit (tested).

/// An RGBA image with f32 samples, interleaved, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Planes {
    pub width: u32,
    pub height: u32,
    pub data: Vec<f32>,
}

impl Planes {
    /// From 8-bit RGBA.
    pub fn from_rgba8(width: u32, height: u32, rgba: &[u8]) -> Planes {
        assert_eq!(rgba.len(), width as usize * height as usize * 4);
        Planes {
            width,
            height,
            data: rgba.iter().map(|&x| x as f32).collect(),
        }
    }

    /// Rounded (half up) and clamped to 8 bits.
    pub fn to_rgba8(&self) -> Vec<u8> {
        self.data.iter().map(|&x| to_u8(x)).collect()
    }

    /// The four samples of texel (x, y).
    pub fn at(&self, x: u32, y: u32) -> &[f32] {
        let i = (y as usize * self.width as usize + x as usize) * 4;
        &self.data[i..i + 4]
    }
}

/// Size of the next level: half, rounded up (edge replication).
pub fn half(n: u32) -> u32 {
    n.div_ceil(2).max(1)
}

/// Sizes of every level from `(w, h)` down to 1x1, level 0 first.
pub fn level_sizes(width: u32, height: u32) -> Vec<(u32, u32)> {
    let mut out = vec![(width.max(1), height.max(1))];
    while let Some(&(w, h)) = out.last() {
        if w <= 1 && h <= 1 {
            break;
        }
        out.push((half(w), half(h)));
    }
    out
}

/// One level of the transform: LL (the next level) and the detail bands, each
/// `half(w) x half(h)` RGBA.
#[derive(Debug, Clone, PartialEq)]
pub struct Bands {
    /// Size of the level these bands came from (to drop replicated edges when rebuilding).
    pub width: u32,
    pub height: u32,
    pub ll: Planes,
    /// Row high, column low (horizontal detail).
    pub hl: Vec<f32>,
    /// Row low, column high (vertical detail).
    pub lh: Vec<f32>,
    /// Row high, column high (diagonal detail).
    pub hh: Vec<f32>,
}

/// Formula (3) on one row: lows then highs, `half(n)` of each, edge-replicated.
fn row_transform(src: &[f32], n: usize, low: &mut [f32], high: &mut [f32]) {
    let m = n.div_ceil(2);
    for j in 0..m {
        let (ia, ib) = (2 * j, (2 * j + 1).min(n - 1));
        for c in 0..4 {
            let (a, b) = (src[ia * 4 + c], src[ib * 4 + c]);
            low[j * 4 + c] = (a + b) / 2.0;
            high[j * 4 + c] = (a - b) / 2.0;
        }
    }
}

/// The full transform of one level (row transform, then column transform).
pub fn analyze(p: &Planes) -> Bands {
    let (w, h) = (p.width as usize, p.height as usize);
    let (w2, h2) = (w.div_ceil(2), h.div_ceil(2));
    // Row transform of every row: L (w2 wide) and H (w2 wide), h rows each.
    let mut lo = vec![0.0f32; w2 * h * 4];
    let mut hi = vec![0.0f32; w2 * h * 4];
    for y in 0..h {
        let src = &p.data[y * w * 4..(y + 1) * w * 4];
        let (l, r) = (y * w2 * 4, (y + 1) * w2 * 4);
        row_transform(src, w, &mut lo[l..r], &mut hi[l..r]);
    }
    // Column transform (formula (4)) of both: rows 2i and 2i+1 (replicated at the bottom).
    let column = |band: &[f32]| {
        let mut low = vec![0.0f32; w2 * h2 * 4];
        let mut high = vec![0.0f32; w2 * h2 * 4];
        for i in 0..h2 {
            let (ra, rb) = (2 * i, (2 * i + 1).min(h - 1));
            for k in 0..w2 * 4 {
                let (a, b) = (band[ra * w2 * 4 + k], band[rb * w2 * 4 + k]);
                low[i * w2 * 4 + k] = (a + b) / 2.0;
                high[i * w2 * 4 + k] = (a - b) / 2.0;
            }
        }
        (low, high)
    };
    let (ll, lh) = column(&lo);
    let (hl, hh) = column(&hi);
    Bands {
        width: p.width,
        height: p.height,
        ll: Planes {
            width: w2 as u32,
            height: h2 as u32,
            data: ll,
        },
        hl,
        lh,
        hh,
    }
}

/// The inverse of [`analyze`]: a = low + high, b = low - high, columns then rows; the replicated
/// last row/column is dropped. Exact for the coefficients of 8-bit images (see the module notes).
pub fn synthesize(b: &Bands) -> Planes {
    let (w, h) = (b.width as usize, b.height as usize);
    let (w2, h2) = (b.ll.width as usize, b.ll.height as usize);
    let uncolumn = |low: &[f32], high: &[f32]| {
        let mut out = vec![0.0f32; w2 * h * 4];
        for i in 0..h2 {
            for k in 0..w2 * 4 {
                let (l, d) = (low[i * w2 * 4 + k], high[i * w2 * 4 + k]);
                out[2 * i * w2 * 4 + k] = l + d;
                if 2 * i + 1 < h {
                    out[(2 * i + 1) * w2 * 4 + k] = l - d;
                }
            }
        }
        out
    };
    let lo = uncolumn(&b.ll.data, &b.lh);
    let hi = uncolumn(&b.hl, &b.hh);
    let mut data = vec![0.0f32; w * h * 4];
    for y in 0..h {
        for j in 0..w2 {
            for c in 0..4 {
                let (l, d) = (lo[(y * w2 + j) * 4 + c], hi[(y * w2 + j) * 4 + c]);
                data[(y * w + 2 * j) * 4 + c] = l + d;
                if 2 * j + 1 < w {
                    data[(y * w + 2 * j + 1) * 4 + c] = l - d;
                }
            }
        }
    }
    Planes {
        width: b.width,
        height: b.height,
        data,
    }
}

/// The LL band of `p` alone, in one pass: for each output texel, the row transform's low band of
/// rows 2i and 2i+1, then the column transform's low band, the same float operations in the same
/// order as [`analyze`] (so the same values, bit for bit).
pub fn next_level(p: &Planes) -> Planes {
    ll_pass(p.width, p.height, &p.data)
}

/// [`next_level`] straight from 8-bit RGBA (the f32 level 0 is never built: u8 → f32 is exact,
/// so the result is the same bit for bit, in a quarter of the memory).
pub fn next_level_rgba8(width: u32, height: u32, rgba: &[u8]) -> Planes {
    assert_eq!(rgba.len(), width as usize * height as usize * 4);
    ll_pass(width, height, rgba)
}

fn ll_pass<T: Copy + Into<f32>>(width: u32, height: u32, src: &[T]) -> Planes {
    let (w, h) = (width as usize, height as usize);
    let (w2, h2) = (w.div_ceil(2), h.div_ceil(2));
    let mut data = vec![0.0f32; w2 * h2 * 4];
    let at = |x: usize, y: usize, c: usize| -> f32 { src[(y * w + x) * 4 + c].into() };
    for i in 0..h2 {
        let (ra, rb) = (2 * i, (2 * i + 1).min(h - 1));
        for j in 0..w2 {
            let (ca, cb) = (2 * j, (2 * j + 1).min(w - 1));
            for c in 0..4 {
                let l0 = (at(ca, ra, c) + at(cb, ra, c)) / 2.0;
                let l1 = (at(ca, rb, c) + at(cb, rb, c)) / 2.0;
                data[(i * w2 + j) * 4 + c] = (l0 + l1) / 2.0;
            }
        }
    }
    Planes {
        width: w2 as u32,
        height: h2 as u32,
        data,
    }
}

/// Rounded (half up) and clamped to 8 bits.
fn to_u8(x: f32) -> u8 {
    (x + 0.5).floor().clamp(0.0, 255.0) as u8
}

/// The row low band of one source row: `(a + b) / 2` of each column pair, edge-replicated, the
/// first operation of [`ll_pass`] on that row.
fn row_low<T: Copy + Into<f32>>(src: &[T], w: usize, out: &mut [f32]) {
    for j in 0..w.div_ceil(2) {
        let (ca, cb) = (2 * j, (2 * j + 1).min(w - 1));
        for c in 0..4 {
            out[j * 4 + c] = (src[ca * 4 + c].into() + src[cb * 4 + c].into()) / 2.0;
        }
    }
}

/// One step of [`RowPyramid`]: the LL band of a level, from that level's rows.
struct RowStep {
    /// Width of the level it reads.
    src_width: usize,
    /// Row low band of the first row of the current pair, if it came.
    first: Option<Vec<f32>>,
    /// Row low band of the second row (scratch).
    second: Vec<f32>,
}

impl RowStep {
    /// Takes one source row; gives an LL row when it completes a pair.
    fn push<T: Copy + Into<f32>>(&mut self, row: &[T]) -> Option<Vec<f32>> {
        match self.first.take() {
            None => {
                let mut l0 = vec![0.0; self.src_width.div_ceil(2) * 4];
                row_low(row, self.src_width, &mut l0);
                self.first = Some(l0);
                None
            }
            Some(mut l0) => {
                row_low(row, self.src_width, &mut self.second);
                for (a, &b) in l0.iter_mut().zip(&self.second) {
                    *a = (*a + b) / 2.0;
                }
                Some(l0)
            }
        }
    }

    /// After the last row: an odd last row pairs with itself (its row low band twice, as
    /// [`ll_pass`] computes it from the same samples).
    fn flush(&mut self) -> Option<Vec<f32>> {
        let mut l0 = self.first.take()?;
        for a in l0.iter_mut() {
            *a = (*a + *a) / 2.0;
        }
        Some(l0)
    }
}

/// Levels 1.. of the pyramid of a `width x height` RGBA image, built from its rows top to
/// bottom ([`Self::push_row`]) and returned as 8-bit RGBA ([`Self::finish`]): the values of
/// [`next_level_rgba8`] then [`next_level`] repeatedly, rounded as [`Planes::to_rgba8`].
pub struct RowPyramid {
    /// Rows of level 0 still to come.
    rows_left: u32,
    /// Step `k` makes level `k + 1`.
    steps: Vec<RowStep>,
    /// Level `k + 1` as 8-bit RGBA, rows so far.
    levels: Vec<(u32, u32, Vec<u8>)>,
}

impl RowPyramid {
    /// Every level down to 1x1 ([`level_sizes`]); none for a 1x1 image.
    pub fn new(width: u32, height: u32) -> RowPyramid {
        let sizes = level_sizes(width, height);
        let steps = sizes[..sizes.len() - 1]
            .iter()
            .map(|&(w, _)| RowStep {
                src_width: w as usize,
                first: None,
                second: vec![0.0; half(w) as usize * 4],
            })
            .collect();
        let levels = sizes[1..]
            .iter()
            // Exact capacity: growing by doubling would hold up to twice the level.
            .map(|&(w, h)| (w, h, Vec::with_capacity(w as usize * h as usize * 4)))
            .collect();
        RowPyramid {
            rows_left: height,
            steps,
            levels,
        }
    }

    /// The next row of level 0, 8-bit RGBA, `width * 4` bytes.
    pub fn push_row(&mut self, rgba: &[u8]) {
        self.rows_left = self
            .rows_left
            .checked_sub(1)
            .expect("more rows than the height");
        let Some(step) = self.steps.first_mut() else {
            return;
        };
        assert_eq!(rgba.len(), step.src_width * 4);
        if let Some(ll) = step.push(rgba) {
            self.emit(0, ll);
        }
    }

    /// A finished row of level `k + 1`: kept in 8 bits, fed to the next step.
    fn emit(&mut self, mut k: usize, mut row: Vec<f32>) {
        loop {
            self.levels[k].2.extend(row.iter().map(|&x| to_u8(x)));
            match self.steps.get_mut(k + 1).and_then(|s| s.push(&row[..])) {
                Some(next) => (k, row) = (k + 1, next),
                None => return,
            }
        }
    }

    /// After the last row of level 0: every level as `(width, height, rgba)`, level 1 first.
    pub fn finish(mut self) -> Vec<(u32, u32, Vec<u8>)> {
        assert_eq!(self.rows_left, 0, "rows of level 0 missing");
        // Finer steps first: a flushed row can complete a pair of the next step.
        for k in 0..self.steps.len() {
            if let Some(ll) = self.steps[k].flush() {
                self.emit(k, ll);
            }
        }
        for (w, h, px) in &self.levels {
            debug_assert_eq!(px.len(), *w as usize * *h as usize * 4);
        }
        self.levels
    }
}

/// Peak signal-to-noise ratio (dB) between two 8-bit images of one size over all four channels;
/// infinite when they are equal.
pub fn psnr(a: &[u8], b: &[u8]) -> f64 {
    assert_eq!(a.len(), b.len());
    if a.is_empty() {
        return f64::INFINITY;
    }
    let se: f64 = a
        .iter()
        .zip(b)
        .map(|(&x, &y)| (x as f64 - y as f64).powi(2))
        .sum();
    let mse = se / a.len() as f64;
    if mse == 0.0 {
        f64::INFINITY
    } else {
        10.0 * (255.0f64 * 255.0 / mse).log10()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic pseudo-random RGBA (with a varying alpha).
    fn noise(w: u32, h: u32, seed: u64) -> Vec<u8> {
        crate::texture::codec::tests::noise((w * h * 4) as usize, seed)
    }

    #[test]
    fn level_sizes_halve_rounding_up() {
        assert_eq!(
            level_sizes(600, 800),
            vec![
                (600, 800),
                (300, 400),
                (150, 200),
                (75, 100),
                (38, 50),
                (19, 25),
                (10, 13),
                (5, 7),
                (3, 4),
                (2, 2),
                (1, 1)
            ]
        );
        assert_eq!(level_sizes(1, 1), vec![(1, 1)]);
        assert_eq!(level_sizes(3, 1), vec![(3, 1), (2, 1), (1, 1)]);
    }

    #[test]
    fn rebuild_from_coarser_ll_and_details_is_exact() {
        // Odd, even, non-power-of-two and 1-pixel sizes; several levels deep.
        for &(w, h) in &[(8, 8), (7, 5), (600, 3), (1, 9), (13, 1), (37, 22)] {
            let orig = Planes::from_rgba8(w, h, &noise(w, h, (w * 31 + h) as u64));
            let mut level = orig.clone();
            for _ in 0..4 {
                let bands = analyze(&level);
                assert_eq!(synthesize(&bands), level, "{w}x{h}: exact rebuild");
                // The one-pass LL is the full transform's LL, bit for bit.
                assert_eq!(next_level(&level), bands.ll);
                if level == orig {
                    let px = orig.to_rgba8();
                    assert_eq!(next_level_rgba8(w, h, &px), bands.ll);
                }
                level = bands.ll;
            }
        }
    }

    #[test]
    fn ll_is_the_exact_box_mean_on_divisible_sizes() {
        let (w, h) = (32u32, 16u32);
        let px = noise(w, h, 7);
        let mut level = Planes::from_rgba8(w, h, &px);
        for k in 1..=4u32 {
            level = next_level(&level);
            let s = 1u32 << k;
            assert_eq!((level.width, level.height), (w / s, h / s));
            for y in 0..h / s {
                for x in 0..w / s {
                    for c in 0..4 {
                        let mut sum = 0u64;
                        for yy in y * s..(y + 1) * s {
                            for xx in x * s..(x + 1) * s {
                                sum += px[((yy * w + xx) * 4 + c) as usize] as u64;
                            }
                        }
                        let mean = sum as f64 / (s * s) as f64;
                        assert_eq!(
                            level.at(x, y)[c as usize] as f64,
                            mean,
                            "level {k} exact mean"
                        );
                    }
                }
            }
        }
    }

    /// An independent reference for odd sizes: pad by replicating the last row/column to an even
    /// size, then average 2x2 blocks, in f64.
    fn box_reference(w: u32, h: u32, px: &[f64]) -> (u32, u32, Vec<f64>) {
        let (w2, h2) = (w.div_ceil(2), h.div_ceil(2));
        let get = |x: u32, y: u32, c: u32| px[((y.min(h - 1) * w + x.min(w - 1)) * 4 + c) as usize];
        let mut out = Vec::new();
        for y in 0..h2 {
            for x in 0..w2 {
                for c in 0..4 {
                    out.push(
                        (get(2 * x, 2 * y, c)
                            + get(2 * x + 1, 2 * y, c)
                            + get(2 * x, 2 * y + 1, c)
                            + get(2 * x + 1, 2 * y + 1, c))
                            / 4.0,
                    );
                }
            }
        }
        (w2, h2, out)
    }

    #[test]
    fn pyramid_matches_a_padded_box_filter_on_odd_sizes() {
        let (w, h) = (45u32, 27u32);
        let px = noise(w, h, 3);
        let mut level = Planes::from_rgba8(w, h, &px);
        let (mut rw, mut rh, mut r): (u32, u32, Vec<f64>) =
            (w, h, px.iter().map(|&x| x as f64).collect());
        for _ in 0..5 {
            level = next_level(&level);
            (rw, rh, r) = box_reference(rw, rh, &r);
            assert_eq!((level.width, level.height), (rw, rh));
            let reference: Vec<u8> = r
                .iter()
                .map(|&x| (x + 0.5).floor().clamp(0.0, 255.0) as u8)
                .collect();
            assert_eq!(psnr(&level.to_rgba8(), &reference), f64::INFINITY);
        }
    }

    #[test]
    fn psnr_of_known_error() {
        let a = vec![10u8; 100];
        let mut b = a.clone();
        assert_eq!(psnr(&a, &b), f64::INFINITY);
        b[0] = 20; // mse = 1
        assert!((psnr(&a, &b) - 48.1308).abs() < 1e-3);
    }

    /// [`RowPyramid`] against the whole-image path: level 1 from 8-bit RGBA, then
    /// [`next_level`] down to 1x1, each rounded to 8 bits.
    #[test]
    fn row_pyramid_is_the_whole_image_pyramid_bit_for_bit() {
        for &(w, h) in &[
            (1, 1),
            (2, 1),
            (1, 2),
            (3, 1),
            (1, 7),
            (7, 5),
            (600, 3),
            (13, 1),
            (37, 22),
            (45, 27),
            (64, 64),
            (100, 75),
        ] {
            let px = noise(w, h, (w * 131 + h) as u64);
            let mut whole = Vec::new();
            if w > 1 || h > 1 {
                let mut level = next_level_rgba8(w, h, &px);
                loop {
                    whole.push((level.width, level.height, level.to_rgba8()));
                    if level.width <= 1 && level.height <= 1 {
                        break;
                    }
                    level = next_level(&level);
                }
            }
            let mut rows = RowPyramid::new(w, h);
            for row in px.chunks_exact(w as usize * 4) {
                rows.push_row(row);
            }
            let streamed = rows.finish();
            assert_eq!(streamed.len(), level_sizes(w, h).len() - 1, "{w}x{h}");
            assert_eq!(streamed, whole, "{w}x{h}");
        }
    }

    #[test]
    #[should_panic(expected = "rows of level 0 missing")]
    fn row_pyramid_needs_every_row() {
        let px = noise(4, 4, 1);
        let mut rows = RowPyramid::new(4, 4);
        for row in px.chunks_exact(16).take(3) {
            rows.push_row(row);
        }
        rows.finish();
    }
}
