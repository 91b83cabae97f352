//! The traversal of the acceleration structure: an eight-wide BVH with full-precision child
//! boxes stored as structs of arrays, traversed one ray at a time with AVX2 (all eight child
//! boxes in one pass of fused multiply-subtracts) and leaves of up to four triangles
//! intersected in one SSE pass — the layout of Embree's BVH8 with `Triangle4` leaves.
//!
//! The tree is collapsed from `sah`'s BVH2 the way Embree does it (`Bvh8::from_bvh2`): the
//! surface area heuristic picks the subtrees that become one leaf block, and each inner node
//! opens its largest child until it has eight. Child boxes are exact float boxes of the
//! triangles as the intersector sees them.
//!
//! The triangle test is the same Möller–Trumbore, in the same order of operations, as
//! `LeafTri::intersect` (no fused multiply-add), so a hit distance is bit-identical to the
//! scalar test's; only the box test uses FMA, and it only culls. Triangles at the same
//! distance resolve to the lowest index, so the closest hit is brute force's whatever the
//! tree and the order of the walk (which visits the nearest entered child next and stacks the
//! others unsorted).
//!
//! Owns: the BVH2 → BVH8 collapse, the wide node and leaf layout, closest-hit and any-hit
//! traversal. Must not touch: the BVH2 build (`sah`), shading. Where AVX2/FMA is missing
//! (checked once at run time) `Accel` uses obvhs's own tree and traversal instead.

use super::{Hit, LeafTri};
use glam::Vec3;
use obvhs::bvh2::Bvh2;

/// At most this many triangles share a leaf: one SSE block.
const LEAF_MAX: usize = 4;

/// Surface-area-heuristic cost of one binary split relative to one leaf block test (an
/// eight-wide node test covers about three binary levels). Measured with `bench trace` on
/// fipt-room, 1 thread, incoherent rays: 0.35 → 14.1 M rays/s, 0.1 → 15.4, 0.05 → 15.2; at
/// `--mesh-scale 4`: 6.5, 6.7 and 7.7 M rays/s.
const TRAVERSAL_COST: f32 = 0.05;

/// The BVH2 being collapsed, with the subtrees chosen as leaf blocks.
struct Collapse<'a> {
    bvh2: &'a Bvh2,
    leaf: &'a [bool],
    tris: &'a [LeafTri],
}

impl Collapse<'_> {
    /// A subtree that becomes one leaf block.
    fn is_leaf(&self, k: usize) -> bool {
        self.leaf[k]
    }

    fn area(&self, k: usize) -> f32 {
        half_area(self.bvh2, k)
    }
}

/// Half the surface area of BVH2 node `k`'s box.
fn half_area(bvh2: &Bvh2, k: usize) -> f32 {
    bvh2.nodes[k].aabb().half_area()
}

/// A leaf child's code has this bit set; the rest is the index of its `Tri4` block.
const LEAF: u32 = 1 << 31;
/// An empty child slot (its box is inverted, so it is never entered).
const EMPTY: u32 = u32::MAX;
/// Depth of the traversal stack: a BVH8 over a billion triangles is ~10 levels deep and each
/// level pushes at most seven entries. A push stores a whole vector of eight lanes, so the
/// stacks have eight slots more.
const STACK: usize = 128;
/// Far box distances are scaled up by this factor so that a ray grazing a box face is not lost
/// to rounding in the slab test (Ize, "Robust BVH ray traversal", 2013: 1 + 2γ₃).
const FAR_SCALE: f32 = 1.0 + 4.0 * f32::EPSILON;

/// Eight child boxes (structs of arrays: min x, y, z then max x, y, z, one lane per child)
/// and the eight child codes. 256 bytes, cache-line aligned.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(64))]
struct Node8 {
    bounds: [[f32; 8]; 6],
    child: [u32; 8],
}

/// Up to four triangles as structs of arrays: vertex 0 and the edges v1 − v0, v2 − v0 per
/// coordinate, and the mesh triangle index per lane. Unused lanes are degenerate (zero edges,
/// determinant 0: never hit).
#[derive(Clone, Copy, Debug)]
#[repr(C, align(16))]
struct Tri4 {
    v0: [[f32; 4]; 3],
    e1: [[f32; 4]; 3],
    e2: [[f32; 4]; 3],
    prim: [u32; 4],
}

