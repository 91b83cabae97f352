//! Helpers shared by the end-to-end tests (included with `mod common;`).

use std::path::Path;

/// Panics unless the file at `p` is non-empty and reads as what its extension says: JSON, PNG,
/// EXR, or HTML that ends with `</html>`.
pub fn assert_readable(p: &Path) {
    let s = p.display();
    let len = std::fs::metadata(p).unwrap().len();
    assert!(len > 0, "{s}: empty");
    match p.extension().and_then(|e| e.to_str()) {
        Some("json") => {
            serde_json::from_str::<serde_json::Value>(&std::fs::read_to_string(p).unwrap())
                .unwrap_or_else(|e| panic!("{s}: {e}"));
        }
        Some("png") => {
            image::open(p).unwrap_or_else(|e| panic!("{s}: {e}"));
        }
        Some("exr") => {
            fipt_core::scene::Image::read_exr(p).unwrap_or_else(|e| panic!("{s}: {e}"));
        }
        Some("html") => {
            let t = std::fs::read_to_string(p).unwrap();
            assert!(t.trim_end().ends_with("</html>"), "{s}: cut short");
        }
        _ => {}
    }
}
