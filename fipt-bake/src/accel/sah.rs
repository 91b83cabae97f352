//! Top-down binned-SAH BVH2 builder feeding obvhs' CWBVH converter.
//!
//! obvhs' own PLOC builders cluster bottom-up by Morton order; on room-like meshes (large
//! tessellated walls enclosing the ray origins) that merges neighbouring walls into hollow boxes
//! every ray starts inside, and tracing drops to a fraction of a million rays per second. A
//! top-down surface-area-heuristic split separates the walls first (thin boxes), which is what
//! Embree-class builders do. The BVH2 (one primitive per leaf) is collapsed into obvhs' 8-wide
//! compressed BVH by its SAH-driven converter.
//!
//! Owns: the split search. Must not touch: traversal (obvhs) or triangle intersection (accel).

use glam::Vec3A;
use obvhs::aabb::Aabb;
use obvhs::bvh2::{Bvh2, node::Bvh2Node};

const BINS: usize = 32;

#[derive(Clone, Copy)]
struct Bin {
    bounds: Aabb,
    count: u32,
}

fn half_area(b: &Aabb) -> f32 {
    if b.min.x > b.max.x {
        return 0.0;
    }
    b.half_area()
}

/// Builds a BVH2 over primitive boxes (one primitive per leaf).
pub fn build_bvh2(boxes: &[Aabb]) -> Bvh2 {
    let n = boxes.len();
    let mut bvh = Bvh2::default();
    if n == 0 {
        return bvh;
    }
    let centroids: Vec<Vec3A> = boxes.iter().map(|b| b.center()).collect();
    let mut prims: Vec<u32> = (0..n as u32).collect();
    let mut nodes: Vec<Bvh2Node> = Vec::with_capacity(2 * n - 1);
    nodes.push(Bvh2Node::default());
    // (node index, start, end, depth)
    let mut stack = vec![(0usize, 0usize, n, 1usize)];
    let mut max_depth = 1;
    while let Some((node, start, end, depth)) = stack.pop() {
        max_depth = max_depth.max(depth);
        let mut bounds = Aabb::INVALID;
        let mut cb = Aabb::INVALID;
        for &p in &prims[start..end] {
            bounds = bounds.union(&boxes[p as usize]);
            cb.extend(centroids[p as usize]);
        }
        if end - start == 1 {
            nodes[node] = Bvh2Node::new(bounds, 1, start as u32);
            continue;
        }
        let mid = split(&mut prims[start..end], boxes, &centroids, &cb) + start;
        let left = nodes.len();
        nodes.push(Bvh2Node::default());
        nodes.push(Bvh2Node::default());
        nodes[node] = Bvh2Node::new(bounds, 0, left as u32);
        stack.push((left + 1, mid, end, depth + 1));
        stack.push((left, start, mid, depth + 1));
    }
    bvh.nodes = nodes;
    bvh.primitive_indices = prims;
    bvh.max_depth = max_depth;
    bvh
}

/// Partitions `prims` by the best binned-SAH plane; returns the split position (never 0 or len).
fn split(prims: &mut [u32], boxes: &[Aabb], centroids: &[Vec3A], cb: &Aabb) -> usize {
    let n = prims.len();
    let ext = cb.max - cb.min;
    let mut best = (f32::INFINITY, usize::MAX, 0usize);
    for axis in 0..3 {
        if ext[axis] <= 0.0 {
            continue;
        }
        let scale = BINS as f32 / ext[axis];
        let bin_of = |p: u32| {
            (((centroids[p as usize][axis] - cb.min[axis]) * scale) as usize).min(BINS - 1)
        };
        let mut bins = [Bin {
            bounds: Aabb::INVALID,
            count: 0,
        }; BINS];
        for &p in prims.iter() {
            let b = &mut bins[bin_of(p)];
            b.bounds = b.bounds.union(&boxes[p as usize]);
            b.count += 1;
        }
        // Sweep from the right, then from the left.
        let mut right_area = [0f32; BINS];
        let mut right_count = [0u32; BINS];
        let (mut acc, mut cnt) = (Aabb::INVALID, 0u32);
        for i in (1..BINS).rev() {
            acc = acc.union(&bins[i].bounds);
            cnt += bins[i].count;
            right_area[i] = half_area(&acc);
            right_count[i] = cnt;
        }
        let (mut acc, mut cnt) = (Aabb::INVALID, 0u32);
        for i in 0..BINS - 1 {
            acc = acc.union(&bins[i].bounds);
            cnt += bins[i].count;
            let (rc, lc) = (right_count[i + 1], cnt);
            if lc == 0 || rc == 0 {
                continue;
            }
            let cost = half_area(&acc) * lc as f32 + right_area[i + 1] * rc as f32;
            if cost < best.0 {
                best = (cost, axis, i);
            }
        }
    }
    if best.1 == usize::MAX {
        // All centroids coincide: split in the middle.
        return n / 2;
    }
    let (axis, split_bin) = (best.1, best.2);
    let scale = BINS as f32 / ext[axis];
    let left_of = |p: &u32| {
        (((centroids[*p as usize][axis] - cb.min[axis]) * scale) as usize).min(BINS - 1)
            <= split_bin
    };
    let mut i = 0;
    for j in 0..n {
        if left_of(&prims[j]) {
            prims.swap(i, j);
            i += 1;
        }
    }
    if i == 0 || i == n { n / 2 } else { i }
}
