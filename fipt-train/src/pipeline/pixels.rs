//! The stage-2 pixel store (paper §4.5): every training pixel with a first hit (less those a
//! refined round leaves out next to the emitters), as plain arrays of unit-cube and world
//! positions, packed shadings, photo values and segment ids; batches are gathered from it by
//! index.
//!
//! Owns: the store, the segmentation map choice, the pixel footprint, the pixels next to the
//! emitters. Must not touch: training.

use super::bake::Baked;
use fipt_bake::{Accel, ViewHits};
use fipt_core::model::step::CAP_NONE;
use fipt_core::model::step::SegMode;
use fipt_core::model::{Batch, PartMap};
use fipt_core::scene::{Camera, MapKind, SceneBox, Split};
use fipt_core::shading::ShadingLayout;
use rayon::prelude::*;

/// Every training pixel whose pixel-centre ray hit the mesh (less those `retain` removed), as
/// one big `Batch`.
pub struct PixelStore {
    pub pixels: Batch,
    /// (view, pixel) of each entry.
    pub origin: Vec<(u32, u32)>,
    /// The triangle each entry's pixel-centre ray hit.
    pub tri: Vec<u32>,
}

/// The part offsets' map (`train.part_offsets`, on with a segmentation loss): the rows of the
/// majority labels of the triangles `store` hit, taken from the store as gathered (before any
/// pixel leaves it), so that a resumed run makes the same map. Off: a map without parts.
pub fn part_map(store: &PixelStore, num_triangles: usize, on: bool, mode: SegMode) -> PartMap {
    if !on || mode == SegMode::None {
        return PartMap::default();
    }
    PartMap::from_labels(&store.triangle_labels(num_triangles))
}

/// Which label map feeds the segmentation loss.
pub fn seg_map(mode: SegMode) -> Option<MapKind> {
    match mode {
        SegMode::Part => Some(MapKind::IndexMA),
        SegMode::Semantic => Some(MapKind::Segmentation),
        SegMode::None => None,
    }
}

impl PixelStore {
    pub fn gather(train: &Split, baked: &Baked, sb: &SceneBox, mode: SegMode) -> Self {
        let mut b = Batch::default();
        let mut origin = Vec::new();
        let mut tri = Vec::new();
        let labels: Vec<Option<Vec<i32>>> = train
            .views
            .iter()
            .map(|v| seg_map(mode).and_then(|k| v.labels(k)))
            .collect();
        for (k, (v, h)) in train.views.iter().zip(&baked.hits).enumerate() {
            let s = &baked.shadings[k];
            for p in 0..h.num_pixels() {
                if h.tri[p] < 0 {
                    continue;
                }
                let x = h.position[p];
                b.x_unit.push(sb.to_unit(x).to_array());
                b.x_world.push(x.to_array());
                b.shadings.extend_from_slice(ShadingLayout::pixel(s, p));
                b.gt.extend_from_slice(&v.image.data[3 * p..3 * p + 3]);
                b.seg.push(labels[k].as_ref().map_or(0, |l| l[p]));
                if let Some(f) = &v.ldr {
                    for c in 0..3 {
                        b.cap.push(if f.clipped(p, c) && !f.is_filled(p) {
                            v.image.data[3 * p + c]
                        } else {
                            CAP_NONE
                        });
                    }
                }
                origin.push((k as u32, p as u32));
                tri.push(h.tri[p] as u32);
            }
        }
        Self {
            pixels: b,
            origin,
            tri,
        }
    }

    /// Per triangle of a mesh of `num_triangles`, the majority segment label of the entries
    /// that hit it (`segfuse`'s rule; −1 where none did).
    pub fn triangle_labels(&self, num_triangles: usize) -> Vec<i32> {
        let votes = self
            .tri
            .iter()
            .copied()
            .zip(self.pixels.seg.iter().copied());
        fipt_bake::segfuse::fuse_votes(num_triangles, votes)
    }

