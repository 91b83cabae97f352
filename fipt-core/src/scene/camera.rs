//! Pinhole cameras. Every input convention (FIPT synthetic left-up-forward, FIPT real look-at +
//! K, nerfstudio/OpenGL right-up-back) is converted once, at load time, to one internal form:
//! OpenCV axes (x right, y down, z forward) with intrinsics (fx, fy, cx, cy) in pixels.
//!
//! Owns: camera conventions and pixel-centre ray generation. Must not touch: images or tracing.

use glam::{DMat3, DVec3, Vec3};

/// A pinhole camera in the OpenCV convention.
#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    /// Camera-to-world rotation; columns are the camera's right, down and forward axes.
    pub rotation: DMat3,
    /// Camera centre in world space.
    pub origin: DVec3,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub width: usize,
    pub height: usize,
}

/// Pinhole intrinsics in pixels: focal lengths (fx, fy) and principal point (cx, cy).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
}

impl Camera {
    /// FIPT synthetic convention (`transforms.json`, Mitsuba `look_at`): c2w columns are
    /// (left, up, forward, position), f = W / (2 tan(fov_x / 2)), principal point at the centre.
    pub fn from_fipt_c2w(c2w: [[f64; 4]; 4], fov_x: f64, width: usize, height: usize) -> Self {
        let col = |j: usize| DVec3::new(c2w[0][j], c2w[1][j], c2w[2][j]);
        let (left, up, fwd) = (col(0), col(1), col(2));
        let f = 0.5 * width as f64 / (0.5 * fov_x).tan();
        Self {
            rotation: normalize_columns(DMat3::from_cols(-left, -up, fwd)),
            origin: col(3),
            fx: f,
            fy: f,
            cx: 0.5 * width as f64,
            cy: 0.5 * height as f64,
            width,
            height,
        }
    }

    /// nerfstudio / OpenGL convention: c2w columns are (right, up, back, position).
    pub fn from_opengl_c2w(c2w: [[f64; 4]; 4], k: Intrinsics, width: usize, height: usize) -> Self {
        let Intrinsics { fx, fy, cx, cy } = k;
        let col = |j: usize| DVec3::new(c2w[0][j], c2w[1][j], c2w[2][j]);
        let (right, up, back) = (col(0), col(1), col(2));
        Self {
            rotation: normalize_columns(DMat3::from_cols(right, -up, -back)),
            origin: col(3),
            fx,
            fy,
            cx,
            cy,
            width,
            height,
        }
    }

    /// FIPT real convention (`cam.txt` + `K_list.txt`): origin, look-at point, up vector, and a
    /// 3×3 intrinsic matrix (row-major).
    pub fn from_look_at(
        origin: DVec3,
        target: DVec3,
        up: DVec3,
        k: [[f64; 3]; 3],
        width: usize,
        height: usize,
    ) -> Self {
        let fwd = (target - origin).normalize();
        let down = -(up - fwd * up.dot(fwd)).normalize();
        let right = down.cross(fwd);
        Self {
            rotation: DMat3::from_cols(right, down, fwd),
            origin,
            fx: k[0][0],
            fy: k[1][1],
            cx: k[0][2],
            cy: k[1][2],
            width,
            height,
        }
    }

    /// The camera's intrinsics.
    pub fn intrinsics(&self) -> Intrinsics {
        Intrinsics {
            fx: self.fx,
            fy: self.fy,
            cx: self.cx,
            cy: self.cy,
        }
    }

    /// Unit world-space direction through the continuous pixel position (x, y); the centre of
    /// pixel (row j, col i) is (i + 0.5, j + 0.5).
    #[inline]
    pub fn direction_at(&self, x: f64, y: f64) -> Vec3 {
        let d = DVec3::new((x - self.cx) / self.fx, (y - self.cy) / self.fy, 1.0);
        (self.rotation * d).normalize().as_vec3()
    }

    /// Unit direction of the pixel-centre ray of (row, col).
    #[inline]
    pub fn pixel_direction(&self, row: usize, col: usize) -> Vec3 {
        self.direction_at(col as f64 + 0.5, row as f64 + 0.5)
    }

    pub fn origin_f32(&self) -> Vec3 {
        self.origin.as_vec3()
    }

    /// The rays (origin, unit direction) through the centres of an n×n grid of cells over
    /// pixel (col `x`, row `y`), row-major: ray s goes through
    /// (x + (s mod n + 0.5)/n, y + (s div n + 0.5)/n).
    pub fn grid_rays(&self, x: usize, y: usize, n: usize) -> Vec<(Vec3, Vec3)> {
        let o = self.origin_f32();
        (0..n * n)
            .map(|s| {
                let px = x as f64 + ((s % n) as f64 + 0.5) / n as f64;
                let py = y as f64 + ((s / n) as f64 + 0.5) / n as f64;
                (o, self.direction_at(px, py))
            })
            .collect()
    }