/// The wide BVH and its leaf blocks.
pub(super) struct Bvh8 {
    nodes: Vec<Node8>,
    leaves: Vec<Tri4>,
    /// Levels of inner nodes on the longest root-to-leaf path.
    depth: usize,
}

impl Bvh8 {
    /// Collapses a BVH2 with one primitive per leaf (`sah::build_bvh2`) into eight-wide nodes,
    /// Embree's way: a subtree of at most `LEAF_MAX` triangles becomes one leaf block; an inner
    /// node takes the two children of its BVH2 node and keeps opening the largest-area child
    /// that is not such a leaf until it has eight. `tris` is in mesh order.
    pub(super) fn from_bvh2(bvh2: &Bvh2, tris: &[LeafTri]) -> Self {
        let mut out = Bvh8 {
            nodes: Vec::new(),
            leaves: Vec::new(),
            depth: 0,
        };
        if bvh2.nodes.is_empty() || tris.is_empty() {
            return out;
        }
        // Bottom-up (children follow their parent in `nodes`): the triangles under each BVH2
        // node and whether it is cheaper as one leaf block than split, by the surface area
        // heuristic: a block test costs 1, a binary split `TRAVERSAL_COST` plus the children's
        // costs weighted by the chance that a ray entering the node enters them.
        let nn = bvh2.nodes.len();
        let (mut count, mut cost, mut leaf) = (vec![0u32; nn], vec![0f32; nn], vec![false; nn]);
        for i in (0..nn).rev() {
            let n = &bvh2.nodes[i];
            if n.is_leaf() {
                count[i] = n.prim_count;
                cost[i] = 1.0;
                leaf[i] = n.prim_count as usize <= LEAF_MAX;
                continue;
            }
            let (l, r) = (n.first_index as usize, n.first_index as usize + 1);
            count[i] = count[l] + count[r];
            let area = |k: usize| half_area(bvh2, k);
            let a = area(i).max(f32::MIN_POSITIVE);
            let split = TRAVERSAL_COST + (area(l) * cost[l] + area(r) * cost[r]) / a;
            leaf[i] = count[i] as usize <= LEAF_MAX && split >= 1.0;
            cost[i] = if leaf[i] { 1.0 } else { split };
        }
        let c = Collapse {
            bvh2,
            leaf: &leaf,
            tris,
        };
        out.node(&c, 0, 1);
        out
    }

    /// Builds the wide node for BVH2 node `root` and its subtree; returns its index and box.
    fn node(&mut self, c: &Collapse, root: usize, depth: usize) -> (u32, Vec3, Vec3) {
        self.depth = self.depth.max(depth);
        let me = self.nodes.len();
        self.nodes.push(Node8 {
            bounds: [
                [f32::INFINITY; 8],
                [f32::INFINITY; 8],
                [f32::INFINITY; 8],
                [f32::NEG_INFINITY; 8],
                [f32::NEG_INFINITY; 8],
                [f32::NEG_INFINITY; 8],
            ],
            child: [EMPTY; 8],
        });
        let mut kids: Vec<usize> = if c.is_leaf(root) {
            vec![root]
        } else {
            let l = c.bvh2.nodes[root].first_index as usize;
            vec![l, l + 1]
        };
        while kids.len() < 8 {
            let open = kids
                .iter()
                .enumerate()
                .filter(|&(_, &k)| !c.is_leaf(k))
                .max_by(|a, b| c.area(*a.1).total_cmp(&c.area(*b.1)))
                .map(|(i, _)| i);
            let Some(i) = open else { break };
            let l = c.bvh2.nodes[kids[i]].first_index as usize;
            kids[i] = l;
            kids.push(l + 1);
        }
        let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
        for (j, &k) in kids.iter().enumerate() {
            let (code, clo, chi) = if c.is_leaf(k) {
                self.leaf(c, k)
            } else {
                self.node(c, k, depth + 1)
            };
            let n = &mut self.nodes[me];
            for a in 0..3 {
                n.bounds[a][j] = clo[a];
                n.bounds[a + 3][j] = chi[a];
            }
            n.child[j] = code;
            lo = lo.min(clo);
            hi = hi.max(chi);
        }
        (me as u32, lo, hi)
    }

