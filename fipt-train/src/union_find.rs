//! Disjoint sets over 0..n (path halving; the smaller root wins a union), for grouping
//! connected triangles: the export's charts, the LDR solve's lamps.
//!
//! Owns: the structure. Must not touch: what is connected.

pub struct UnionFind(Vec<u32>);

impl UnionFind {
    /// `n` singletons.
    pub fn new(n: usize) -> Self {
        Self((0..n as u32).collect())
    }

    /// The root of `a`'s set.
    pub fn find(&mut self, mut a: u32) -> u32 {
        while self.0[a as usize] != a {
            let up = self.0[self.0[a as usize] as usize];
            self.0[a as usize] = up;
            a = up;
        }
        a
    }

    /// Joins the sets of `a` and `b`.
    pub fn union(&mut self, a: u32, b: u32) {
        let (ra, rb) = (self.find(a), self.find(b));
        if ra != rb {
            self.0[ra.max(rb) as usize] = ra.min(rb);
        }
    }
}
