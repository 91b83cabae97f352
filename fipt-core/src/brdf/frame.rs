//! The local shading frame about a normal (reference §2.1): t = normalize(x̂ × n) if |n_x| ≤ 0.1,
//! else normalize(ŷ × n); b = n × t.

use glam::Vec3;

#[derive(Clone, Copy, Debug)]
pub struct Frame {
    pub t: Vec3,
    pub b: Vec3,
    pub n: Vec3,
}

impl Frame {
    pub fn new(n: Vec3) -> Self {
        let t = if n.x.abs() <= 0.1 {
            Vec3::X.cross(n)
        } else {
            Vec3::Y.cross(n)
        }
        .normalize();
        Self {
            t,
            b: n.cross(t),
            n,
        }
    }

    /// Local (x, y, z) → world.
    #[inline]
    pub fn to_world(&self, v: Vec3) -> Vec3 {
        self.t * v.x + self.b * v.y + self.n * v.z
    }

    /// World → local.
    #[inline]
    pub fn to_local(&self, v: Vec3) -> Vec3 {
        Vec3::new(v.dot(self.t), v.dot(self.b), v.dot(self.n))
    }
}
