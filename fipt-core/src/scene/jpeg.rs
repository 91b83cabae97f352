//! A JPEG photo's quantisation and the reconstruction of its code values within it.
//!
//! A JPEG stores, for each 8×8 block of each colour component (Y, Cb, Cr), the block's DCT
//! coefficients divided by a quantisation table and rounded. A decoder's pixels are one image
//! whose coefficients round to the stored ones; every image in that set is as consistent with
//! the file. `reconstruct` picks a smoother one: projected gradient descent on the image's total
//! variation, each step projected back onto the set (every coefficient of a block into its
//! quantisation interval, which is the Euclidean projection since the DCT is orthonormal) and
//! onto the code range [0, 255] (projection onto convex sets, after Bredies & Holler's total
//! variation JPEG decompression). The ringing and blocking that the rounding adds raise the total
//! variation and go; the edges and texture that the coefficients carry stay.
//!
//! Owns: reading the quantisation tables and the component layout from a JPEG's markers, the
//! 8×8 DCT, the reconstruction. Must not touch: reading files and their errors
//! (`super::ldr`), the camera response, tensors.

/// Zig-zag position → natural (row-major) index of an 8×8 block (ITU T.81, Figure 5).
const ZIGZAG: [usize; 64] = [
    0, 1, 8, 16, 9, 2, 3, 10, 17, 24, 32, 25, 18, 11, 4, 5, 12, 19, 26, 33, 40, 48, 41, 34, 27, 20,
    13, 6, 7, 14, 21, 28, 35, 42, 49, 56, 57, 50, 43, 36, 29, 22, 15, 23, 30, 37, 44, 51, 58, 59,
    52, 45, 38, 31, 39, 46, 53, 60, 61, 54, 47, 55, 62, 63,
];

/// What a JPEG file says about its quantisation: one table per colour component.
#[derive(Clone, Debug, PartialEq)]
pub struct JpegTables {
    /// The quantisation table of each component in frame order (Y, Cb, Cr; Y alone for a grey
    /// JPEG), natural (row-major) order.
    pub quant: Vec<[u16; 64]>,
    /// Whether every component is sampled at the same resolution (no chroma subsampling).
    /// Otherwise only Y, whose blocks lie on the pixel grid, is reconstructed.
    pub full_chroma: bool,
}

impl JpegTables {
    /// The tables of a JPEG file's bytes, read from its markers up to the first scan: the
    /// quantisation tables (DQT) and the frame header (SOF0, SOF1 or SOF2: baseline, extended or
    /// progressive Huffman). `None` for what this does not model: another coding process, a
    /// component count other than 1 or 3, RGB or CMYK JPEGs (Adobe transform 0), a table that
    /// a component names but the file lacks, or bytes that do not parse.
    pub fn read(bytes: &[u8]) -> Option<Self> {
        if !bytes.starts_with(&[0xFF, 0xD8]) {
            return None;
        }
        let mut tables: [Option<[u16; 64]>; 4] = [None; 4];
        // (sampling factors, table id) per component.
        let mut comps: Vec<(u8, usize)> = Vec::new();
        let mut i = 2;
        loop {
            // Markers may be preceded by fill bytes (0xFF).
            while *bytes.get(i)? == 0xFF && *bytes.get(i + 1)? == 0xFF {
                i += 1;
            }
            if *bytes.get(i)? != 0xFF {
                return None;
            }
            let marker = *bytes.get(i + 1)?;
            i += 2;
            if marker == 0x01 || (0xD0..=0xD7).contains(&marker) {
                continue;
            }
            if marker == 0xD9 || marker == 0xDA {
                break;
            }
            let len = u16::from_be_bytes([*bytes.get(i)?, *bytes.get(i + 1)?]) as usize;
            let seg = bytes.get(i + 2..i + len)?;
            match marker {
                0xDB => {
                    let mut s = seg;
                    while !s.is_empty() {
                        let (precision, id) = (s[0] >> 4, (s[0] & 15) as usize);
                        let n = if precision == 0 { 64 } else { 128 };
                        let vals = s.get(1..1 + n)?;
                        let mut t = [0u16; 64];
                        for (k, &nat) in ZIGZAG.iter().enumerate() {
                            t[nat] = if precision == 0 {
                                vals[k] as u16
                            } else {
                                u16::from_be_bytes([vals[2 * k], vals[2 * k + 1]])
                            };
                        }
                        if t.contains(&0) {
                            return None;
                        }
                        *tables.get_mut(id)? = Some(t);
                        s = &s[1 + n..];
                    }
                }
                0xC0..=0xC2 => {
                    let nf = *seg.get(5)? as usize;
                    for c in 0..nf {
                        let d = seg.get(6 + 3 * c..9 + 3 * c)?;
                        comps.push((d[1], d[2] as usize));
                    }
                }
                0xC3 | 0xC5..=0xC7 | 0xC9..=0xCB | 0xCD..=0xCF => return None,
                // Adobe APP14 with transform 0: the components are RGB or CMYK, not YCbCr.
                0xEE if seg.starts_with(b"Adobe") && seg.get(11) == Some(&0) => return None,
                _ => {}
            }
            i += len;
        }
        if comps.len() != 1 && comps.len() != 3 {
            return None;
        }
        let quant = comps
            .iter()
            .map(|&(_, id)| tables.get(id).copied().flatten())
            .collect::<Option<Vec<_>>>()?;
        Some(Self {
            quant,
            full_chroma: comps.iter().all(|&(s, _)| s == comps[0].0),
        })
    }
}