    /// Sets every entry's part-offset row (`Batch::part`) from its triangle's row in `map`
    /// (a map without parts: none).
    pub fn set_parts(&mut self, map: &PartMap) {
        self.pixels.part = if map.parts > 0 {
            map.rows(&self.tri)
        } else {
            Vec::new()
        };
    }

    pub fn len(&self) -> usize {
        self.origin.len()
    }

    pub fn is_empty(&self) -> bool {
        self.origin.is_empty()
    }

    /// Replaces every entry's shadings by those of its (view, pixel) in `per_view`
    /// (`ShadingLayout::DIM` values per pixel, per view), e.g. after a refinement.
    pub fn set_shadings(&mut self, per_view: &[Vec<f32>]) {
        let d = ShadingLayout::DIM;
        for (i, &(k, p)) in self.origin.iter().enumerate() {
            self.pixels.shadings[i * d..(i + 1) * d]
                .copy_from_slice(ShadingLayout::pixel(&per_view[k as usize], p as usize));
        }
    }

    /// Keeps the entries whose (view, pixel) `keep` accepts, in order; returns how many went.
    pub fn retain(&mut self, keep: impl Fn(u32, u32) -> bool) -> usize {
        let d = ShadingLayout::DIM;
        let b = &mut self.pixels;
        let caps = !b.cap.is_empty();
        let mut n = 0;
        for i in 0..self.origin.len() {
            let (k, p) = self.origin[i];
            if !keep(k, p) {
                continue;
            }
            self.origin[n] = (k, p);
            self.tri[n] = self.tri[i];
            if !b.part.is_empty() {
                b.part[n] = b.part[i];
            }
            b.x_unit[n] = b.x_unit[i];
            b.x_world[n] = b.x_world[i];
            b.shadings.copy_within(i * d..(i + 1) * d, n * d);
            b.gt.copy_within(3 * i..3 * i + 3, 3 * n);
            b.seg[n] = b.seg[i];
            if caps {
                b.cap.copy_within(3 * i..3 * i + 3, 3 * n);
            }
            n += 1;
        }
        let gone = self.origin.len() - n;
        self.origin.truncate(n);
        self.tri.truncate(n);
        if !b.part.is_empty() {
            b.part.truncate(n);
        }
        b.x_unit.truncate(n);
        b.x_world.truncate(n);
        b.shadings.truncate(n * d);
        b.gt.truncate(3 * n);
        b.seg.truncate(n);
        if caps {
            b.cap.truncate(3 * n);
        }
        gone
    }

    /// The batch of the given entries, gathered in parallel (a step's batch reads scattered
    /// entries of a store of millions).
    pub fn batch(&self, idx: &[u32]) -> Batch {
        let b = &self.pixels;
        let at = |i: &u32| *i as usize;
        /// `width` values per entry of `src`, gathered at `idx`.
        fn rows<T: Copy + Default + Send + Sync>(src: &[T], idx: &[u32], width: usize) -> Vec<T> {
            let mut out = vec![T::default(); idx.len() * width];
            out.par_chunks_mut(width * 256)
                .zip(idx.par_chunks(256))
                .for_each(|(o, ix)| {
                    for (row, &i) in o.chunks_exact_mut(width).zip(ix) {
                        let i = i as usize;
                        row.copy_from_slice(&src[width * i..width * (i + 1)]);
                    }
                });
            out
        }
        Batch {
            x_unit: idx.par_iter().map(|i| b.x_unit[at(i)]).collect(),
            x_world: idx.par_iter().map(|i| b.x_world[at(i)]).collect(),
            shadings: rows(&b.shadings, idx, ShadingLayout::DIM),
            gt: rows(&b.gt, idx, 3),
            seg: idx.par_iter().map(|i| b.seg[at(i)]).collect(),
            cap: if b.cap.is_empty() {
                Vec::new()
            } else {
                rows(&b.cap, idx, 3)
            },
            part: if b.part.is_empty() {
                Vec::new()
            } else {
                idx.par_iter().map(|i| b.part[at(i)]).collect()
            },
        }
    }
}

