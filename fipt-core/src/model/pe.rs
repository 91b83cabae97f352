//! NeRF positional encoding (paper Eq. 14, reference §2.3): [x, sin(2^l π x), cos(2^l π x)],
//! l = 0..L−1, on raw world coordinates, as tensor ops.
//!
//! Owns: the encoding. Must not touch: the MLP that consumes it.

use burn::tensor::{Tensor, TensorData};

/// Output width of the encoding of 3-D points with `freqs` frequencies.
pub fn pe_dim(freqs: usize) -> usize {
    3 + 6 * freqs
}

/// Encodes `x` [N, 3] into [N, 3 + 6L].
pub fn positional_encoding(x: Tensor<2>, freqs: usize) -> Tensor<2> {
    let [n, _] = x.dims();
    let f: Vec<f32> = (0..freqs)
        .map(|l| (2f64.powi(l as i32) * std::f64::consts::PI) as f32)
        .collect();
    let f = Tensor::<3>::from_data(TensorData::new(f, [1, freqs, 1]), &x.device());
    let xf = x.clone().reshape([n, 1, 3]) * f; // [N, L, 3]
    let s = xf.clone().sin().reshape([n, 3 * freqs]);
    let c = xf.cos().reshape([n, 3 * freqs]);
    Tensor::cat(vec![x, s, c], 1)
}