/// How `reconstruct` runs (`ldr.jpeg_iterations` in fipt-train's config).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reconstruction {
    /// Projected gradient steps.
    pub iterations: usize,
    /// Step length, in code units (0–255) per unit of the total variation's gradient.
    pub step: f32,
    /// Smoothing of the total variation's norm, √(|∇x|² + ε²), in code units.
    pub epsilon: f32,
}

impl Default for Reconstruction {
    fn default() -> Self {
        Self {
            iterations: 15,
            step: 0.1,
            epsilon: 0.3,
        }
    }
}

/// The orthonormal 8-point DCT-II matrix, `m[u][x]` = α(u)·cos((2x + 1)uπ/16); JPEG's 2-D DCT
/// is `m · block · mᵀ` (ITU T.81, A.3.3).
fn dct_matrix() -> [[f32; 8]; 8] {
    let mut m = [[0f32; 8]; 8];
    for (u, row) in m.iter_mut().enumerate() {
        let a = if u == 0 { (1.0f64 / 8.0).sqrt() } else { 0.5 };
        for (x, v) in row.iter_mut().enumerate() {
            *v = (a * ((2 * x + 1) as f64 * u as f64 * std::f64::consts::PI / 16.0).cos()) as f32;
        }
    }
    m
}

/// `m · b · mᵀ` (forward) or `mᵀ · b · m` (inverse) of one 8×8 block, row-major.
fn dct8(m: &[[f32; 8]; 8], b: &[f32; 64], inverse: bool) -> [f32; 64] {
    let at = |r: usize, c: usize| if inverse { m[c][r] } else { m[r][c] };
    let mut t = [0f32; 64];
    for r in 0..8 {
        for x in 0..8 {
            t[r * 8 + x] = (0..8).map(|k| at(r, k) * b[k * 8 + x]).sum();
        }
    }
    let mut o = [0f32; 64];
    for r in 0..8 {
        for c in 0..8 {
            o[r * 8 + c] = (0..8).map(|k| t[r * 8 + k] * at(c, k)).sum();
        }
    }
    o
}

/// The whole block (`bx`, `by`) of a plane `w` wide, level-shifted by −128 as JPEG codes it.
fn block(x: &[f32], w: usize, bx: usize, by: usize) -> [f32; 64] {
    std::array::from_fn(|i| x[(by * 8 + i / 8) * w + bx * 8 + i % 8] - 128.0)
}

/// JFIF's RGB → YCbCr (ITU T.871, §7), in code units.
fn to_ycc([r, g, b]: [f32; 3]) -> [f32; 3] {
    [
        0.299 * r + 0.587 * g + 0.114 * b,
        -0.168_736 * r - 0.331_264 * g + 0.5 * b + 128.0,
        0.5 * r - 0.418_688 * g - 0.081_312 * b + 128.0,
    ]
}

/// JFIF's YCbCr → RGB.
fn to_rgb([y, cb, cr]: [f32; 3]) -> [f32; 3] {
    let (cb, cr) = (cb - 128.0, cr - 128.0);
    [
        y + 1.402 * cr,
        y - 0.344_136 * cb - 0.714_136 * cr,
        y + 1.772 * cb,
    ]
}

