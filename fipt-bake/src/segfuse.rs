//! Segmentation fusion (reference §1.5, without its off-by-one): every triangle takes the
//! majority label of the pixels whose pixel-centre first hit it, over a set of label images;
//! per-view label maps are then re-rendered from the triangle labels by the same ray casts.
//!
//! Owns: per-triangle label votes and re-rendered label maps. Must not touch: file IO.

use crate::accel::raycast::ViewHits;
use std::collections::HashMap;

/// Label of a triangle no pixel voted for (and of missed pixels).
pub const UNLABELLED: i32 = -1;

/// Per-triangle majority vote. `labels[v]` is view v's row-major label map, `hits[v]` its ray
/// casts. Labels equal to `ignore` (e.g. 0 = unlabelled for Mask2Former output) do not vote.
/// Ties go to the smallest label. Triangles without votes get `UNLABELLED`.
pub fn fuse_labels(
    num_triangles: usize,
    hits: &[ViewHits],
    labels: &[Vec<i32>],
    ignore: Option<i32>,
) -> Vec<i32> {
    assert_eq!(hits.len(), labels.len());
    let votes = hits.iter().zip(labels).flat_map(|(h, l)| {
        assert_eq!(h.tri.len(), l.len());
        h.tri
            .iter()
            .zip(l)
            .filter(|&(&tri, &lab)| tri >= 0 && Some(lab) != ignore)
            .map(|(&tri, &lab)| (tri as u32, lab))
    });
    fuse_votes(num_triangles, votes)
}

/// Per-triangle majority vote over (triangle, label) pairs, e.g. one per training pixel.
/// Negative labels do not vote; ties go to the smallest label; triangles without votes get
/// `UNLABELLED`.
pub fn fuse_votes(num_triangles: usize, votes: impl IntoIterator<Item = (u32, i32)>) -> Vec<i32> {
    let mut count: Vec<HashMap<i32, u32>> = vec![HashMap::new(); num_triangles];
    for (tri, lab) in votes {
        if lab >= 0 {
            *count[tri as usize].entry(lab).or_default() += 1;
        }
    }
    count.iter().map(majority).collect()
}

/// The label with the most votes, the smallest on a tie; `UNLABELLED` without votes.
fn majority(votes: &HashMap<i32, u32>) -> i32 {
    votes
        .iter()
        .max_by(|a, b| a.1.cmp(b.1).then(b.0.cmp(a.0)))
        .map(|(&lab, _)| lab)
        .unwrap_or(UNLABELLED)
}

/// Re-renders a label map from per-triangle labels.
pub fn render_labels(tri_labels: &[i32], hits: &ViewHits) -> Vec<i32> {
    hits.tri
        .iter()
        .map(|&t| {
            if t >= 0 {
                tri_labels[t as usize]
            } else {
                UNLABELLED
            }
        })
        .collect()
}

/// Fraction of pixels where two label maps agree.
pub fn agreement(a: &[i32], b: &[i32]) -> f64 {
    assert_eq!(a.len(), b.len());
    if a.is_empty() {
        return 1.0;
    }
    a.iter().zip(b).filter(|(x, y)| x == y).count() as f64 / a.len() as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hits(tri: Vec<i32>) -> ViewHits {
        ViewHits {
            width: tri.len(),
            height: 1,
            tri,
            ..Default::default()
        }
    }

    #[test]
    fn majority_and_ties_and_largest_label_can_win() {
        let h = vec![hits(vec![0, 0, 0, 1, 1, 2, -1]), hits(vec![1, 2, 2])];
        let l = vec![vec![5, 5, 3, 7, 2, 9, 4], vec![2, 9, 9]];
        let f = fuse_labels(4, &h, &l, None);
        // tri 0: 5,5,3 → 5; tri 1: 7,2,2 → 2; tri 2: 9,9,9 → 9 (largest label wins); tri 3: none.
        assert_eq!(f, vec![5, 2, 9, UNLABELLED]);
        assert_eq!(render_labels(&f, &h[0]), vec![5, 5, 5, 2, 2, 9, UNLABELLED]);
        // Tie 1:1 → smaller label; ignored label does not vote.
        let f = fuse_labels(1, &[hits(vec![0, 0, 0])], &[vec![4, 3, 0]], Some(0));
        assert_eq!(f, vec![3]);
        assert!((agreement(&[1, 2, 3, 4], &[1, 2, 0, 4]) - 0.75).abs() < 1e-12);
    }
}
