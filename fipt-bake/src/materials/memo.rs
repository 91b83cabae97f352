//! A memo in front of an expensive material source: answers a query at a point it has seen
//! (same triangle, bit-identical position) from memory, and forwards only the new points, in
//! one batched query. With fixed pixel positions (`PathConfig::pixel_positions`) every camera
//! hit repeats bit for bit, so a view costs N exact queries per pixel instead of one per
//! sample.
//!
//! Owns: the memo. Must not touch: what the wrapped source computes.

use super::{MaterialSource, SurfaceMaterial};
use glam::Vec3;
use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};
use std::sync::Mutex;

/// A multiplicative hash mixing every word (keys are not attacker-controlled).
#[derive(Default)]
struct MixHasher(u64);

impl Hasher for MixHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u32(b as u32);
        }
    }
    fn write_u32(&mut self, k: u32) {
        self.0 = (self.0 ^ k as u64)
            .wrapping_mul(0x9e37_79b9_7f4a_7c15)
            .rotate_left(27);
    }
    fn write_usize(&mut self, k: usize) {
        self.write_u32(k as u32);
    }
}

type Key = [u32; 4];

pub struct Memo<'a> {
    inner: &'a dyn MaterialSource,
    map: Mutex<HashMap<Key, SurfaceMaterial, BuildHasherDefault<MixHasher>>>,
}

impl<'a> Memo<'a> {
    pub fn new(inner: &'a dyn MaterialSource) -> Self {
        Self {
            inner,
            map: Mutex::new(HashMap::default()),
        }
    }

    /// Forgets every point (e.g. between views, to bound memory).
    pub fn clear(&self) {
        self.map.lock().unwrap_or_else(|e| e.into_inner()).clear();
    }

    /// Points remembered.
    pub fn len(&self) -> usize {
        self.map.lock().unwrap_or_else(|e| e.into_inner()).len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

fn key(p: Vec3, t: u32) -> Key {
    [t, p.x.to_bits(), p.y.to_bits(), p.z.to_bits()]
}

impl MaterialSource for Memo<'_> {
    fn query(&self, points: &[Vec3], tris: &[u32], out: &mut Vec<SurfaceMaterial>) {
        out.clear();
        let mut map = self.map.lock().unwrap_or_else(|e| e.into_inner());
        // Known points answered; the first occurrence of each new point forwarded once.
        let mut pending: HashMap<Key, usize, BuildHasherDefault<MixHasher>> = HashMap::default();
        let (mut fp, mut ft) = (Vec::new(), Vec::new());
        let mut slot = Vec::with_capacity(points.len());
        for (&p, &t) in points.iter().zip(tris) {
            let k = key(p, t);
            match map.get(&k) {
                Some(m) => {
                    out.push(*m);
                    slot.push(usize::MAX);
                }
                None => {
                    let j = *pending.entry(k).or_insert_with(|| {
                        fp.push(p);
                        ft.push(t);
                        fp.len() - 1
                    });
                    out.push(SurfaceMaterial::BLACK);
                    slot.push(j);
                }
            }
        }
        if fp.is_empty() {
            return;
        }
        let mut fresh = Vec::with_capacity(fp.len());
        self.inner.query(&fp, &ft, &mut fresh);
        for (o, &j) in out.iter_mut().zip(&slot) {
            if j != usize::MAX {
                *o = fresh[j];
            }
        }
        for ((p, t), m) in fp.into_iter().zip(ft).zip(fresh) {
            map.insert(key(p, t), m);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicUsize, Ordering};

    /// Roughness = x, counting the points it is asked for.
    struct Counting(AtomicUsize);
    impl MaterialSource for Counting {
        fn query(&self, points: &[Vec3], _t: &[u32], out: &mut Vec<SurfaceMaterial>) {
            self.0.fetch_add(points.len(), Ordering::Relaxed);
            out.clear();
            out.extend(points.iter().map(|p| SurfaceMaterial {
                base_color: Vec3::ONE,
                roughness: p.x,
                metallic: p.y,
            }));
        }
    }

    /// The memo returns what the source would, in order, and asks it once per distinct
    /// (point, triangle).
    #[test]
    fn answers_as_the_source_once_per_point() {
        let src = Counting(AtomicUsize::new(0));
        let memo = Memo::new(&src);
        let p = |i: u32| Vec3::new(i as f32 * 0.1, 1.0 - i as f32 * 0.1, 0.0);
        let pts = [p(1), p(2), p(1), p(3), p(2)];
        let tris = [0, 0, 0, 0, 5];
        let mut out = Vec::new();
        memo.query(&pts, &tris, &mut out);
        assert_eq!(src.0.load(Ordering::Relaxed), 4);
        let mut again = Vec::new();
        memo.query(&[p(3), p(1), p(4)], &[0, 0, 0], &mut again);
        assert_eq!(src.0.load(Ordering::Relaxed), 5);
        for (m, q) in out.iter().zip(&pts) {
            assert_eq!((m.roughness, m.metallic), (q.x, q.y));
        }
        assert_eq!(again[0].roughness, p(3).x);
        assert_eq!(again[2].roughness, p(4).x);
        assert_eq!(memo.len(), 5);
        memo.clear();
        assert!(memo.is_empty());
    }
}