/// Per view, the pixels within `margin` pixels (the 8-neighbourhood, repeated) of a pixel whose
/// centre ray hit an emitter triangle (`is_emitter`), not on one themselves. Their footprint
/// takes in part of the emitter, so they are far brighter than the surface their centre hits:
/// a lobe of that surface would have to explain them.
pub fn near_emitters(
    hits: &[ViewHits],
    is_emitter: impl Fn(i32) -> bool,
    margin: usize,
) -> Vec<Vec<bool>> {
    emitter_masks(hits, is_emitter, margin, false)
}

/// Per view, the pixels whose centre ray hit an emitter triangle (`is_emitter`) and those
/// within `margin` pixels of one (`near_emitters`).
pub fn on_or_near_emitters(
    hits: &[ViewHits],
    is_emitter: impl Fn(i32) -> bool,
    margin: usize,
) -> Vec<Vec<bool>> {
    emitter_masks(hits, is_emitter, margin, true)
}

/// Per view, the pixels that the fits on refined shadings leave out: those within `margin`
/// pixels of one whose centre ray hits an emitter (`refine.emitter_margin`), and, unless
/// `keep_on` (`refine.emitter_pixels`), those themselves. None when none leave.
pub fn left_out_of_refined_fits(
    hits: &[ViewHits],
    is_emitter: impl Fn(i32) -> bool,
    margin: usize,
    keep_on: bool,
) -> Option<Vec<Vec<bool>>> {
    (margin > 0 || !keep_on).then(|| emitter_masks(hits, is_emitter, margin, !keep_on))
}

/// The ring of `margin` pixels around the emitter pixels of each view, with the emitter pixels
/// themselves where `with_on`.
fn emitter_masks(
    hits: &[ViewHits],
    is_emitter: impl Fn(i32) -> bool,
    margin: usize,
    with_on: bool,
) -> Vec<Vec<bool>> {
    hits.iter()
        .map(|h| {
            let on: Vec<bool> = h.tri.iter().map(|&t| t >= 0 && is_emitter(t)).collect();
            let ring = ring_around(&on, h.width, margin);
            if with_on {
                on.iter().zip(ring).map(|(a, b)| *a || b).collect()
            } else {
                ring
            }
        })
        .collect()
}

/// The pixels of a `width`-wide image within `margin` pixels (Chebyshev distance) of one that
/// is `on`, not `on` themselves.
pub fn ring_around(on: &[bool], width: usize, margin: usize) -> Vec<bool> {
    debug_assert!(width > 0 && on.len().is_multiple_of(width));
    let height = on.len() / width;
    let mut near = vec![false; on.len()];
    let m = margin as isize;
    for (p, _) in on.iter().enumerate().filter(|(_, e)| **e) {
        let (x, y) = ((p % width) as isize, (p / width) as isize);
        for yy in (y - m).max(0)..=(y + m).min(height as isize - 1) {
            for xx in (x - m).max(0)..=(x + m).min(width as isize - 1) {
                near[yy as usize * width + xx as usize] = true;
            }
        }
    }
    near.iter().zip(on).map(|(n, e)| *n && !e).collect()
}

/// Points per side of the grid `coverage` casts inside a pixel.
const COVER_GRID: usize = 4;

/// What counts as the surface a pixel's centre ray hits, for `coverage`: the triangles with
/// its key (a part label, or a plane), and with `crease` also a unit normal within that angle
/// of the centre triangle's (two faces of one box are then two surfaces, a finely tessellated
/// curved part one).
pub struct CoverKeys {
    keys: Vec<u64>,
    /// Per triangle its unit normal, and the cosine of the crease angle (None: keys alone).
    crease: Option<(Vec<glam::Vec3>, f32)>,
}

impl CoverKeys {
    /// Keys alone.
    pub fn keys(keys: Vec<u64>) -> Self {
        Self { keys, crease: None }
    }