    /// All pixel-centre directions, row-major.
    pub fn pixel_directions(&self) -> Vec<Vec3> {
        let mut out = Vec::with_capacity(self.width * self.height);
        for j in 0..self.height {
            for i in 0..self.width {
                out.push(self.pixel_direction(j, i));
            }
        }
        out
    }

    /// The camera-to-world matrix in the FIPT synthetic convention (left, up, forward).
    pub fn to_fipt_c2w(&self) -> [[f64; 4]; 4] {
        c2w_of([
            -self.rotation.x_axis,
            -self.rotation.y_axis,
            self.rotation.z_axis,
            self.origin,
        ])
    }

    /// The camera-to-world matrix in the nerfstudio / OpenGL convention (right, up, back;
    /// what `from_opengl_c2w` reads).
    pub fn to_opengl_c2w(&self) -> [[f64; 4]; 4] {
        c2w_of([
            self.rotation.x_axis,
            -self.rotation.y_axis,
            -self.rotation.z_axis,
            self.origin,
        ])
    }

    /// A camera at `eye` looking at `target` with the given up vector and horizontal FOV.
    pub fn look_at_fov(
        eye: DVec3,
        target: DVec3,
        up: DVec3,
        fov_x: f64,
        width: usize,
        height: usize,
    ) -> Self {
        let f = 0.5 * width as f64 / (0.5 * fov_x).tan();
        let k = [
            [f, 0.0, 0.5 * width as f64],
            [0.0, f, 0.5 * height as f64],
            [0.0, 0.0, 1.0],
        ];
        Self::from_look_at(eye, target, up, k, width, height)
    }
}

fn normalize_columns(m: DMat3) -> DMat3 {
    DMat3::from_cols(
        m.x_axis.normalize(),
        m.y_axis.normalize(),
        m.z_axis.normalize(),
    )
}

/// A 4×4 camera-to-world matrix of three axis columns and the position.
fn c2w_of(c: [DVec3; 4]) -> [[f64; 4]; 4] {
    let mut m = [[0.0; 4]; 4];
    for (j, v) in c.iter().enumerate() {
        m[0][j] = v.x;
        m[1][j] = v.y;
        m[2][j] = v.z;
    }
    m[3][3] = 1.0;
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The worked example of `shared/scenes/README.md` (camera at (1,1.5,2) looking at +x).
    #[test]
    fn readme_worked_example() {
        let c2w = [
            [0.0, 0.0, 1.0, 1.0],
            [0.0, 1.0, 0.0, 1.5],
            [-1.0, 0.0, 0.0, 2.0],
            [0.0, 0.0, 0.0, 1.0],
        ];
        let cam = Camera::from_fipt_c2w(c2w, 70f64.to_radians(), 160, 120);
        assert!((cam.fx - 114.2518).abs() < 1e-4);
        let cases = [
            ((0, 0), [0.754767, 0.393067, -0.525190]),
            ((0, 159), [0.754767, 0.393067, 0.525190]),
            ((119, 0), [0.754767, -0.393067, -0.525190]),
            ((59, 79), [0.999981, 0.004376, -0.004376]),
        ];
        for ((r, c), want) in cases {
            let d = cam.pixel_direction(r, c);
            for k in 0..3 {
                assert!(
                    (d[k] - want[k]).abs() < 1e-5,
                    "pixel ({r},{c}): {d:?} vs {want:?}"
                );
            }
        }
        // Round trip through the FIPT matrix.
        assert_eq!(cam.to_fipt_c2w(), c2w);
    }

    /// The same camera expressed in the three input conventions gives the same rays.
    #[test]
    fn conventions_agree() {
        let eye = DVec3::new(0.3, 1.2, -0.4);
        let target = DVec3::new(2.0, 0.7, 1.0);
        let cam = Camera::look_at_fov(eye, target, DVec3::Y, 1.1, 64, 48);
        let m = cam.to_fipt_c2w();
        let a = Camera::from_fipt_c2w(m, 1.1, 64, 48);
        let r = cam.rotation;
        let mut gl = [[0.0; 4]; 4];
        for (j, v) in [r.x_axis, -r.y_axis, -r.z_axis, eye].iter().enumerate() {
            gl[0][j] = v.x;
            gl[1][j] = v.y;
            gl[2][j] = v.z;
        }
        gl[3][3] = 1.0;
        let b = Camera::from_opengl_c2w(gl, cam.intrinsics(), 64, 48);
        for (row, col) in [(0, 0), (47, 63), (20, 31), (5, 60)] {
            let d = cam.pixel_direction(row, col);
            assert!((a.pixel_direction(row, col) - d).length() < 1e-6);
            assert!((b.pixel_direction(row, col) - d).length() < 1e-6);
        }
        // The centre of the image looks at the target.
        let c = cam.direction_at(32.0, 24.0).as_dvec3();
        assert!((c - (target - eye).normalize()).length() < 1e-6);
    }
}