    /// One leaf block holding the triangles under BVH2 node `k`; returns its code and box.
    fn leaf(&mut self, c: &Collapse, k: usize) -> (u32, Vec3, Vec3) {
        let mut prims = Vec::with_capacity(LEAF_MAX);
        let mut stack = vec![k];
        while let Some(i) = stack.pop() {
            let n = &c.bvh2.nodes[i];
            if n.is_leaf() {
                let f = n.first_index as usize;
                prims.extend_from_slice(&c.bvh2.primitive_indices[f..f + n.prim_count as usize]);
            } else {
                stack.push(n.first_index as usize + 1);
                stack.push(n.first_index as usize);
            }
        }
        prims.sort_unstable();
        let mut block = Tri4 {
            v0: [[0.0; 4]; 3],
            e1: [[0.0; 4]; 3],
            e2: [[0.0; 4]; 3],
            prim: [u32::MAX; 4],
        };
        let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
        for (l, &p) in prims.iter().enumerate() {
            let t = &c.tris[p as usize];
            let (v0, e1, e2) = (Vec3::from(t.v0), Vec3::from(t.e1), Vec3::from(t.e2));
            for a in 0..3 {
                block.v0[a][l] = v0[a];
                block.e1[a][l] = e1[a];
                block.e2[a][l] = e2[a];
            }
            block.prim[l] = p;
            // The corners as the intersector sees them (v0 + e rounds like the mesh's), and
            // the band of barycentric slack around the edges where it accepts hits too (up to
            // BARY_EPS·(|e1| + |e2|) beyond them), so the box bounds every hit it can report.
            let pad = Vec3::splat(2.0 * super::BARY_EPS * (e1.length() + e2.length()));
            for q in [v0, v0 + e1, v0 + e2] {
                lo = lo.min(q - pad);
                hi = hi.max(q + pad);
            }
        }
        self.leaves.push(block);
        (LEAF | (self.leaves.len() as u32 - 1), lo, hi)
    }

    /// Whether the traversal stack is deep enough for this tree (each inner level pushes at
    /// most seven pending children).
    pub(super) fn fits_stack(&self) -> bool {
        7 * self.depth < STACK
    }

    /// Whether this CPU runs the SIMD traversal (AVX2 and FMA).
    pub(super) fn supported() -> bool {
        #[cfg(target_arch = "x86_64")]
        {
            std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("fma")
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            false
        }
    }

