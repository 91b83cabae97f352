//! The scene's normalising cube (reference §2.2): L′'s voxel grid spans it and it maps positions
//! to the hash grid's unit cube.
//!
//! Owns: the cube and the map to unit coordinates. Must not touch: what is stored over it.

use glam::Vec3;

/// The reference's scene cube: the scalar min and max over all coordinates of all first hits,
/// each scaled by 1.1 (`voxel_min = 1.1·min`, `voxel_max = 1.1·max`; the same box normalises
/// positions for the hash grid).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SceneBox {
    pub min: f32,
    pub max: f32,
}

impl SceneBox {
    pub fn from_points<'a>(points: impl IntoIterator<Item = &'a Vec3>) -> Self {
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        for p in points {
            lo = lo.min(p.min_element());
            hi = hi.max(p.max_element());
        }
        Self {
            min: 1.1 * lo,
            max: 1.1 * hi,
        }
    }

    /// Position mapped to the unit cube (not clamped).
    #[inline]
    pub fn to_unit(&self, p: Vec3) -> Vec3 {
        (p - Vec3::splat(self.min)) / (self.max - self.min)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cube_is_the_scaled_scalar_extent_of_all_coordinates() {
        let sb = SceneBox::from_points(&[Vec3::new(0.0, 1.0, 2.0), Vec3::new(5.0, 2.7, 4.0)]);
        assert_eq!(sb, SceneBox { min: 0.0, max: 5.5 });
        assert_eq!(
            sb.to_unit(Vec3::new(0.0, 2.75, 5.5)),
            Vec3::new(0.0, 0.5, 1.0)
        );
    }
}