    /// Keys, and the normals of `mesh`'s triangles within `degrees` of each other where
    /// `degrees` < 180 (`train.coverage_crease`).
    pub fn with_crease(keys: Vec<u64>, mesh: &fipt_core::scene::Mesh, degrees: f32) -> Self {
        let crease = (degrees < 180.0).then(|| {
            let normals = (0..mesh.num_triangles()).map(|t| mesh.normal(t)).collect();
            (normals, degrees.to_radians().cos())
        });
        Self { keys, crease }
    }

    /// Whether triangle `t` belongs to the surface of the centre's triangle `c`.
    fn same(&self, c: usize, t: usize) -> bool {
        self.keys[c] == self.keys[t]
            && self
                .crease
                .as_ref()
                .is_none_or(|(n, cos)| n[c].dot(n[t]) >= *cos)
    }
}

/// Per view and pixel, the share of the pixel's square that the surface its centre ray hits
/// covers: the share of a 4×4 grid of points inside the pixel whose rays hit a triangle of the
/// centre triangle's surface (`CoverKeys`). A photo's pixel is the mean over its square (a box
/// filter) while the fit reads the surface at its centre, so a pixel split between two parts,
/// or two faces of one, mixes a second reflection into the first one's data. Pixels whose 3×3
/// neighbourhood of centre rays hits the centre's surface only are covered whole without
/// casting; a pixel whose centre ray misses covers 0.
pub fn coverage<'a>(
    accel: &Accel,
    cams: impl IntoIterator<Item = &'a Camera>,
    hits: &[ViewHits],
    keys: &CoverKeys,
) -> Vec<Vec<f32>> {
    let n = COVER_GRID;
    cams.into_iter()
        .zip(hits)
        .map(|(cam, h)| {
            let (w, ht) = (h.width, h.height);
            (0..w * ht)
                .into_par_iter()
                .map(|p| {
                    let Ok(c) = usize::try_from(h.tri[p]) else {
                        return 0.0;
                    };
                    let on = |t: i32| usize::try_from(t).is_ok_and(|t| keys.same(c, t));
                    let (x, y) = (p % w, p / w);
                    let whole = (y.saturating_sub(1)..(y + 2).min(ht)).all(|yy| {
                        (x.saturating_sub(1)..(x + 2).min(w)).all(|xx| on(h.tri[yy * w + xx]))
                    });
                    if whole {
                        return 1.0;
                    }
                    let rays = cam.grid_rays(x, y, n);
                    let mut sub = vec![None; rays.len()];
                    accel.closest_many(&rays, 0.0, f32::INFINITY, &mut sub);
                    let same = sub
                        .iter()
                        .filter(|hit| hit.is_some_and(|x| keys.same(c, x.tri as usize)))
                        .count();
                    same as f32 / (n * n) as f32
                })
                .collect()
        })
        .collect()
}