    /// Closest hit along `o + t·d`, t ∈ (tmin, tmax): (t, mesh triangle). Call only where
    /// `supported()`.
    #[inline]
    pub(super) fn closest(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> Option<Hit> {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `Accel` calls this only after `supported()` returned true.
        unsafe {
            simd::closest(self, o, d, tmin, tmax)
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            let _ = (o, d, tmin, tmax);
            unreachable!("the wide traversal needs x86-64 with AVX2")
        }
    }

    /// `closest` of every ray of `rays`, into `out` (same length, checked by `Accel`), several
    /// rays interleaved. Call only where `supported()`.
    pub(super) fn closest_many(
        &self,
        rays: &[(Vec3, Vec3)],
        tmin: f32,
        tmax: f32,
        out: &mut [Option<Hit>],
    ) {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as `closest`.
        unsafe {
            simd::closest_many(self, rays, tmin, tmax, out)
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            unreachable!("the wide traversal needs x86-64 with AVX2")
        }
    }

    /// True when any triangle lies along `o + t·d`, t ∈ (tmin, tmax). Call only where
    /// `supported()`.
    #[inline]
    pub(super) fn occluded(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> bool {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as `closest`.
        unsafe {
            simd::occluded(self, o, d, tmin, tmax)
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            let _ = (o, d, tmin, tmax);
            unreachable!("the wide traversal needs x86-64 with AVX2")
        }
    }
}

/// A reciprocal that stays finite: a zero component becomes ±1e30 with its sign, so that slab
/// distances are ±inf or finite, never NaN (`-0.0` counts as positive, as in obvhs's fix).
/// The traversal's ray setup computes this for three components at once.
#[cfg(test)]
fn safe_rcp(x: f32) -> f32 {
    if x.abs() < 1e-30 {
        if x.is_sign_negative() && x != 0.0 {
            -1e30
        } else {
            1e30
        }
    } else {
        1.0 / x
    }
}

#[cfg(target_arch = "x86_64")]
mod simd {
    use super::*;
    use std::arch::x86_64::*;
    use std::mem::MaybeUninit;

    /// The ray as the box test wants it: 1/d, o/d broadcast, and which bound (min 0, max 3)
    /// is the near plane per axis.
    struct RaySetup {
        inv: [__m256; 3],
        org_inv: [__m256; 3],
        near: [usize; 3],
        far: [usize; 3],
    }

    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn setup(o: Vec3, d: Vec3) -> RaySetup {
        // `safe_rcp` on all three components at once (the same values, bit for bit): 1/d, with
        // |d| < 1e-30 replaced by ±1e30 (+ for ±0), so slab distances are never NaN.
        let dv = _mm_set_ps(0.0, d.z, d.y, d.x);
        let tiny = _mm_cmplt_ps(_mm_andnot_ps(_mm_set1_ps(-0.0), dv), _mm_set1_ps(1e-30));
        let big = _mm_blendv_ps(
            _mm_set1_ps(1e30),
            _mm_set1_ps(-1e30),
            _mm_cmplt_ps(dv, _mm_setzero_ps()),
        );
        let inv = _mm_blendv_ps(_mm_div_ps(_mm_set1_ps(1.0), dv), big, tiny);
        let org_inv = _mm_mul_ps(_mm_set_ps(0.0, o.z, o.y, o.x), inv);
        let neg = _mm_movemask_ps(_mm_cmplt_ps(inv, _mm_setzero_ps())) as usize;
        let mut near = [0; 3];
        let mut far = [0; 3];
        for a in 0..3 {
            let n = (neg >> a) & 1;
            near[a] = a + 3 * n;
            far[a] = a + 3 * (1 - n);
        }
        let b = |v: __m128| {
            [
                _mm256_broadcastss_ps(v),
                _mm256_broadcastss_ps(_mm_shuffle_ps::<0b01_01_01_01>(v, v)),
                _mm256_broadcastss_ps(_mm_shuffle_ps::<0b10_10_10_10>(v, v)),
            ]
        };
        RaySetup {
            inv: b(inv),
            org_inv: b(org_inv),
            near,
            far,
        }
    }

    /// The setup's 1/d, for the test against `safe_rcp`.
    #[cfg(test)]
    #[target_feature(enable = "avx2,fma")]
    pub(super) fn setup_inv(o: Vec3, d: Vec3) -> Vec3 {
        let r = setup(o, d);
        Vec3::new(
            _mm256_cvtss_f32(r.inv[0]),
            _mm256_cvtss_f32(r.inv[1]),
            _mm256_cvtss_f32(r.inv[2]),
        )
    }

    /// Slab test of the eight child boxes: the entry distances and the boxes entered within
    /// (tmin, tmax), as a lane mask vector and as bits.
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn boxes(n: &Node8, r: &RaySetup, tmin: __m256, tmax: __m256) -> (__m256, __m256, u32) {
        unsafe {
            let b = &n.bounds;
            let t = |plane: usize, a: usize| {
                _mm256_fmsub_ps(_mm256_load_ps(b[plane].as_ptr()), r.inv[a], r.org_inv[a])
            };
            let tn = _mm256_max_ps(
                _mm256_max_ps(t(r.near[0], 0), t(r.near[1], 1)),
                _mm256_max_ps(t(r.near[2], 2), tmin),
            );
            // Near and far planes go through the same arithmetic, so a flat box (a wall's) is
            // entered exactly where it is left; scaling the far distance up afterwards keeps
            // a grazing ray from being lost to rounding.
            let tf = _mm256_min_ps(
                _mm256_min_ps(t(r.far[0], 0), t(r.far[1], 1)),
                _mm256_min_ps(t(r.far[2], 2), tmax),
            );
            let tf = _mm256_mul_ps(tf, _mm256_set1_ps(FAR_SCALE));
            let entered = _mm256_cmp_ps::<_CMP_LE_OQ>(tn, tf);
            (tn, entered, _mm256_movemask_ps(entered) as u32)
        }
    }

    /// Möller–Trumbore on four triangles at once, as `LeafTri::intersect` computes it: the
    /// hit distance per lane, +inf where missed or outside (tmin, tmax).
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn leaf(l: &Tri4, o: [__m128; 3], d: [__m128; 3], tmin: f32, tmax: f32) -> __m128 {
        unsafe {
            let ld = |a: &[f32; 4]| _mm_load_ps(a.as_ptr());
            let (mul, sub, add) = (
                |a, b| _mm_mul_ps(a, b),
                |a, b| _mm_sub_ps(a, b),
                |a, b| _mm_add_ps(a, b),
            );
            let cross = |a: [__m128; 3], b: [__m128; 3]| {
                [
                    sub(mul(a[1], b[2]), mul(b[1], a[2])),
                    sub(mul(a[2], b[0]), mul(b[2], a[0])),
                    sub(mul(a[0], b[1]), mul(b[0], a[1])),
                ]
            };
            let dot = |a: [__m128; 3], b: [__m128; 3]| {
                add(add(mul(a[0], b[0]), mul(a[1], b[1])), mul(a[2], b[2]))
            };
            let v0 = [ld(&l.v0[0]), ld(&l.v0[1]), ld(&l.v0[2])];
            let e1 = [ld(&l.e1[0]), ld(&l.e1[1]), ld(&l.e1[2])];
            let e2 = [ld(&l.e2[0]), ld(&l.e2[1]), ld(&l.e2[2])];
            let p = cross(d, e2);
            let det = dot(e1, p);
            let inv = _mm_div_ps(_mm_set1_ps(1.0), det);
            let s = [sub(o[0], v0[0]), sub(o[1], v0[1]), sub(o[2], v0[2])];
            let u = mul(dot(s, p), inv);
            let q = cross(s, e1);
            let v = mul(dot(d, q), inv);
            let t = mul(dot(e2, q), inv);
            let lo = _mm_set1_ps(-super::super::BARY_EPS);
            let ok = _mm_and_ps(
                _mm_and_ps(
                    _mm_cmpneq_ps(det, _mm_setzero_ps()),
                    _mm_and_ps(_mm_cmpge_ps(u, lo), _mm_cmpge_ps(v, lo)),
                ),
                _mm_and_ps(
                    _mm_cmple_ps(add(u, v), _mm_set1_ps(1.0 + super::super::BARY_EPS)),
                    _mm_and_ps(
                        _mm_cmpgt_ps(t, _mm_set1_ps(tmin)),
                        _mm_cmplt_ps(t, _mm_set1_ps(tmax)),
                    ),
                ),
            );
            _mm_blendv_ps(_mm_set1_ps(f32::INFINITY), t, ok)
        }
    }

    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn splat3(v: Vec3) -> [__m128; 3] {
        [_mm_set1_ps(v.x), _mm_set1_ps(v.y), _mm_set1_ps(v.z)]
    }

    /// A walk's per-ray constants: the box test's setup, and o and d for the leaf test.
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn start(o: Vec3, d: Vec3) -> (RaySetup, [__m128; 3], [__m128; 3]) {
        (setup(o, d), splat3(o), splat3(d))
    }

    /// A finished walk's result: its closest hit, if it found a triangle.
    #[inline]
    fn found(t: f32, best: u32) -> Option<Hit> {
        (best != u32::MAX).then_some(Hit { t, tri: best })
    }

    /// One step of a closest-hit walk: visits the node or leaf `$code` and picks the next;
    /// `false` when the walk is over. Of the children a ray enters, the nearest is visited
    /// next; the others are pushed with their entry distance, unsorted (one table permutation
    /// compresses them into a vector stored onto the stack), and skipped when popped beyond
    /// the closest hit `$tmax`. Sorting them by distance (an insertion sort) cost more in
    /// mispredicted branches than the better pop order saved: incoherent rays on fipt-room,
    /// 1 thread, 12.7–13.1 → 14.8–15.8 M rays/s.
    ///
    /// A macro over plain locals, not a method on a struct: a `#[target_feature]` function
    /// cannot be `#[inline(always)]`, and state kept in a struct goes through memory on every
    /// step; either costs 10–20 % of the throughput.
    macro_rules! step {
        ($bvh:expr, $r:expr, $o4:expr, $d4:expr, $tmin:expr, $tmax:ident, $best:ident,
         $code:ident, $sp:ident, $sc:expr, $st:expr) => {
            'step: {
                #[allow(unused_unsafe)]
                // SAFETY: node and leaf codes come from the tree built with them; the stack holds
                // at most 7 entries per level (`fits_stack`); AVX2 and FMA were checked.
                unsafe {
                    let (sc, st): (*mut u32, *mut f32) = ($sc, $st);
                    if $code & LEAF == 0 {
                        let n = $bvh.nodes.get_unchecked($code as usize);
                        let (tn, entered, mask) =
                            boxes(n, &$r, _mm256_set1_ps($tmin), _mm256_set1_ps($tmax));
                        if mask != 0 {
                            if mask & (mask - 1) == 0 {
                                $code = n.child[mask.trailing_zeros() as usize];
                                break 'step true;
                            }
                            // The nearest entered child goes on; the others are pushed in
                            // lane order, compressed by a table permutation (no sorting, no
                            // loop over them).
                            let d = _mm256_blendv_ps(_mm256_set1_ps(f32::INFINITY), tn, entered);
                            let m1 = _mm256_min_ps(d, _mm256_permute_ps::<0b10_11_00_01>(d));
                            let m2 = _mm256_min_ps(m1, _mm256_permute_ps::<0b01_00_11_10>(m1));
                            let m3 = _mm256_min_ps(m2, _mm256_permute2f128_ps::<1>(m2, m2));
                            let near = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_EQ_OQ>(d, m3))
                                as u32
                                & mask;
                            let j = near.trailing_zeros() as usize;
                            let rest = mask & !(1u32 << j);
                            let perm = compress(rest);
                            push_children(n, perm, sc.add($sp));
                            _mm256_storeu_ps(st.add($sp), _mm256_permutevar8x32_ps(tn, perm));
                            $sp += rest.count_ones() as usize;
                            $code = n.child[j];
                            break 'step true;
                        }
                    } else {
                        let l = $bvh.leaves.get_unchecked(($code & !LEAF) as usize);
                        // Once a hit is found, triangles at its distance count too (the
                        // leaf test's bound is exclusive), for the tie rule below.
                        let bound = if $best == u32::MAX {
                            $tmax
                        } else {
                            $tmax.next_up()
                        };
                        let t = leaf(l, $o4, $d4, $tmin, bound);
                        // The nearest lane, without a loop over lanes; of equals the first,
                        // which holds the lowest triangle index (a block's triangles are in
                        // index order).
                        let m = _mm_min_ps(t, _mm_shuffle_ps::<0b10_11_00_01>(t, t));
                        let m = _mm_min_ps(m, _mm_shuffle_ps::<0b01_00_11_10>(m, m));
                        let near = _mm_cvtss_f32(m);
                        if near <= $tmax {
                            let j = _mm_movemask_ps(_mm_cmpeq_ps(t, m)).trailing_zeros();
                            let p = l.prim[j as usize];
                            // A tie with the closest hit so far goes to the lower triangle
                            // index, so the answer does not depend on the order of the walk.
                            // (`near == $tmax` with no hit yet is the bound itself: a miss.)
                            if near < $tmax || ($best != u32::MAX && p < $best) {
                                $tmax = near;
                                $best = p;
                            }
                        }
                    }
                    // Pop the nearest pending child still in front of the closest hit.
                    while $sp > 0 {
                        $sp -= 1;
                        if *st.add($sp) <= $tmax * FAR_SCALE {
                            $code = *sc.add($sp);
                            break 'step true;
                        }
                    }
                    false
                }
            }
        };
    }

