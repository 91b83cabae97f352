//! The packed per-pixel shading layout shared by the bake, the shading cache, the training
//! batches and the tensor renderer: L_d, then L_s0 and L_s1 (paper Eq. 5–6) at the
//! `ROUGHNESS_LEVELS` roughness levels of Eq. 8, RGB each.
//!
//! Owns: the one definition of that layout. Must not touch: how shadings are estimated or used.

use std::ops::Range;

/// Number of pre-integrated roughness levels in the shading cache (their roughness values are
/// `brdf::roughness_levels`).
pub const ROUGHNESS_LEVELS: usize = 6;

/// Offsets of the blocks in one pixel's packed shadings:
/// `[L_d (3) | L_s0 level 0..L (L × 3) | L_s1 level 0..L (L × 3)]`, L = `ROUGHNESS_LEVELS`.
#[derive(Clone, Copy, Debug)]
pub struct ShadingLayout;

impl ShadingLayout {
    /// Roughness levels per specular block.
    pub const LEVELS: usize = ROUGHNESS_LEVELS;
    /// Values per pixel.
    pub const DIM: usize = 3 + 6 * Self::LEVELS;
    /// The diffuse shading L_d.
    pub const LD: Range<usize> = 0..3;
    /// All levels of L_s0 (level-major, RGB inner).
    pub const LS0: Range<usize> = 3..3 + 3 * Self::LEVELS;
    /// All levels of L_s1 (level-major, RGB inner).
    pub const LS1: Range<usize> = 3 + 3 * Self::LEVELS..Self::DIM;

    /// L_s0 at roughness level `j`.
    #[inline]
    pub const fn ls0(j: usize) -> Range<usize> {
        Self::LS0.start + 3 * j..Self::LS0.start + 3 * j + 3
    }

    /// L_s1 at roughness level `j`.
    #[inline]
    pub const fn ls1(j: usize) -> Range<usize> {
        Self::LS1.start + 3 * j..Self::LS1.start + 3 * j + 3
    }

    /// Pixel `p`'s values in a buffer of packed pixels.
    #[inline]
    pub fn pixel(buf: &[f32], p: usize) -> &[f32] {
        &buf[p * Self::DIM..(p + 1) * Self::DIM]
    }

    /// Pixel `p`'s values, mutable.
    #[inline]
    pub fn pixel_mut(buf: &mut [f32], p: usize) -> &mut [f32] {
        &mut buf[p * Self::DIM..(p + 1) * Self::DIM]
    }
}

#[cfg(test)]
mod tests {
    use super::ShadingLayout as S;

    #[test]
    fn blocks_tile_the_pixel_without_overlap() {
        let mut owner = [0u8; S::DIM];
        for r in [S::LD]
            .into_iter()
            .chain((0..S::LEVELS).map(S::ls0))
            .chain((0..S::LEVELS).map(S::ls1))
        {
            for i in r {
                owner[i] += 1;
            }
        }
        assert!(owner.iter().all(|&c| c == 1));
        assert_eq!(S::ls0(0).start, S::LS0.start);
        assert_eq!(S::ls1(S::LEVELS - 1).end, S::LS1.end);
        assert_eq!(S::LS1.end, S::DIM);
    }
}
