//! What a step trains on: a batch of pixels on the host (`Batch`), the pixel store on the
//! device (`DeviceStore`), the choice between them (`StepInput`), and a step's pixels as device
//! tensors (`Pixels`) with the host views of their positions.
//!
//! Owns: the pixel containers and their uploads and gathers. Must not touch: the networks, the
//! losses, the optimisers.

use super::copies::{download, flat3, upload2};
use crate::model::gather::{index_tensor, select_int_dev, select_rows_dev};
use crate::shading::ShadingLayout;
use burn::tensor::{Device, Int, Tensor};
use std::borrow::Cow;
use std::collections::HashMap;

/// A batch of training pixels as plain host arrays.
#[derive(Clone, Debug, Default)]
pub struct Batch {
    /// First-hit positions normalised to the unit cube of the scene box (hash-grid input).
    pub x_unit: Vec<[f32; 3]>,
    /// First-hit positions in world space (emission-mask input).
    pub x_world: Vec<[f32; 3]>,
    /// `ShadingLayout::DIM` values per pixel.
    pub shadings: Vec<f32>,
    /// Ground-truth HDR radiance, 3 per pixel.
    pub gt: Vec<f32>,
    /// Segment id per pixel (part or semantic label).
    pub seg: Vec<i32>,
    /// Row of the part offsets per pixel (`PartMap::rows` of its triangle); empty without
    /// them.
    pub part: Vec<u32>,
    /// LDR photos only, 3 per pixel: the clip level of a clipped channel (where `gt` is only a
    /// lower bound), `CAP_NONE` elsewhere; empty for HDR photos.
    pub cap: Vec<f32>,
}

/// The `cap` of a channel that is not clipped.
pub const CAP_NONE: f32 = 1e30;

impl Batch {
    pub fn len(&self) -> usize {
        self.x_unit.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x_unit.is_empty()
    }
}

/// Training pixels as device tensors: unit-cube and world positions, packed shadings, photo
/// values and segment ids (made compact, 0..n_seg, by `compact_ids`). As the device path's
/// pixel store it is uploaded once, and a step gathers its batch from it by index
/// (`rows`), uploading only the indices; a host batch is uploaded into one for its step.
pub struct DeviceStore {
    pub x_unit: Tensor<2>,
    pub x_world: Tensor<2>,
    pub shadings: Tensor<2>,
    pub gt: Tensor<2>,
    pub seg: Tensor<1, Int>,
    pub n_seg: usize,
    /// `Batch::cap` where the photos are LDR.
    pub cap: Option<Tensor<2>>,
    /// `Batch::part` where the model has part offsets.
    pub part: Option<Tensor<1, Int>>,
}

impl DeviceStore {
    /// Uploads every pixel of `pixels` onto `device`.
    pub fn upload(pixels: &Batch, device: &Device) -> Self {
        let n = pixels.len();
        let (seg, n_seg) = compact_ids(&pixels.seg);
        Self {
            x_unit: upload2(flat3(&pixels.x_unit), [n, 3], device),
            x_world: upload2(flat3(&pixels.x_world), [n, 3], device),
            shadings: upload2(pixels.shadings.clone(), [n, ShadingLayout::DIM], device),
            gt: upload2(pixels.gt.clone(), [n, 3], device),
            seg: index_tensor(&seg, device),
            n_seg,
            cap: (!pixels.cap.is_empty()).then(|| upload2(pixels.cap.clone(), [n, 3], device)),
            part: (!pixels.part.is_empty()).then(|| {
                let rows: Vec<i64> = pixels.part.iter().map(|&r| r as i64).collect();
                index_tensor(&rows, device)
            }),
        }
    }

    /// Entries `idx`, gathered on the device (only the indices are uploaded); the segment ids
    /// keep the store's numbering.
    pub(super) fn rows(&self, idx: &[u32], device: &Device) -> Self {
        let i: Vec<i64> = idx.iter().map(|&i| i as i64).collect();
        let i = index_tensor(&i, device);
        let rows = |t: &Tensor<2>| select_rows_dev(t.clone(), i.clone());
        Self {
            x_unit: rows(&self.x_unit),
            x_world: rows(&self.x_world),
            shadings: rows(&self.shadings),
            gt: rows(&self.gt),
            seg: select_int_dev(self.seg.clone(), i.clone()),
            n_seg: self.n_seg,
            cap: self.cap.as_ref().map(rows),
            part: self
                .part
                .as_ref()
                .map(|p| select_int_dev(p.clone(), i.clone())),
        }
    }

    /// Pixels held.
    pub(super) fn len(&self) -> usize {
        self.x_unit.dims()[0]
    }
}

/// What a step trains on.
#[derive(Clone, Copy)]
pub enum StepInput<'a> {
    /// A batch gathered on the host and uploaded.
    Host(&'a Batch),
    /// Entries `idx` of a `DeviceStore` (only the indices are uploaded). The semantic loss
    /// also needs the batch's labels and positions on the host (`host`, gathered there from the
    /// host store); the part loss does not.
    Device {
        store: &'a DeviceStore,
        idx: &'a [u32],
        host: Option<&'a Batch>,
    },
}

/// Segment ids made compact, 0..S−1 in order of first appearance, and S.
pub(super) fn compact_ids(seg: &[i32]) -> (Vec<i64>, usize) {
    let mut map: HashMap<i32, i64> = HashMap::new();
    let compact = seg
        .iter()
        .map(|s| {
            let k = map.len() as i64;
            *map.entry(*s).or_insert(k)
        })
        .collect();
    (compact, map.len())
}

/// A step's pixels as device tensors, and the host batch where the semantic loss needs it.
pub(super) struct Pixels<'a> {
    pub(super) t: DeviceStore,
    /// The batch on the host (always with a host batch; with a device store, only where the
    /// semantic loss needs it).
    pub(super) host: Option<&'a Batch>,
}

impl<'a> Pixels<'a> {
    pub(super) fn of(input: StepInput<'a>, dev: &Device) -> Self {
        match input {
            StepInput::Host(b) => Pixels {
                t: DeviceStore::upload(b, dev),
                host: Some(b),
            },
            StepInput::Device { store, idx, host } => Pixels {
                t: store.rows(idx, dev),
                host,
            },
        }
    }
}

/// The batch's unit-cube positions on the host: from the host batch, else read back.
pub(super) fn host_positions<'a>(px: &Pixels<'a>) -> Cow<'a, [[f32; 3]]> {
    host_points(px.host.map(|b| &b.x_unit[..]), &px.t.x_unit)
}

/// Points on the host: `host` where the batch is there, else `t` read back.
pub(super) fn host_points<'a>(host: Option<&'a [[f32; 3]]>, t: &Tensor<2>) -> Cow<'a, [[f32; 3]]> {
    match host {
        Some(b) => Cow::Borrowed(b),
        None => Cow::Owned(
            download(t.clone())
                .chunks_exact(3)
                .map(|c| [c[0], c[1], c[2]])
                .collect(),
        ),
    }
}