    /// Per 8-bit lane mask, the lane indices of its set bits in increasing order (the rest 0):
    /// the permutation that compresses those lanes to the front of a vector.
    #[repr(C, align(32))]
    struct Compress([[u32; 8]; 256]);

    static COMPRESS: Compress = {
        let mut t = [[0u32; 8]; 256];
        let mut m = 0;
        while m < 256 {
            let (mut k, mut lane) = (0, 0);
            while lane < 8 {
                if m & (1 << lane) != 0 {
                    t[m][k] = lane as u32;
                    k += 1;
                }
                lane += 1;
            }
            m += 1;
        }
        Compress(t)
    };

    /// The permutation that moves the lanes set in `lanes` (8 bits) to the front, in order.
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn compress(lanes: u32) -> __m256i {
        // SAFETY: `lanes` < 256 indexes the table; its rows are 32-byte aligned.
        unsafe {
            _mm256_load_si256(COMPRESS.0.get_unchecked(lanes as usize).as_ptr() as *const __m256i)
        }
    }

    /// Stores `n`'s child codes permuted by `perm` (`compress`) at `dst`: all eight lanes,
    /// of which the caller counts the ones it pushed.
    ///
    /// # Safety
    /// `dst` must have room for eight codes.
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn push_children(n: &Node8, perm: __m256i, dst: *mut u32) {
        unsafe {
            let codes = _mm256_loadu_si256(n.child.as_ptr() as *const __m256i);
            _mm256_storeu_si256(
                dst as *mut __m256i,
                _mm256_permutevar8x32_epi32(codes, perm),
            );
        }
    }

