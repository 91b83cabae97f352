//! Area lights for the path tracer: emitting triangles with constant radiance, one- or
//! two-sided, and how next-event estimation picks one (reference §2.5 picks uniformly; area- and
//! power-weighted picks are options), with the pdfs MIS needs.
//!
//! Owns: the emitter list, its selection distribution and point sampling. Must not touch:
//! visibility, materials.

use super::extract::EmitterSides;
use fipt_core::scene::Mesh;
use glam::Vec3;

/// How next-event estimation picks an emitter triangle.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LightSelection {
    /// Every triangle equally likely (the reference's `SLFEmitter`).
    Uniform,
    /// Proportional to area.
    Area,
    /// Proportional to emitted power: area × luminance of the radiance (× 2 if two-sided).
    Power,
}

impl std::str::FromStr for LightSelection {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "uniform" => Ok(Self::Uniform),
            "area" => Ok(Self::Area),
            "power" => Ok(Self::Power),
            _ => Err(format!(
                "unknown light selection '{s}' (uniform, area, power)"
            )),
        }
    }
}

/// One emitting triangle.
#[derive(Clone, Copy, Debug)]
pub struct AreaLight {
    pub tri: u32,
    pub v0: Vec3,
    pub e1: Vec3,
    pub e2: Vec3,
    /// Unit winding normal `cross(e1, e2)`: the emitting side of a one-sided light.
    pub normal: Vec3,
    pub area: f32,
    pub radiance: Vec3,
    pub two_sided: bool,
}

impl AreaLight {
    /// Radiance leaving the light towards direction `w` (unit, pointing away from the light).
    #[inline]
    pub fn radiance_towards(&self, w: Vec3) -> Vec3 {
        if self.two_sided || self.normal.dot(w) > 0.0 {
            self.radiance
        } else {
            Vec3::ZERO
        }
    }
}

/// A point sampled on a light.
#[derive(Clone, Copy, Debug)]
pub struct LightSample {
    pub light: u32,
    pub point: Vec3,
    /// pdf of the point in area measure (selection × 1/area).
    pub pdf_area: f32,
}

/// All emitters of a scene with a selection distribution.
#[derive(Clone, Debug)]
pub struct EmitterSet {
    pub lights: Vec<AreaLight>,
    /// Light index per mesh triangle (`u32::MAX` for non-emitters).
    by_tri: Vec<u32>,
    /// Cumulative selection weights, normalised to end at 1.
    cdf: Vec<f32>,
    /// Selection probability per light.
    pick: Vec<f32>,
}

fn luminance(c: Vec3) -> f32 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}

impl EmitterSet {
    /// The emitters `(triangle, radiance)` of `mesh`; zero-radiance and zero-area entries are
    /// skipped.
    pub fn new(
        mesh: &Mesh,
        emitters: impl IntoIterator<Item = (u32, Vec3)>,
        two_sided: bool,
        selection: LightSelection,
    ) -> Self {
        let sides = if two_sided {
            EmitterSides::Both
        } else {
            EmitterSides::Front
        };
        Self::with_sides(
            mesh,
            emitters.into_iter().map(|(t, r)| (t, r, sides)),
            selection,
        )
    }

    /// The emitters `(triangle, radiance, emitting sides)` of `mesh`; zero-radiance and
    /// zero-area entries are skipped. A back-emitting light stores the flipped normal.
    pub fn with_sides(
        mesh: &Mesh,
        emitters: impl IntoIterator<Item = (u32, Vec3, EmitterSides)>,
        selection: LightSelection,
    ) -> Self {
        let mut lights = Vec::new();
        let mut by_tri = vec![u32::MAX; mesh.num_triangles()];
        for (tri, radiance, sides) in emitters {
            let [a, b, c] = mesh.corners(tri as usize);
            let cross = (b - a).cross(c - a);
            let area = 0.5 * cross.length();
            if area <= 0.0 || radiance.max_element() <= 0.0 || by_tri[tri as usize] != u32::MAX {
                continue;
            }
            by_tri[tri as usize] = lights.len() as u32;
            lights.push(AreaLight {
                tri,
                v0: a,
                e1: b - a,
                e2: c - a,
                normal: if sides == EmitterSides::Back {
                    -cross.normalize()
                } else {
                    cross.normalize()
                },
                area,
                radiance,
                two_sided: sides == EmitterSides::Both,
            });
        }
        let weights: Vec<f64> = lights
            .iter()
            .map(|l| match selection {
                LightSelection::Uniform => 1.0,
                LightSelection::Area => l.area as f64,
                LightSelection::Power => {
                    l.area as f64
                        * luminance(l.radiance).max(1e-6) as f64
                        * if l.two_sided { 2.0 } else { 1.0 }
                }
            })
            .collect();
        let total: f64 = weights.iter().sum();
        let mut acc = 0.0;
        let mut cdf = Vec::with_capacity(lights.len());
        for w in &weights {
            acc += w / total;
            cdf.push(acc as f32);
        }
        if let Some(last) = cdf.last_mut() {
            *last = 1.0;
        }
        let pick = weights.iter().map(|w| (w / total) as f32).collect();
        Self {
            lights,
            by_tri,
            cdf,
            pick,
        }
    }

    pub fn is_empty(&self) -> bool {
        self.lights.is_empty()
    }