/// One component plane and the quantisation intervals of its whole blocks.
struct Plane {
    /// The decoded values (pixels outside whole blocks keep them).
    decoded: Vec<f32>,
    /// Per whole block, per coefficient: the interval's bounds.
    lo: Vec<[f32; 64]>,
    hi: Vec<[f32; 64]>,
}

/// The gradient of the smoothed isotropic total variation Σ √(|∇x|² + ε²) (forward
/// differences, none across the far edges).
fn tv_gradient(x: &[f32], w: usize, h: usize, eps: f32) -> Vec<f32> {
    let mut px = vec![0f32; w * h];
    let mut py = vec![0f32; w * h];
    for r in 0..h {
        for c in 0..w {
            let i = r * w + c;
            let dx = if c + 1 < w { x[i + 1] - x[i] } else { 0.0 };
            let dy = if r + 1 < h { x[i + w] - x[i] } else { 0.0 };
            let n = (dx * dx + dy * dy + eps * eps).sqrt();
            px[i] = dx / n;
            py[i] = dy / n;
        }
    }
    let mut g = vec![0f32; w * h];
    for r in 0..h {
        for c in 0..w {
            let i = r * w + c;
            let mut div = px[i] + py[i];
            if c > 0 {
                div -= px[i - 1];
            }
            if r > 0 {
                div -= py[i - w];
            }
            g[i] = -div;
        }
    }
    g
}