    /// A traversal stack (uninitialised: zeroing 1 KiB per ray costs more than a short walk),
    /// with room for a push's eight lanes beyond `STACK`.
    struct Stack {
        code: MaybeUninit<[u32; STACK + 8]>,
        t: MaybeUninit<[f32; STACK + 8]>,
    }

    impl Stack {
        fn new() -> Self {
            Stack {
                code: MaybeUninit::uninit(),
                t: MaybeUninit::uninit(),
            }
        }

        fn ptrs(&mut self) -> (*mut u32, *mut f32) {
            (
                self.code.as_mut_ptr() as *mut u32,
                self.t.as_mut_ptr() as *mut f32,
            )
        }
    }

    /// Closest hit of one ray.
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn closest(
        bvh: &Bvh8,
        o: Vec3,
        d: Vec3,
        tmin: f32,
        mut tmax: f32,
    ) -> Option<Hit> {
        if bvh.nodes.is_empty() {
            return None;
        }
        let (r, o4, d4) = start(o, d);
        let mut stack = Stack::new();
        let (sc, st) = stack.ptrs();
        let (mut best, mut code, mut sp) = (u32::MAX, 0u32, 0usize);
        while step!(bvh, r, o4, d4, tmin, tmax, best, code, sp, sc, st) {}
        found(tmax, best)
    }