    /// The light on mesh triangle `tri`, if it emits.
    #[inline]
    pub fn light_of(&self, tri: u32) -> Option<u32> {
        self.by_tri
            .get(tri as usize)
            .copied()
            .filter(|&l| l != u32::MAX)
    }

    /// pdf (area measure) that `sample` returns a given point of light `l`.
    #[inline]
    pub fn pdf_area(&self, l: u32) -> f32 {
        self.pick[l as usize] / self.lights[l as usize].area
    }

    /// Picks a light with `u0` and a uniform point on it with (`u1`, `u2`).
    pub fn sample(&self, u0: f32, u1: f32, u2: f32) -> Option<LightSample> {
        if self.lights.is_empty() {
            return None;
        }
        let l = self
            .cdf
            .partition_point(|&c| c <= u0)
            .min(self.lights.len() - 1);
        let light = &self.lights[l];
        // Uniform on the triangle: p = (1 − s)·v0 + s(1 − u2)·v1 + s·u2·v2, s = √u1.
        let s = u1.sqrt();
        Some(LightSample {
            light: l as u32,
            point: light.v0 + light.e1 * (s * (1.0 - u2)) + light.e2 * (s * u2),
            pdf_area: self.pdf_area(l as u32),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fipt_core::scene::Mesh;

    /// One-sided lights emit along their (possibly flipped) normal only; two-sided both ways.
    #[test]
    fn emitting_sides() {
        let m = two_tris();
        let set = EmitterSet::with_sides(
            &m,
            [
                (0, Vec3::ONE, EmitterSides::Front),
                (1, Vec3::ONE, EmitterSides::Back),
            ],
            LightSelection::Uniform,
        );
        for l in &set.lights {
            let n = l.normal;
            assert_eq!(l.radiance_towards(n), Vec3::ONE);
            assert_eq!(l.radiance_towards(-n), Vec3::ZERO);
        }
        let winding = |t: usize| {
            let [a, b, c] = m.corners(t);
            (b - a).cross(c - a).normalize()
        };
        assert!(set.lights[0].normal.dot(winding(0)) > 0.99);
        assert!(set.lights[1].normal.dot(winding(1)) < -0.99);
        let both = EmitterSet::new(&m, [(0, Vec3::ONE)], true, LightSelection::Uniform);
        let n = both.lights[0].normal;
        assert_eq!(both.lights[0].radiance_towards(-n), Vec3::ONE);
    }

    fn two_tris() -> Mesh {
        Mesh {
            vertices: vec![
                Vec3::ZERO,
                Vec3::X,
                Vec3::Z,
                Vec3::new(0.0, 1.0, 0.0),
                Vec3::new(2.0, 1.0, 0.0),
                Vec3::new(0.0, 1.0, 2.0),
            ],
            triangles: vec![[0, 2, 1], [3, 5, 4]],
        }
    }

    /// Selection frequencies follow the weights, points are uniform on the triangle (their
    /// mean is the centroid) and lie on it.
    #[test]
    fn selection_and_points_follow_the_pdfs() {
        let mesh = two_tris();
        let em = [(0, Vec3::splat(1.0)), (1, Vec3::splat(3.0))];
        for (sel, want) in [
            (LightSelection::Uniform, 0.5),
            (LightSelection::Area, 4.0 / 5.0),
            (LightSelection::Power, 12.0 / 13.0),
        ] {
            let set = EmitterSet::new(&mesh, em, false, sel);
            let mut r = fipt_core::rng::Rng::new(1, 2);
            let n = 200_000;
            let (mut second, mut centroid) = (0usize, Vec3::ZERO);
            for _ in 0..n {
                let s = set
                    .sample(r.next_f32(), r.next_f32(), r.next_f32())
                    .unwrap();
                if s.light == 1 {
                    second += 1;
                    centroid += s.point;
                    assert!((s.point.y - 1.0).abs() < 1e-6);
                    assert!(
                        s.point.x >= -1e-6
                            && s.point.z >= -1e-6
                            && s.point.x / 2.0 + s.point.z / 2.0 <= 1.0 + 1e-5
                    );
                }
            }
            let f = second as f64 / n as f64;
            assert!((f - want).abs() < 5e-3, "{sel:?}: {f} vs {want}");
            let c = centroid / second as f32;
            assert!(
                (c - Vec3::new(2.0 / 3.0, 1.0, 2.0 / 3.0)).length() < 1e-2,
                "{c}"
            );
            let p1 = set.pick[1] / 2.0;
            assert!((set.pdf_area(1) - p1).abs() < 1e-6);
        }
    }

    #[test]
    fn one_sided_lights_emit_towards_their_winding_normal() {
        let set = EmitterSet::new(&two_tris(), [(1, Vec3::ONE)], false, LightSelection::Area);
        let l = &set.lights[0];
        // Winding (3, 5, 4): cross((0,0,2), (2,0,0)) = (0, 4, 0): +y.
        assert!(l.normal.y > 0.99);
        assert_eq!(l.radiance_towards(Vec3::Y), Vec3::ONE);
        assert_eq!(l.radiance_towards(-Vec3::Y), Vec3::ZERO);
        assert_eq!(set.light_of(1), Some(0));
        assert_eq!(set.light_of(0), None);
    }
}