/// The median pixel footprint of the training views in unit-cube units: over every hit, the
/// hit distance times the angle one pixel subtends (1/f_x), divided by the scene box's side.
pub fn pixel_footprint(train: &Split, hits: &[ViewHits], sb: &SceneBox) -> f64 {
    let mut f: Vec<f32> = train
        .views
        .iter()
        .zip(hits)
        .flat_map(|(v, h)| {
            let k = (1.0 / v.camera.fx) as f32;
            h.t.iter()
                .zip(&h.tri)
                .filter(|(_, tri)| **tri >= 0)
                .map(move |(t, _)| t * k)
        })
        .collect();
    if f.is_empty() {
        return 1.0;
    }
    let mid = f.len() / 2;
    let (_, m, _) = f.select_nth_unstable_by(mid, f32::total_cmp);
    *m as f64 / (sb.max - sb.min) as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    /// A view of `w`×`h` pixels whose centre rays hit the triangles `tri` (−1: a miss).
    fn view(w: usize, h: usize, tri: Vec<i32>) -> ViewHits {
        let n = w * h;
        ViewHits {
            width: w,
            height: h,
            origin: Vec3::ZERO,
            direction: vec![Vec3::Z; n],
            t: vec![1.0; n],
            tri,
            position: vec![Vec3::ZERO; n],
            normal: vec![Vec3::Z; n],
        }
    }

    /// The refined fits leave out the ring, the emitter pixels with it unless they are kept,
    /// and nothing with no margin and the emitter pixels kept.
    #[test]
    fn refined_fits_leave_out_the_ring_and_the_emitters_unless_kept() {
        let (w, h) = (5, 3);
        let mut tri = vec![1; w * h];
        tri[w + 2] = 9;
        let v = vec![view(w, h, tri)];
        let out = |m, keep| left_out_of_refined_fits(&v, |t| t == 9, m, keep);
        assert!(out(0, true).is_none());
        let count = |x: Option<Vec<Vec<bool>>>| x.unwrap()[0].iter().filter(|b| **b).count();
        assert_eq!(count(out(0, false)), 1);
        assert_eq!(count(out(1, true)), 8);
        let both = out(1, false).unwrap();
        assert_eq!(both[0].iter().filter(|b| **b).count(), 9);
        assert!(both[0][w + 2] && both[0][1] && !both[0][0] && !both[0][4]);
    }

    #[test]
    fn near_emitters_is_the_ring_around_the_emitter_pixels() {
        // 7×5 pixels of triangle 1; triangle 9 (the emitter) at (3, 2) and at the corner (0, 0).
        let (w, h) = (7, 5);
        let mut tri = vec![1; w * h];
        tri[2 * w + 3] = 9;
        tri[0] = 9;
        tri[4 * w + 6] = -1;
        let v = vec![view(w, h, tri.clone()), view(w, h, vec![1; w * h])];
        let near = |m| near_emitters(&v, |t| t == 9, m);
        let ring = |m: usize| -> Vec<bool> {
            (0..w * h)
                .map(|p| {
                    let (x, y) = ((p % w) as isize, (p / w) as isize);
                    let cheb = |cx: isize, cy: isize| (x - cx).abs().max((y - cy).abs());
                    let d = cheb(3, 2).min(cheb(0, 0));
                    tri[p] != 9 && d <= m as isize
                })
                .collect()
        };
        for m in 0..4 {
            let n = near(m);
            assert_eq!(n[0], ring(m), "margin {m}");
            assert!(
                n[1].iter().all(|b| !b),
                "a view without emitters loses nothing"
            );
        }
        // The counts: 8 around the inner pixel and 3 at the corner for one pixel of margin.
        assert_eq!(near(1)[0].iter().filter(|b| **b).count(), 8 + 3);
        assert!(near(0)[0].iter().all(|b| !b));
        // With the emitter pixels themselves: the ring and the two pixels.
        for m in 0..4 {
            let both = on_or_near_emitters(&v, |t| t == 9, m);
            let want: Vec<bool> = ring(m)
                .iter()
                .zip(&tri)
                .map(|(r, &t)| *r || t == 9)
                .collect();
            assert_eq!(both[0], want, "margin {m}");
            assert!(both[1].iter().all(|b| !b));
        }
    }

    /// `n` entries whose values are made of their index i: positions (i, i + 0.1, i + 0.2) and
    /// (−i, 2i, 3i), shadings 100 i + j, ground truth (i, 2i, 3i), segment i mod 3, clip levels
    /// (i, none, i + 0.5).
    fn numbered_batch(n: usize) -> Batch {
        let mut b = Batch::default();
        for i in 0..n {
            let f = i as f32;
            b.x_unit.push([f, f + 0.1, f + 0.2]);
            b.x_world.push([-f, 2.0 * f, 3.0 * f]);
            b.shadings
                .extend((0..ShadingLayout::DIM).map(|j| f * 100.0 + j as f32));
            b.gt.extend([f, f * 2.0, f * 3.0]);
            b.seg.push(i as i32 % 3);
            b.cap.extend([f, CAP_NONE, f + 0.5]);
        }
        b
    }

    /// A batch of scattered entries, repeats included and longer than one parallel chunk,
    /// holds each entry's values in the order asked for, parts and clip levels included.
    #[test]
    fn batch_gathers_the_entries_in_the_order_asked() {
        let n = 700u32;
        let mut store = PixelStore {
            pixels: numbered_batch(n as usize),
            origin: (0..n).map(|i| (0, i)).collect(),
            tri: (0..n).collect(),
        };
        store.set_parts(&PartMap::from_labels(
            &(0..n as i32).map(|t| t % 4).collect::<Vec<_>>(),
        ));
        let idx: Vec<u32> = (0..900u32).map(|k| (k * 397 + 11) % n).collect();
        let got = store.batch(&idx);
        assert_eq!(got.len(), idx.len());
        for (k, &i) in idx.iter().enumerate() {
            let (i, f) = (i as usize, i as f32);
            assert_eq!(got.x_unit[k], [f, f + 0.1, f + 0.2], "entry {k}");
            assert_eq!(got.x_world[k], [-f, 2.0 * f, 3.0 * f]);
            assert_eq!(
                ShadingLayout::pixel(&got.shadings, k),
                ShadingLayout::pixel(&store.pixels.shadings, i)
            );
            assert_eq!(got.gt[3 * k..3 * k + 3], [f, 2.0 * f, 3.0 * f]);
            assert_eq!(got.seg[k], i as i32 % 3);
            assert_eq!(got.cap[3 * k..3 * k + 3], [f, CAP_NONE, f + 0.5]);
            assert_eq!(got.part[k], store.pixels.part[i]);
        }
        // Without clip levels or parts, the batch has none either.
        store.pixels.cap.clear();
        store.pixels.part.clear();
        let plain = store.batch(&idx);
        assert!(plain.cap.is_empty() && plain.part.is_empty());
        assert_eq!(plain.shadings, got.shadings);
    }

    #[test]
    fn retain_keeps_the_chosen_entries_whole_and_in_order() {
        let n = 10;
        let b = numbered_batch(n);
        let origin: Vec<(u32, u32)> = (0..n as u32).map(|i| (i % 2, i)).collect();
        let tri: Vec<u32> = (0..n as u32).map(|i| 3 * i).collect();
        let mut store = PixelStore {
            pixels: b,
            origin,
            tri,
        };
        store.set_parts(&PartMap::from_labels(
            &(0..3 * n as i32).map(|t| t % 4).collect::<Vec<_>>(),
        ));
        let keep = |k: u32, p: u32| k == 0 || p == 7;
        let kept: Vec<u32> = (0..n as u32).filter(|&i| keep(i % 2, i)).collect();
        let want = store.batch(&kept);
        assert_eq!(store.retain(keep), n - kept.len());
        assert_eq!(store.len(), kept.len());
        assert_eq!(
            store.origin,
            kept.iter().map(|&i| (i % 2, i)).collect::<Vec<_>>()
        );
        let got = &store.pixels;
        assert_eq!(got.x_unit, want.x_unit);
        assert_eq!(got.x_world, want.x_world);
        assert_eq!(got.shadings, want.shadings);
        assert_eq!(got.gt, want.gt);
        assert_eq!(got.part, want.part);
        assert_eq!(store.tri, kept.iter().map(|&i| 3 * i).collect::<Vec<_>>());
        assert_eq!(got.seg, want.seg);
        assert_eq!(got.cap, want.cap);
    }

    /// A strip 2.6 pixels wide in front of a wall, across the whole height of an 8-pixel-wide
    /// view: the pixels its edges split cover 3/4 of the wall side (the grid's share of the
    /// true 0.7), those whose centre it hits are covered whole, and with one key for both
    /// every pixel is whole.
    #[test]
    fn coverage_is_the_share_of_the_pixel_on_the_centres_part() {
        use glam::DVec3;
        let (w, h) = (8, 4);
        let cam = Camera::look_at_fov(DVec3::ZERO, DVec3::Z, DVec3::Y, 1.0, w, h);
        // Pixel columns [2.7, 5.3] at depth 5: half-width 1.3 pixels.
        let (zs, zw) = (5.0f32, 10.0f32);
        let hs = 1.3 * zs / cam.fx as f32;
        let quad = |x0: f32, x1: f32, z: f32, y: f32| {
            [
                Vec3::new(x0, -y, z),
                Vec3::new(x1, -y, z),
                Vec3::new(x1, y, z),
                Vec3::new(x0, y, z),
            ]
        };
        let mut vertices = quad(-20.0, 20.0, zw, 20.0).to_vec();
        vertices.extend(quad(-hs, hs, zs, 20.0));
        let mesh = fipt_core::scene::Mesh {
            vertices,
            triangles: vec![[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]],
        };
        let accel = Accel::build(&mesh);
        let hits = vec![fipt_bake::cast_view(&accel, &mesh, &cam)];
        let strip: Vec<bool> = hits[0].tri.iter().map(|&t| t >= 2).collect();
        assert_eq!(
            strip[..w],
            [false, false, false, true, true, false, false, false]
        );
        let cover = coverage(&accel, [&cam], &hits, &CoverKeys::keys(vec![0, 0, 1, 1]));
        let want = [1.0, 1.0, 0.75, 1.0, 1.0, 0.75, 1.0, 1.0];
        for y in 0..h {
            assert_eq!(cover[0][y * w..(y + 1) * w], want, "row {y}");
        }
        let one = coverage(&accel, [&cam], &hits, &CoverKeys::keys(vec![7; 4]));
        assert!(one[0].iter().all(|&c| c == 1.0));
        // The strip and the wall face the camera alike: one surface under any crease angle.
        let flat = coverage(
            &accel,
            [&cam],
            &hits,
            &CoverKeys::with_crease(vec![7; 4], &mesh, 30.0),
        );
        assert!(flat[0].iter().all(|&c| c == 1.0));
    }

    /// A ridge of one part, two faces at 90° meeting through the middle column of a 9-pixel-wide
    /// view: with a crease angle the middle column straddles two surfaces and covers half its
    /// square, every other pixel one face whole; without one, the part covers every pixel whole.
    #[test]
    fn a_crease_splits_one_part_into_its_faces() {
        use glam::DVec3;
        let (w, h) = (9, 3);
        let cam = Camera::look_at_fov(DVec3::ZERO, DVec3::Z, DVec3::Y, 1.0, w, h);
        // z = 10 + |x|: the ridge at x = 0 nearest the camera.
        let (x0, y0) = (20.0f32, 20.0f32);
        let vertices = vec![
            Vec3::new(-x0, -y0, 10.0 + x0),
            Vec3::new(0.0, -y0, 10.0),
            Vec3::new(0.0, y0, 10.0),
            Vec3::new(-x0, y0, 10.0 + x0),
            Vec3::new(x0, -y0, 10.0 + x0),
            Vec3::new(x0, y0, 10.0 + x0),
        ];
        let mesh = fipt_core::scene::Mesh {
            vertices,
            triangles: vec![[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2]],
        };
        let accel = Accel::build(&mesh);
        let hits = vec![fipt_bake::cast_view(&accel, &mesh, &cam)];
        let part = vec![3u64; 4];
        let whole = coverage(&accel, [&cam], &hits, &CoverKeys::keys(part.clone()));
        assert!(whole[0].iter().all(|&c| c == 1.0));
        let faces = coverage(
            &accel,
            [&cam],
            &hits,
            &CoverKeys::with_crease(part.clone(), &mesh, 30.0),
        );
        let want = [1.0, 1.0, 1.0, 1.0, 0.5, 1.0, 1.0, 1.0, 1.0];
        for y in 0..h {
            assert_eq!(faces[0][y * w..(y + 1) * w], want, "row {y}");
        }
        // 180°: no crease.
        let off = coverage(
            &accel,
            [&cam],
            &hits,
            &CoverKeys::with_crease(part, &mesh, 180.0),
        );
        assert_eq!(off, whole);
    }
}