    /// Closest hits of many rays, two walks interleaved step by step so that one ray's memory
    /// latency overlaps the other's work; a finished walk takes the next ray. Each ray's
    /// result is the one `closest` gives.
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn closest_many(
        bvh: &Bvh8,
        rays: &[(Vec3, Vec3)],
        tmin: f32,
        tmax: f32,
        out: &mut [Option<Hit>],
    ) {
        let n = rays.len();
        if bvh.nodes.is_empty() || n < 2 {
            for (h, &(o, d)) in out.iter_mut().zip(rays) {
                *h = unsafe { closest(bvh, o, d, tmin, tmax) };
            }
            return;
        }
        let (mut sa, mut sb) = (Stack::new(), Stack::new());
        let ((sca, sta), (scb, stb)) = (sa.ptrs(), sb.ptrs());
        let (mut ia, mut ib, mut next) = (0, 1, 2);
        let (mut ra, mut oa, mut da) = start(rays[0].0, rays[0].1);
        let (mut rb, mut ob, mut db) = start(rays[1].0, rays[1].1);
        let (mut ta, mut ba, mut ca, mut pa) = (tmax, u32::MAX, 0u32, 0usize);
        let (mut tb, mut bb, mut cb, mut pb) = (tmax, u32::MAX, 0u32, 0usize);
        loop {
            let more_a = step!(bvh, ra, oa, da, tmin, ta, ba, ca, pa, sca, sta);
            let more_b = step!(bvh, rb, ob, db, tmin, tb, bb, cb, pb, scb, stb);
            if !more_a {
                out[ia] = found(ta, ba);
                if next == n {
                    while step!(bvh, rb, ob, db, tmin, tb, bb, cb, pb, scb, stb) {}
                    out[ib] = found(tb, bb);
                    return;
                }
                let (o, d) = rays[next];
                (ia, (ra, oa, da)) = (next, start(o, d));
                (ta, ba, ca, pa) = (tmax, u32::MAX, 0, 0);
                next += 1;
            }
            if !more_b {
                out[ib] = found(tb, bb);
                if next == n {
                    while step!(bvh, ra, oa, da, tmin, ta, ba, ca, pa, sca, sta) {}
                    out[ia] = found(ta, ba);
                    return;
                }
                let (o, d) = rays[next];
                (ib, (rb, ob, db)) = (next, start(o, d));
                (tb, bb, cb, pb) = (tmax, u32::MAX, 0, 0);
                next += 1;
            }
        }
    }