/// The code values, in [0, 1], of a JPEG photo reconstructed within its quantisation
/// (module doc). `codes`: the decoder's 8-bit RGB, `w`×`h`, rows top to bottom. The components
/// reconstructed are Y, Cb and Cr without chroma subsampling, else Y alone; pixels outside
/// the whole 8×8 blocks keep the decoder's values.
pub fn reconstruct(
    codes: &[u8],
    w: usize,
    h: usize,
    tables: &JpegTables,
    how: &Reconstruction,
) -> Vec<f32> {
    let n = w * h;
    let ycc: Vec<[f32; 3]> = codes
        .chunks_exact(3)
        .map(|p| to_ycc([p[0] as f32, p[1] as f32, p[2] as f32]))
        .collect();
    let m = dct_matrix();
    let (bw, bh) = (w / 8, h / 8);
    let active = if tables.quant.len() == 3 && tables.full_chroma {
        3
    } else {
        1
    };
    let mut planes: Vec<Plane> = (0..active)
        .map(|k| {
            let decoded: Vec<f32> = ycc.iter().map(|p| p[k]).collect();
            let q = &tables.quant[k];
            let (mut lo, mut hi) = (Vec::new(), Vec::new());
            for by in 0..bh {
                for bx in 0..bw {
                    let coef = dct8(&m, &block(&decoded, w, bx, by), false);
                    let (mut l, mut u) = ([0f32; 64], [0f32; 64]);
                    for j in 0..64 {
                        let qj = q[j] as f32;
                        let idx = (coef[j] / qj).round();
                        l[j] = (idx - 0.5) * qj;
                        u[j] = (idx + 0.5) * qj;
                    }
                    lo.push(l);
                    hi.push(u);
                }
            }
            Plane { decoded, lo, hi }
        })
        .collect();
    let mut x: Vec<Vec<f32>> = (0..3).map(|k| ycc.iter().map(|p| p[k]).collect()).collect();
    for _ in 0..how.iterations {
        for (k, plane) in planes.iter_mut().enumerate() {
            let g = tv_gradient(&x[k], w, h, how.epsilon);
            let z: Vec<f32> = x[k].iter().zip(&g).map(|(v, d)| v - how.step * d).collect();
            let mut out = plane.decoded.clone();
            for by in 0..bh {
                for bx in 0..bw {
                    let bi = by * bw + bx;
                    let mut coef = dct8(&m, &block(&z, w, bx, by), false);
                    for (j, v) in coef.iter_mut().enumerate() {
                        *v = v.clamp(plane.lo[bi][j], plane.hi[bi][j]);
                    }
                    let b = dct8(&m, &coef, true);
                    for r in 0..8 {
                        for c in 0..8 {
                            out[(by * 8 + r) * w + bx * 8 + c] = b[r * 8 + c] + 128.0;
                        }
                    }
                }
            }
            x[k] = out;
        }
        // Onto the code range; the components not reconstructed keep the decoder's values.
        for i in 0..n {
            let rgb = to_rgb([x[0][i], x[1][i], x[2][i]]).map(|v| v.clamp(0.0, 255.0));
            let y = to_ycc(rgb);
            for (plane, &v) in x.iter_mut().zip(&y).take(active) {
                plane[i] = v;
            }
        }
    }
    (0..n)
        .flat_map(|i| to_rgb([x[0][i], x[1][i], x[2][i]]).map(|v| v.clamp(0.0, 255.0) / 255.0))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 96×64 photo-like image: smooth shading, hard-edged planks and checks, mild noise, all
    /// inside the code range.
    fn photo() -> (usize, usize, Vec<u8>) {
        let (w, h) = (96, 64);
        let mut s = 12345u32;
        let mut noise = || {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            (s as f32 / u32::MAX as f32 - 0.5) * 4.0
        };
        let mut codes = Vec::with_capacity(w * h * 3);
        for r in 0..h {
            for c in 0..w {
                let shade = 60.0 + 1.2 * c as f32 + 0.8 * r as f32;
                let plank = if (c / 11 + r / 23) % 2 == 0 {
                    1.0
                } else {
                    0.72
                };
                let check = if (c / 5 + r / 5) % 2 == 0 { 1.0 } else { 0.85 };
                let t = if r < h / 2 { plank } else { check };
                for tint in [1.0, 0.8, 0.55] {
                    codes.push((shade * t * tint + noise()).clamp(1.0, 254.0).round() as u8);
                }
            }
        }
        (w, h, codes)
    }

    fn encode(w: usize, h: usize, codes: &[u8], quality: u8) -> Vec<u8> {
        let mut bytes = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, quality)
            .encode(codes, w as u32, h as u32, image::ExtendedColorType::Rgb8)
            .unwrap();
        bytes
    }

    fn decode(bytes: &[u8]) -> Vec<u8> {
        image::load_from_memory(bytes).unwrap().to_rgb8().into_raw()
    }

    fn psnr(a: &[f32], b: &[u8]) -> f64 {
        let mse = a
            .iter()
            .zip(b)
            .map(|(&x, &y)| ((x * 255.0) as f64 - y as f64).powi(2))
            .sum::<f64>()
            / a.len() as f64;
        10.0 * (255.0f64 * 255.0 / mse).log10()
    }

    /// The DCT coefficients of every whole Y block of an RGB image in code units.
    fn y_coefficients(rgb: &[f32], w: usize, h: usize) -> Vec<[f32; 64]> {
        let m = dct_matrix();
        let y: Vec<f32> = rgb
            .chunks_exact(3)
            .map(|p| to_ycc([p[0], p[1], p[2]])[0])
            .collect();
        (0..h / 8)
            .flat_map(|by| (0..w / 8).map(move |bx| (bx, by)))
            .map(|(bx, by)| dct8(&m, &block(&y, w, bx, by), false))
            .collect()
    }

    /// Mean distance of the Y blocks' DCT coefficients larger than 2 from the nearest multiple
    /// of their quantisation step, in steps (uniform: 0.25). `rgb`: code units.
    fn mean_offset(rgb: &[f32], w: usize, h: usize, q: &[u16; 64]) -> f64 {
        let t: Vec<f64> = y_coefficients(rgb, w, h)
            .iter()
            .flat_map(|c| {
                (0..64)
                    .filter(|&j| c[j].abs() > 2.0)
                    .map(|j| c[j] as f64 / q[j] as f64)
            })
            .collect();
        t.iter().map(|t| (t - t.round()).abs()).sum::<f64>() / t.len() as f64
    }

    /// The share of Y coefficients of `a` (code units) within their quantisation interval
    /// about those of `b` (the decoder's), 0.05 of a step allowed past its ends.
    fn same_indices(a: &[f32], b: &[f32], w: usize, h: usize, q: &[u16; 64]) -> f64 {
        let (ca, cb) = (y_coefficients(a, w, h), y_coefficients(b, w, h));
        let pairs = ca
            .iter()
            .zip(&cb)
            .flat_map(|(x, y)| (0..64).map(move |j| (x[j] / q[j] as f32, y[j] / q[j] as f32)));
        let (inside, n) = pairs.fold((0usize, 0usize), |(k, n), (x, y)| {
            (k + ((x - y.round()).abs() <= 0.55) as usize, n + 1)
        });
        inside as f64 / n as f64
    }

    #[test]
    fn the_dct_is_orthonormal() {
        let m = dct_matrix();
        let b: [f32; 64] = std::array::from_fn(|i| ((i * 37) % 61) as f32 - 30.0);
        let back = dct8(&m, &dct8(&m, &b, false), true);
        for (x, y) in b.iter().zip(&back) {
            assert!((x - y).abs() < 1e-3, "{x} {y}");
        }
        let energy = |v: &[f32; 64]| v.iter().map(|x| x * x).sum::<f32>();
        let e = energy(&dct8(&m, &b, false));
        assert!((e / energy(&b) - 1.0).abs() < 1e-5);
    }

    #[test]
    fn tables_are_the_files_quantisation() {
        let (w, h, codes) = photo();
        let bytes = encode(w, h, &codes, 50);
        let t = JpegTables::read(&bytes).expect("tables");
        assert_eq!(t.quant.len(), 3);
        assert!(t.full_chroma);
        // Quality 50 is the example luminance table of ITU T.81, Annex K.1, unscaled.
        assert_eq!(&t.quant[0][..8], &[16, 11, 10, 16, 24, 40, 51, 61]);
        assert_eq!(&t.quant[0][56..], &[72, 92, 95, 98, 112, 100, 103, 99]);
        // The decoded blocks' coefficients lie on the table's multiples; on the transposed
        // table (the zig-zag order misread) they do not.
        let decoded: Vec<f32> = decode(&bytes).iter().map(|&c| c as f32).collect();
        let on = mean_offset(&decoded, w, h, &t.quant[0]);
        let mut tr = [0u16; 64];
        for r in 0..8 {
            for c in 0..8 {
                tr[c * 8 + r] = t.quant[0][r * 8 + c];
            }
        }
        let off = mean_offset(&decoded, w, h, &tr);
        assert!(on < 0.08 && off > 0.15, "{on} {off}");
    }

    #[test]
    fn reconstruction_is_nearer_the_image_than_the_decoder() {
        let (w, h, codes) = photo();
        for quality in [75, 90] {
            let bytes = encode(w, h, &codes, quality);
            let decoded = decode(&bytes);
            let t = JpegTables::read(&bytes).unwrap();
            let plain: Vec<f32> = decoded.iter().map(|&c| c as f32 / 255.0).collect();
            let rec = reconstruct(&decoded, w, h, &t, &Reconstruction::default());
            let (p0, p1) = (psnr(&plain, &codes), psnr(&rec, &codes));
            // Still consistent with the file: the coefficients round to the stored ones.
            let rec255: Vec<f32> = rec.iter().map(|v| v * 255.0).collect();
            let dec255: Vec<f32> = decoded.iter().map(|&c| c as f32).collect();
            let same = same_indices(&rec255, &dec255, w, h, &t.quant[0]);
            eprintln!("quality {quality}: {p0:.2} → {p1:.2} dB, same indices {same:.4}");
            assert!(p1 > p0 + 0.3, "quality {quality}: {p0:.2} → {p1:.2} dB");
            assert!(same > 0.99, "quality {quality}: {same}");
        }
    }

    #[test]
    fn no_iterations_give_the_decoders_codes() {
        let (w, h, codes) = photo();
        let bytes = encode(w, h, &codes, 90);
        let decoded = decode(&bytes);
        let t = JpegTables::read(&bytes).unwrap();
        let how = Reconstruction {
            iterations: 0,
            ..Reconstruction::default()
        };
        let rec = reconstruct(&decoded, w, h, &t, &how);
        for (r, &d) in rec.iter().zip(&decoded) {
            assert!((r * 255.0 - d as f32).abs() < 0.01, "{r} {d}");
        }
    }

    #[test]
    fn what_is_not_a_whole_jpeg_header_reads_as_none() {
        let (w, h, codes) = photo();
        let bytes = encode(w, h, &codes, 90);
        let scan = bytes
            .windows(2)
            .position(|p| p == [0xFF, 0xDA])
            .expect("a scan");
        for k in 0..scan {
            assert_eq!(JpegTables::read(&bytes[..k]), None, "{k} bytes");
        }
        assert!(JpegTables::read(&bytes[..scan + 2]).is_some());
        use image::ImageEncoder;
        let mut png = Vec::new();
        image::codecs::png::PngEncoder::new(&mut png)
            .write_image(&codes, w as u32, h as u32, image::ExtendedColorType::Rgb8)
            .unwrap();
        assert_eq!(JpegTables::read(&png), None);
    }
}