    /// Any-hit traversal: stops at the first triangle hit.
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn occluded(bvh: &Bvh8, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> bool {
        if bvh.nodes.is_empty() {
            return false;
        }
        unsafe {
            let (r, o4, d4) = start(o, d);
            let (tmin8, tmax8) = (_mm256_set1_ps(tmin), _mm256_set1_ps(tmax));
            let mut stack = MaybeUninit::<[u32; STACK + 8]>::uninit();
            let stack = stack.as_mut_ptr() as *mut u32;
            let mut sp = 0usize;
            let mut code = 0u32;
            loop {
                if code & LEAF == 0 {
                    let n = bvh.nodes.get_unchecked(code as usize);
                    let (_, _, mask) = boxes(n, &r, tmin8, tmax8);
                    if mask != 0 {
                        // The first entered child goes on, the others are pushed compressed.
                        code = n.child[mask.trailing_zeros() as usize];
                        let rest = mask & (mask - 1);
                        push_children(n, compress(rest), stack.add(sp));
                        sp += rest.count_ones() as usize;
                        continue;
                    }
                } else {
                    let l = bvh.leaves.get_unchecked((code & !LEAF) as usize);
                    let t = leaf(l, o4, d4, tmin, tmax);
                    if _mm_movemask_ps(_mm_cmplt_ps(t, _mm_set1_ps(tmax))) != 0 {
                        return true;
                    }
                }
                if sp == 0 {
                    return false;
                }
                sp -= 1;
                code = *stack.add(sp);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The vectorised ray setup's 1/d is `safe_rcp` bit for bit, on the values where it
    /// matters: ±0, denormals, the ±1e-30 boundary and ordinary values.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn setup_reciprocal_is_safe_rcp() {
        if !Bvh8::supported() {
            return;
        }
        let vals = [
            0.0f32, -0.0, 1e-40, -1e-40, 1e-30, -1e-30, 9.9e-31, -9.9e-31, 0.3, -0.7, 1.0, -1.0,
        ];
        for &x in &vals {
            for &y in &vals {
                let d = Vec3::new(x, y, 0.5);
                // SAFETY: AVX2 and FMA were checked above.
                let inv = unsafe { simd::setup_inv(Vec3::ZERO, d) };
                for a in 0..3 {
                    assert_eq!(inv[a].to_bits(), safe_rcp(d[a]).to_bits(), "{d} axis {a}");
                }
            }
        }
    }
}
