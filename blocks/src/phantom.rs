//! The built-in dataset: a deterministic procedural CT head phantom.
//!
//! A schematic adult head and upper neck in Hounsfield units, drawn so that each
//! CT preset shows something a radiologist recognises: the skull with its
//! orbits, nasal cavity and foramen magnum under `ct-bone`; skin, airways and
//! bone under `ct-soft-tissue`; the carotid and vertebral arteries, the circle of
//! Willis and the dural venous sinuses under `ct-angio`. Slices show the brain
//! with its grey and white matter, ventricles and a small lesion.
//!
//! # Coordinates
//! Millimetres with the origin at the centre of the cube, which is [`EDGE_MM`]
//! wide: x towards the patient's left, y anterior, z superior. The face looks
//! towards +y, the vertex is at the top (+z) and the neck leaves through the
//! bottom of the cube. Voxel indices follow the volume's LPS geometry: index x
//! grows to the left, index y towards posterior (so anterior is low y), index z
//! towards superior.
//!
//! # Anatomy
//! Structures are painted in order, each setting the value inside it (a later
//! structure overwrites an earlier one), which makes holes and cavities simple:
//! the skull is a solid bony egg from which the brain's spaces, the orbits and
//! the sinuses are carved, and the vessels, painted last, run through bone.
//! Shapes are ellipsoids (centre, semi-axes), capsules (tubes with round ends:
//! a segment and a radius) and chains of capsules, some cut by planes.
//! Positions in mm (x, y, z); ± marks a left–right pair:
//!
//! - Skin (40 HU): of the scalp: an ellipsoid at (0, −10, 20), semi-axes (76, 98, 92); of the face:
//!   at (0, 20, −30), (66, 76, 72), and the lower face; a tube round the mandible; the neck at
//!   (0, −12, −125), (56, 58, 70), through the cube's bottom; the nose from (0, 86, −4) to
//!   (0, 104, −34); the ears at (±75, −14, −12).
//! - Subcutaneous fat (−90 HU): 4 mm under the skin.
//! - Muscle (50 HU): 7 mm under the skin of face, jaw and neck; temporalis and masseter at
//!   (±52, 4, −22).
//! - Skull vault (1000 HU): outer surface an ellipsoid at (0, −10, 20), semi-axes (70, 92, 86), cut
//!   below by the skull base z ≥ −48 + 0.3 y and beside it by ±x − z + 0.7 y ≤ 82; 7 mm thick:
//!   2.5 mm outer table, 2.5 mm diploë, 2 mm inner table.
//! - Diploë (700 HU): between the tables, and the marrow of the skull base.
//! - Facial skeleton (1000 HU): an ellipsoid at (0, 52, −22), (54, 32, 36); zygomatic arches from
//!   (±46, 46, −20) to (±60, 0, −24); the mandible from the condyles at (±50, −4, −28) down the
//!   rami and round to the chin at (0, 74, −97).
//! - Cervical spine (1000 HU): C1 ring at z = −68; C2 dens (tip at z = −56), body and arch; C3 body
//!   and arch; bodies at y = −8.
//! - Orbital fat (−80 HU): the orbits, ellipsoids at (±32, 58, −4), (18, 25, 17), their front ends
//!   turned 15° outwards, open forwards through the facial skeleton.
//! - Eyeballs, lenses, optic nerves (10, 100, 35 HU): eyeballs of radius 12 at (±32, 65, −4),
//!   lenses at y = 76, nerves back to the chiasm at (0, 20, 11).
//! - Air (−1000 HU): the nasal cavity at (0, 52, −26), (12, 38, 20), with a bony septum and
//!   turbinates; maxillary sinuses at (±28, 50, −36); the sphenoid sinus under the sella at
//!   (0, 24, −12); the airway, radius 7, from the nasopharynx at (0, 20, −38) down in front of the
//!   spine; ear canals at (y, z) = (−10, −16).
//! - Ethmoid cells (−800 HU): between the orbits at (0, 50, −2).
//! - Pituitary (45 HU): in the sella at (0, 14, 4).
//! - CSF spaces (6 HU): 2 mm between brain and skull; the interhemispheric fissure; the prepontine
//!   cistern; the foramen magnum, radius 14 about (0, −30), through the skull base at z ≈ −50; the
//!   spinal canal below it.
//! - Cortex, cerebellum (40 HU): the cerebrum above z = 7 + 0.2 y; temporal lobes at (±35, 8, −8)
//!   in the middle cranial fossae; the cerebellum at (0, −44, −26) in the posterior fossa.
//! - White matter (28 HU): an ellipsoid at (0, −10, 34), (46, 66, 42).
//! - Thalami, basal ganglia (38 HU): beside the third ventricle and the lateral ventricles.
//! - Brainstem, spinal cord (32 HU): from the midbrain at (0, −14, 8) through the foramen magnum;
//!   the cord of radius 5.
//! - Ventricles (6 HU): lateral: frontal horns at (±10, 20, 28), bodies at (±11, −6, 32), atria and
//!   occipital horns to (±22, −52, 20), temporal horns; third at (0, −6, 18); aqueduct; fourth at
//!   (0, −36, −30).
//! - Lesion (75 HU in oedema of 18 HU): an enhancing mass of radius 6 in oedema of radius 13, right
//!   frontal lobe, at (−32, 36, 34).
//! - Contrast-filled arteries (380 HU): internal carotids, radius 2.6, from (±24, 2, −125) through
//!   the skull base and beside the sella to (±14, 16, 12); the circle of Willis at z ≈ 10–16;
//!   anterior, middle (to the insula at (±46, 8, 24), three branches) and posterior cerebral
//!   arteries; vertebral arteries from (±24, −20, −125) through the foramen magnum into the
//!   basilar.
//! - Contrast-filled venous sinuses (280 HU): the superior sagittal sinus under the vault's midline
//!   to the torcula at (0, −85, −4); transverse and sigmoid sinuses; internal jugular veins at
//!   (±36, −6).
//!
//! All cortical bone is 1000 HU, the densest value, and air −1000 HU; contrast
//! (280–380 HU) lies below the bone ramp of `ct-angio` and above its soft tissue.
//! A little zero-mean noise (σ ≈ 5 HU) from a hash of the voxel index is added,
//! so the phantom is the same on every machine and every run.
//!
//! Stored as 16-bit unsigned values with the usual CT offset: stored = HU + 1024,
//! so the value map is slope 1, intercept −1024.
//!
//! # Soft edges
//! Edges are soft, as in a real scan, where the scanner's point-spread function
//! and partial volume blur every boundary over a voxel or two: a voxel's share of
//! a structure falls from 1 to 0 over ±[`EDGE_VOXELS`] of its approximate signed
//! distance to the surface, and the voxel takes `v·(1 − share) + value·share`.
//! Without this, gradient shading shows every voxel step of the surfaces as
//! terraces. The edge is 2 voxels each side (about a Gaussian blur of σ = 0.9
//! voxel), not 1.5 or 1: a sharper smooth step is not band-limited enough for
//! the voxel grid, and where a surface crosses the voxel planes at a slant
//! its reconstructed normal tilts back and forth with the offset, which
//! draws concentric rings, one per voxel slice, on every smooth surface seen
//! head-on (at ±1.5 voxels they showed faintly on the vertex under gradient
//! shading, whatever the step or the gradient filter).
//!
//! # Generation
//! Row by row: along a row of constant y and z each structure (convex, and cut
//! by planes only into a convex piece) covers one interval of x, found in
//! closed form. Voxels deep
//! inside the interval are filled with the structure's value; only the few
//! voxels in the soft band near the surface evaluate a distance. The deep and
//! outer intervals are chosen so that the voxels they leave out have a share of
//! exactly 1 or 0, so the result is the same as evaluating every structure at
//! every voxel. Slices are generated in parallel; each voxel's value depends on
//! its position alone, so the bytes do not depend on the scheduling.

use rayon::prelude::*;

use crate::geometry::IDENTITY_DIRECTION;
use crate::{Error, Geometry, ValueMap, Volume, VoxelData};

/// The default edge length in voxels.
pub const DEFAULT_SIZE: u32 = 256;
/// The smallest edge length accepted.
pub const MIN_SIZE: u32 = 16;
/// The largest edge length accepted (512³ × 2 bytes = 256 MiB).
pub const MAX_SIZE: u32 = 512;
/// The physical edge of the phantom's cube, in millimetres (a head fits in it).
pub const EDGE_MM: f32 = 240.0;
/// The value of air, outside the head and in its airways.
pub const AIR_HU: f32 = -1000.0;
/// Peak-to-peak amplitude of the triangular noise (σ = amplitude / √6 ≈ 4.9 HU).
const NOISE_HU: f32 = 12.0;
/// Stored value = HU + this offset.
const STORED_OFFSET: f32 = 1024.0;
/// Half-width of the soft edge, in voxels (see the module docs).
pub const EDGE_VOXELS: f32 = 2.0;
/// The deep and outer intervals of a row keep this much beyond the soft edge,
/// in voxels, so that rounding never puts a voxel with a share strictly
/// between 0 and 1 outside the band that evaluates it.
const SPAN_MARGIN_VOXELS: f32 = 0.05;

// Tissue values, Hounsfield units.
const SKIN: f32 = 40.0;
const FAT: f32 = -90.0;
const MUSCLE: f32 = 50.0;
const BONE: f32 = 1000.0;
const DIPLOE: f32 = 700.0;
const CSF: f32 = 6.0;
const GREY: f32 = 40.0;
const WHITE: f32 = 28.0;
const DEEP_GREY: f32 = 38.0;
const BRAINSTEM: f32 = 32.0;
const ORBITAL_FAT: f32 = -80.0;
const VITREOUS: f32 = 10.0;
const LENS: f32 = 100.0;
const NERVE: f32 = 35.0;
const ETHMOID: f32 = -800.0;
const PITUITARY: f32 = 45.0;
const OEDEMA: f32 = 18.0;
const LESION: f32 = 75.0;
const ARTERY: f32 = 380.0;
const VEIN: f32 = 280.0;

/// The centre of the lesion, in the right frontal lobe.
const LESION_CENTER: [f32; 3] = [-32.0, 36.0, 34.0];

/// The centre of the ellipsoid of the skull vault's outer surface, mm.
const VAULT_CENTER: [f32; 3] = [0.0, -10.0, 20.0];
/// The semi-axes of the ellipsoid of the skull vault's outer surface, mm.
const VAULT_SEMI: [f32; 3] = [70.0, 92.0, 86.0];

/// A convex shape, in millimetres (x left, y anterior, z superior).
#[derive(Debug, Clone, Copy)]
enum Shape {
    /// An ellipsoid turned about the z axis by the angle whose sine and cosine
    /// are given (a positive angle turns +y towards −x).
    Ellipsoid {
        center: [f32; 3],
        semi: [f32; 3],
        sin: f32,
        cos: f32,
    },
    /// The points within `radius` of the segment from `a` to `b`: a tube with
    /// round ends.
    Capsule {
        a: [f32; 3],
        b: [f32; 3],
        radius: f32,
    },
}

/// A plane that cuts a shape: points with normal · p ≤ offset stay.
#[derive(Debug, Clone, Copy)]
struct Cut {
    /// Unit normal, pointing out of the part that stays.
    normal: [f32; 3],
    offset: f32,
}

impl Cut {
    /// Keeps normal · p ≤ offset; `normal` need not have unit length.
    fn new(normal: [f32; 3], offset: f32) -> Cut {
        let len = dot(normal, normal).sqrt();
        Cut {
            normal: normal.map(|c| c / len),
            offset: offset / len,
        }
    }

    /// Keeps z ≥ z0 + slope·y: a floor sloping along y.
    fn above(z0: f32, slope: f32) -> Cut {
        Cut::new([0.0, slope, -1.0], -z0)
    }

    /// Signed distance to the plane, mm, negative on the side that stays.
    fn signed_distance(self, p: [f32; 3]) -> f32 {
        dot(self.normal, p) - self.offset
    }

    /// The same plane moved `by` mm into the side that stays.
    fn inset(self, by: f32) -> Cut {
        Cut {
            offset: self.offset - by,
            ..self
        }
    }

    /// The x interval of the row at (y, z) where the signed distance is at
    /// most `reach`: everything, nothing or a half-line.
    fn span(self, y: f32, z: f32, reach: f32) -> Option<(f32, f32)> {
        let [nx, ny, nz] = self.normal;
        let rest = self.offset + reach - ny * y - nz * z;
        if nx.abs() < 1e-6 {
            (rest >= 0.0).then_some((f32::NEG_INFINITY, f32::INFINITY))
        } else if nx > 0.0 {
            Some((f32::NEG_INFINITY, rest / nx))
        } else {
            Some((rest / nx, f32::INFINITY))
        }
    }
}

/// One structure: a shape, perhaps cut by planes, and the value inside it.
#[derive(Debug, Clone)]
struct Part {
    shape: Shape,
    cuts: Vec<Cut>,
    hu: f32,
}

/// An axis-aligned ellipsoid.
fn ellipsoid(center: [f32; 3], semi: [f32; 3]) -> Shape {
    turned(center, semi, 0.0)
}

/// An ellipsoid turned about the z axis by `deg` degrees (positive turns its
/// +y semi-axis towards −x).
fn turned(center: [f32; 3], semi: [f32; 3], deg: f32) -> Shape {
    let (sin, cos) = deg.to_radians().sin_cos();
    Shape::Ellipsoid {
        center,
        semi,
        sin,
        cos,
    }
}

/// A sphere.
fn sphere(center: [f32; 3], radius: f32) -> Shape {
    ellipsoid(center, [radius; 3])
}

/// A capsule: the points within `radius` of the segment from `a` to `b`.
fn capsule(a: [f32; 3], b: [f32; 3], radius: f32) -> Shape {
    Shape::Capsule { a, b, radius }
}

/// A bent tube through `points`: one capsule per segment.
fn tube(points: &[[f32; 3]], radius: f32) -> Vec<Shape> {
    points
        .windows(2)
        .map(|w| capsule(w[0], w[1], radius))
        .collect()
}

/// The vault's ellipsoid moved inwards by `inset` mm (outwards when negative).
fn vault(inset: f32) -> Shape {
    ellipsoid(VAULT_CENTER, VAULT_SEMI.map(|s| s - inset))
}

/// An ellipsoid with every semi-axis `by` mm shorter.
fn shrunk(shape: Shape, by: f32) -> Shape {
    match shape {
        Shape::Ellipsoid {
            center,
            semi,
            sin,
            cos,
        } => Shape::Ellipsoid {
            center,
            semi: semi.map(|s| s - by),
            sin,
            cos,
        },
        Shape::Capsule { a, b, radius } => Shape::Capsule {
            a,
            b,
            radius: radius - by,
        },
    }
}

impl Shape {
    /// The shape mirrored from the patient's left to the right (x → −x).
    fn mirrored(self) -> Shape {
        let flip = |p: [f32; 3]| [-p[0], p[1], p[2]];
        match self {
            Shape::Ellipsoid {
                center,
                semi,
                sin,
                cos,
            } => Shape::Ellipsoid {
                center: flip(center),
                semi,
                sin: -sin,
                cos,
            },
            Shape::Capsule { a, b, radius } => Shape::Capsule {
                a: flip(a),
                b: flip(b),
                radius,
            },
        }
    }

    /// Approximate signed distance from `p` to the surface, mm, negative inside.
    /// Exact for a capsule; for an ellipsoid the implicit function over its
    /// gradient's length, exact to first order near the surface, which is all
    /// the soft edge needs.
    fn signed_distance(&self, p: [f32; 3]) -> f32 {
        match *self {
            Shape::Ellipsoid {
                center,
                semi,
                sin,
                cos,
            } => {
                let (dx, dy) = (p[0] - center[0], p[1] - center[1]);
                let q = [cos * dx + sin * dy, -sin * dx + cos * dy, p[2] - center[2]];
                let (mut f, mut grad2) = (-1.0f32, 0.0f32);
                for (q, a) in q.into_iter().zip(semi) {
                    f += (q / a) * (q / a);
                    grad2 += (2.0 * q / (a * a)).powi(2);
                }
                let grad = grad2.sqrt();
                if grad > f32::EPSILON {
                    f / grad
                } else {
                    f32::NEG_INFINITY
                }
            }
            Shape::Capsule { a, b, radius } => {
                let u = sub(b, a);
                let w = sub(p, a);
                let t = (dot(w, u) / dot(u, u).max(f32::MIN_POSITIVE)).clamp(0.0, 1.0);
                let r = sub(w, u.map(|c| c * t));
                dot(r, r).sqrt() - radius
            }
        }
    }

    /// The x interval of the row at (`y`, `z`) that holds every point whose
    /// signed distance is below `reach` mm when `reach` > 0 (points outside it
    /// are at least `reach` away), or only points whose signed distance is at
    /// most `reach` when `reach` < 0 (points inside it are at least −`reach`
    /// deep); `None` when that interval is empty.
    fn span(&self, y: f32, z: f32, reach: f32) -> Option<(f32, f32)> {
        match *self {
            Shape::Ellipsoid {
                center,
                semi,
                sin,
                cos,
            } => {
                let scale = reach_scale(semi, reach);
                ellipsoid_row(center, semi.map(|s| s * scale), sin, cos, y, z)
            }
            Shape::Capsule { a, b, radius } => {
                let r = radius + reach;
                if r <= 0.0 {
                    return None;
                }
                capsule_row(a, b, r, y, z)
            }
        }
    }

    /// The bounding box, `[min, max]` per axis, of the shape grown so that its
    /// `span` for `reach` lies inside.
    fn bounds(&self, reach: f32) -> [[f32; 2]; 3] {
        match *self {
            Shape::Ellipsoid {
                center,
                semi,
                sin,
                cos,
            } => {
                let scale = reach_scale(semi, reach.abs());
                let [a, b, c] = semi.map(|s| s * scale);
                let half = [(a * cos).hypot(b * sin), (a * sin).hypot(b * cos), c];
                std::array::from_fn(|i| [center[i] - half[i], center[i] + half[i]])
            }
            Shape::Capsule { a, b, radius } => {
                let r = radius + reach.max(0.0);
                std::array::from_fn(|i| [a[i].min(b[i]) - r, a[i].max(b[i]) + r])
            }
        }
    }
}

fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The roots of A t² + B t + C = 0 with A > 0, or `None` when there are none.
fn roots(qa: f32, qb: f32, qc: f32) -> Option<(f32, f32)> {
    let disc = qb * qb - 4.0 * qa * qc;
    if disc < 0.0 {
        return None;
    }
    let root = disc.sqrt();
    Some(((-qb - root) / (2.0 * qa), (-qb + root) / (2.0 * qa)))
}

/// The x interval of the row at (y, z) inside an ellipsoid turned about z.
fn ellipsoid_row(
    center: [f32; 3],
    semi: [f32; 3],
    sin: f32,
    cos: f32,
    y: f32,
    z: f32,
) -> Option<(f32, f32)> {
    let [a, b, c] = semi;
    if a <= 0.0 || b <= 0.0 || c <= 0.0 {
        return None;
    }
    let dy = y - center[1];
    let dz = z - center[2];
    // With dx = x − cx, the turned point is q = (cos dx + sin dy, −sin dx + cos dy, dz),
    // and (qx/a)² + (qy/b)² + (qz/c)² ≤ 1 is a quadratic A dx² + B dx + C ≤ 0.
    let (a2, b2) = (a * a, b * b);
    let qa = cos * cos / a2 + sin * sin / b2;
    let qb = 2.0 * sin * cos * dy * (1.0 / a2 - 1.0 / b2);
    let qc = (sin * dy).powi(2) / a2 + (cos * dy).powi(2) / b2 + dz * dz / (c * c) - 1.0;
    let (x0, x1) = roots(qa, qb, qc)?;
    Some((center[0] + x0, center[0] + x1))
}

/// The x interval of the row at (y, z) within `r` of the segment from `a` to
/// `b`: the hull of the intervals inside the two end spheres and the
/// cylinder between them, whose union is convex.
fn capsule_row(a: [f32; 3], b: [f32; 3], r: f32, y: f32, z: f32) -> Option<(f32, f32)> {
    let sphere_row = |c: [f32; 3]| {
        let rest = r * r - (y - c[1]).powi(2) - (z - c[2]).powi(2);
        (rest >= 0.0).then(|| (c[0] - rest.sqrt(), c[0] + rest.sqrt()))
    };
    let u = sub(b, a);
    let len2 = dot(u, u);
    let cylinder = (len2 > f32::EPSILON)
        .then(|| {
            // With s = x − ax and w = (s, y − ay, z − az): the projection
            // t = (s ux + P) / L² must lie in 0..=1, and the squared distance
            // to the axis |w|² − (w·u)²/L² is a quadratic in s.
            let (wy, wz) = (y - a[1], z - a[2]);
            let p = wy * u[1] + wz * u[2];
            let qa = 1.0 - u[0] * u[0] / len2;
            let qb = -2.0 * u[0] * p / len2;
            let qc = wy * wy + wz * wz - p * p / len2 - r * r;
            let (mut s0, mut s1) = if qa > 1e-6 {
                roots(qa, qb, qc)?
            } else if qc <= 0.0 {
                (f32::NEG_INFINITY, f32::INFINITY)
            } else {
                return None;
            };
            if u[0].abs() > 1e-6 {
                let (t0, t1) = (-p / u[0], (len2 - p) / u[0]);
                s0 = s0.max(t0.min(t1));
                s1 = s1.min(t0.max(t1));
            } else if !(0.0..=len2).contains(&p) {
                return None;
            }
            (s0 <= s1).then_some((a[0] + s0, a[0] + s1))
        })
        .flatten();
    [sphere_row(a), sphere_row(b), cylinder]
        .into_iter()
        .flatten()
        .reduce(|(l0, h0), (l1, h1)| (l0.min(l1), h0.max(h1)))
}

impl Part {
    /// Signed distance, mm: the largest of the shape's and the cuts'.
    fn signed_distance(&self, p: [f32; 3]) -> f32 {
        self.cuts
            .iter()
            .fold(self.shape.signed_distance(p), |d, cut| {
                d.max(cut.signed_distance(p))
            })
    }

    /// [`Shape::span`] within the cuts: the intersection of the shape's
    /// interval with each cut's.
    fn span(&self, y: f32, z: f32, reach: f32) -> Option<(f32, f32)> {
        self.cuts
            .iter()
            .try_fold(self.shape.span(y, z, reach)?, |(x0, x1), cut| {
                let (c0, c1) = cut.span(y, z, reach)?;
                let (x0, x1) = (x0.max(c0), x1.min(c1));
                (x0 <= x1).then_some((x0, x1))
            })
    }
}

/// The head's structures in painting order.
#[derive(Debug, Default)]
struct Anatomy(Vec<Part>);

impl Anatomy {
    /// Sets `hu` inside each shape.
    fn paint(&mut self, hu: f32, shapes: impl IntoIterator<Item = Shape>) {
        self.0.extend(shapes.into_iter().map(|shape| Part {
            shape,
            cuts: Vec::new(),
            hu,
        }));
    }

    /// Sets `hu` inside each shape and its mirror image (x → −x).
    fn paint_both(&mut self, hu: f32, shapes: impl IntoIterator<Item = Shape>) {
        let shapes: Vec<Shape> = shapes.into_iter().collect();
        let mirrored: Vec<Shape> = shapes.iter().map(|s| s.mirrored()).collect();
        self.paint(hu, shapes);
        self.paint(hu, mirrored);
    }

    /// Sets `hu` inside `shape` where every cut keeps it.
    fn paint_cut(&mut self, hu: f32, shape: Shape, cuts: &[Cut]) {
        self.0.push(Part {
            shape,
            cuts: cuts.to_vec(),
            hu,
        });
    }
}

/// The phantom's structures, in the order they are painted (see the module
/// docs for the table). Shapes given once with a `paint_both` are the
/// patient's left ones (x > 0).
fn anatomy() -> Vec<Part> {
    let mut head = Anatomy::default();
    // Bone of the vault is kept above the skull base, z ≥ −48 + 0.3 y, and,
    // on each side, where ±x − z + 0.7 y ≤ 82: below the middle cranial fossae
    // the egg is cut away laterally, leaving the temporal and infratemporal
    // fossae to soft tissue and the zygomatic arches free.
    let skull = [
        Cut::above(-48.0, 0.3),
        Cut::new([1.0, 0.7, -1.0], 82.0),
        Cut::new([-1.0, 0.7, -1.0], 82.0),
    ];
    let skull_inset = |by: f32| skull.map(|c| c.inset(by));
    // The floor of the cerebrum's space: the anterior cranial fossa over the
    // orbits, sloping down backwards to the tentorium.
    let cerebrum_floor = Cut::above(5.0, 0.2);

    // Soft tissues as layers over the union of the scalp, face, jaw and neck:
    // every shape's skin, then every shape's fat 4 mm in, then muscle 7 mm in
    // (4 mm of skin: enough to reach its value between soft edges of ±2
    // voxels at 256³).
    let face = ellipsoid([0.0, 20.0, -30.0], [66.0, 76.0, 72.0]);
    let lower_face = ellipsoid([0.0, 30.0, -76.0], [50.0, 56.0, 26.0]);
    let neck = ellipsoid([0.0, -12.0, -125.0], [56.0, 58.0, 70.0]);
    let ramus = [[50.0, -4.0, -28.0], [46.0, 4.0, -82.0]];
    let mandible = [
        [46.0, 4.0, -82.0],
        [38.0, 40.0, -92.0],
        [20.0, 66.0, -96.0],
        [0.0, 74.0, -97.0],
    ];
    let jaw = |radius: f32| {
        let mut shapes = tube(&ramus, radius);
        shapes.extend(tube(&mandible, radius));
        shapes
    };
    let skin = [vault(-6.0), face, lower_face, neck];
    head.paint(SKIN, skin);
    head.paint_both(SKIN, jaw(16.0));
    head.paint(SKIN, [capsule([0.0, 86.0, -4.0], [0.0, 104.0, -34.0], 7.0)]);
    head.paint_both(SKIN, [ellipsoid([75.0, -14.0, -12.0], [5.0, 12.0, 26.0])]);
    head.paint(FAT, skin.map(|s| shrunk(s, 4.0)));
    head.paint_both(FAT, jaw(12.0));
    // Under the scalp lies bone, painted below; beside the skull base, the
    // temporalis and masseter.
    head.paint(MUSCLE, [face, lower_face, neck].map(|s| shrunk(s, 7.0)));
    head.paint_both(MUSCLE, jaw(9.0));
    head.paint_both(MUSCLE, [ellipsoid([52.0, 4.0, -22.0], [12.0, 28.0, 32.0])]);

    // Bone: the vault as a solid egg cut by the skull base, the facial
    // skeleton, mandible and the upper cervical spine; then the diploë and
    // the inner table.
    head.paint_cut(BONE, vault(0.0), &skull);
    head.paint(BONE, [ellipsoid([0.0, 52.0, -22.0], [54.0, 32.0, 36.0])]);
    head.paint_both(
        BONE,
        [capsule([46.0, 46.0, -20.0], [60.0, 0.0, -24.0], 3.5)],
    );
    head.paint_both(BONE, tube(&ramus, 5.0));
    head.paint_both(BONE, tube(&mandible, 6.0));
    head.paint(
        BONE,
        [
            // C1: a ring round the canal, carved below.
            ellipsoid([0.0, -26.0, -68.0], [34.0, 30.0, 5.5]),
            // C2: dens, body and arch.
            capsule([0.0, -8.0, -82.0], [0.0, -8.0, -61.0], 5.5),
            capsule([0.0, -8.0, -94.0], [0.0, -8.0, -85.0], 8.0),
            ellipsoid([0.0, -28.0, -90.0], [24.0, 26.0, 5.0]),
            // C3: body and arch.
            capsule([0.0, -8.0, -122.0], [0.0, -8.0, -114.0], 8.0),
            ellipsoid([0.0, -28.0, -116.0], [24.0, 26.0, 5.0]),
        ],
    );
    head.paint_cut(DIPLOE, vault(2.5), &skull_inset(2.5));
    head.paint_cut(BONE, vault(5.0), &skull_inset(5.0));

    // Cavities carved in the bone: orbits, nasal cavity and sinuses, ear
    // canals, airway, the sella, the foramen magnum and the spinal canal.
    // The orbits open forwards through the facial skeleton and stop 3 mm
    // under the skin, behind the eyelids.
    let orbit = turned([32.0, 58.0, -4.0], [18.0, 25.0, 17.0], -15.0);
    let eyelids = Cut::new([0.0, 1.0, 0.0], 78.0);
    head.paint_cut(ORBITAL_FAT, orbit, &[eyelids]);
    head.paint_cut(ORBITAL_FAT, orbit.mirrored(), &[eyelids]);
    head.paint(
        AIR_HU,
        [
            ellipsoid([0.0, 52.0, -26.0], [12.0, 38.0, 20.0]),
            // The front of the nasal cavity, behind the piriform aperture.
            ellipsoid([0.0, 80.0, -28.0], [12.0, 12.0, 16.0]),
            // The sphenoid sinus, under the sella.
            ellipsoid([0.0, 24.0, -12.0], [11.0, 12.0, 10.0]),
        ],
    );
    head.paint(ETHMOID, [ellipsoid([0.0, 50.0, -2.0], [10.0, 22.0, 11.0])]);
    head.paint_both(AIR_HU, [ellipsoid([28.0, 50.0, -36.0], [13.0, 19.0, 12.0])]);
    head.paint_both(
        AIR_HU,
        [capsule([44.0, -10.0, -16.0], [82.0, -10.0, -16.0], 3.5)],
    );
    head.paint(
        AIR_HU,
        tube(
            &[
                [0.0, 20.0, -38.0],
                [0.0, 14.0, -70.0],
                [0.0, 16.0, -100.0],
                [0.0, 18.0, -125.0],
            ],
            7.0,
        ),
    );
    head.paint(
        CSF,
        [
            capsule([0.0, -30.0, -62.0], [0.0, -30.0, -46.0], 14.0),
            capsule([0.0, -30.0, -125.0], [0.0, -30.0, -62.0], 9.0),
        ],
    );
    head.paint(DIPLOE, [ellipsoid([0.0, 56.0, -24.0], [1.5, 32.0, 17.0])]);
    head.paint_both(
        SKIN,
        [
            capsule([8.0, 30.0, -38.0], [8.0, 78.0, -36.0], 3.5),
            capsule([8.0, 34.0, -24.0], [8.0, 74.0, -22.0], 3.0),
        ],
    );
    head.paint(PITUITARY, [ellipsoid([0.0, 14.0, 4.0], [6.0, 5.0, 4.5])]);

    // The orbits' contents.
    head.paint_both(VITREOUS, [sphere([32.0, 65.0, -4.0], 12.0)]);
    head.paint_both(LENS, [ellipsoid([32.0, 76.0, -4.0], [4.5, 2.0, 4.5])]);
    head.paint_both(
        NERVE,
        tube(
            &[[30.0, 54.0, -4.0], [12.0, 30.0, 8.0], [0.0, 20.0, 11.0]],
            2.5,
        ),
    );

    // The brain's spaces (CSF), then the brain 2 mm inside them.
    head.paint_cut(CSF, vault(7.0), &[cerebrum_floor]);
    let temporal = ellipsoid([35.0, 8.0, -8.0], [19.0, 24.0, 18.0]);
    let posterior_fossa = ellipsoid([0.0, -44.0, -26.0], [40.0, 30.0, 22.0]);
    head.paint_both(CSF, [temporal]);
    head.paint(
        CSF,
        [
            posterior_fossa,
            // The prepontine cistern along the clivus.
            capsule([0.0, -2.0, 4.0], [0.0, -18.0, -48.0], 9.0),
        ],
    );
    head.paint_cut(GREY, vault(9.0), &[cerebrum_floor.inset(2.0)]);
    head.paint_both(GREY, [shrunk(temporal, 2.0)]);
    head.paint(GREY, [shrunk(posterior_fossa, 2.0)]);
    head.paint_cut(
        WHITE,
        ellipsoid([0.0, -10.0, 34.0], [46.0, 66.0, 42.0]),
        &[cerebrum_floor.inset(8.0)],
    );
    head.paint_both(
        DEEP_GREY,
        [
            // Thalamus, lentiform nucleus, head of the caudate.
            ellipsoid([11.0, -12.0, 18.0], [9.0, 15.0, 9.0]),
            ellipsoid([24.0, 6.0, 18.0], [6.0, 14.0, 10.0]),
            ellipsoid([14.0, 18.0, 26.0], [5.0, 8.0, 7.0]),
        ],
    );
    head.paint(
        BRAINSTEM,
        [
            capsule([0.0, -14.0, 8.0], [0.0, -24.0, -40.0], 9.0),
            capsule([0.0, -24.0, -40.0], [0.0, -30.0, -58.0], 6.5),
            capsule([0.0, -30.0, -58.0], [0.0, -30.0, -125.0], 5.0),
        ],
    );

    // CSF inside the brain: the interhemispheric fissure and the ventricles.
    head.paint_cut(
        CSF,
        ellipsoid(VAULT_CENTER, [2.0, 73.0, 67.0]),
        &[Cut::above(36.0, 0.0)],
    );
    head.paint_both(
        CSF,
        [
            // Body, frontal horn, atrium and occipital horn, temporal horn.
            turned([11.0, -6.0, 32.0], [5.5, 24.0, 6.0], 8.0),
            turned([10.0, 20.0, 28.0], [5.0, 11.0, 8.0], -15.0),
            capsule([16.0, -28.0, 28.0], [22.0, -52.0, 20.0], 6.0),
            capsule([22.0, -30.0, 22.0], [32.0, 4.0, -10.0], 3.0),
        ],
    );
    head.paint(
        CSF,
        [
            // Third ventricle, aqueduct, fourth ventricle.
            ellipsoid([0.0, -6.0, 18.0], [2.5, 14.0, 9.0]),
            capsule([0.0, -14.0, 10.0], [0.0, -32.0, -24.0], 1.5),
            ellipsoid([0.0, -36.0, -30.0], [5.0, 4.0, 8.0]),
        ],
    );

    // A small enhancing mass in oedema, in the right frontal lobe.
    head.paint(OEDEMA, [sphere(LESION_CENTER, 13.0)]);
    head.paint(LESION, [sphere(LESION_CENTER, 6.0)]);

    // Contrast-filled vessels, painted last so they run through bone too:
    // internal carotid arteries from the neck through the skull base and
    // the cavernous sinus; vertebral arteries joining into the basilar.
    head.paint_both(
        ARTERY,
        tube(
            &[
                [24.0, 2.0, -125.0],
                [24.0, 2.0, -62.0],
                [22.0, 4.0, -46.0],
                [18.0, 16.0, -36.0],
                [15.0, 22.0, -20.0],
                [15.0, 24.0, -2.0],
                [14.0, 16.0, 12.0],
            ],
            2.6,
        ),
    );
    head.paint_both(
        ARTERY,
        tube(
            &[
                [24.0, -20.0, -125.0],
                [24.0, -20.0, -74.0],
                [16.0, -36.0, -63.0],
                [7.0, -26.0, -52.0],
                [0.0, -12.0, -44.0],
            ],
            2.0,
        ),
    );
    head.paint(
        ARTERY,
        [
            // Basilar artery, anterior communicating artery.
            capsule([0.0, -12.0, -44.0], [0.0, -4.0, 10.0], 1.8),
            capsule([-3.0, 28.0, 16.0], [3.0, 28.0, 16.0], 1.2),
        ],
    );
    let cerebral_arteries: [(&[[f32; 3]], f32); 9] = [
        // The circle of Willis: A1 to the anterior communicating artery,
        // posterior communicating artery, P1 from the basilar tip.
        (&[[14.0, 16.0, 12.0], [3.0, 28.0, 16.0]], 1.4),
        (&[[14.0, 16.0, 12.0], [9.0, -2.0, 10.0]], 1.1),
        (&[[0.0, -4.0, 10.0], [9.0, -2.0, 10.0]], 1.4),
        // Anterior cerebral artery, round the corpus callosum.
        (
            &[
                [3.0, 28.0, 16.0],
                [2.5, 46.0, 26.0],
                [2.5, 44.0, 50.0],
                [2.5, 14.0, 66.0],
                [2.5, -30.0, 64.0],
                [2.5, -56.0, 46.0],
            ],
            1.3,
        ),
        // Middle cerebral artery to the insula, and three branches.
        (
            &[[14.0, 16.0, 12.0], [36.0, 16.0, 14.0], [46.0, 8.0, 24.0]],
            1.6,
        ),
        (
            &[[46.0, 8.0, 24.0], [52.0, 26.0, 38.0], [42.0, 38.0, 46.0]],
            1.1,
        ),
        (
            &[[46.0, 8.0, 24.0], [54.0, -18.0, 36.0], [48.0, -44.0, 42.0]],
            1.1,
        ),
        (
            &[[46.0, 8.0, 24.0], [54.0, -2.0, 50.0], [44.0, -6.0, 66.0]],
            1.1,
        ),
        // Posterior cerebral artery, over the tentorium.
        (
            &[
                [9.0, -2.0, 10.0],
                [24.0, -22.0, 12.0],
                [24.0, -50.0, 14.0],
                [14.0, -76.0, 16.0],
            ],
            1.3,
        ),
    ];
    for (points, radius) in cerebral_arteries {
        head.paint_both(ARTERY, tube(points, radius));
    }

    // Venous sinuses: the superior sagittal sinus follows the vault's midline
    // 2.5 mm inside the brain's space (so that even at coarse sizes its soft
    // edge leaves the inner table whole), from the frontal region to the
    // torcula; the transverse and sigmoid sinuses lead to the internal
    // jugular veins.
    let [_, sy, sz] = VAULT_SEMI.map(|s| s - 13.0);
    let sagittal: Vec<[f32; 3]> = (0..8)
        .map(|i| {
            let angle = (25.0 + 25.0 * i as f32).to_radians();
            [
                0.0,
                VAULT_CENTER[1] + sy * angle.cos(),
                VAULT_CENTER[2] + sz * angle.sin(),
            ]
        })
        .chain([[0.0, -85.0, -4.0]])
        .collect();
    head.paint(VEIN, tube(&sagittal, 3.5));
    head.paint_both(
        VEIN,
        tube(
            &[
                [0.0, -85.0, -4.0],
                [26.0, -73.0, -6.0],
                [45.0, -45.0, -6.0],
                [52.0, -22.0, -8.0],
                [50.0, -24.0, -30.0],
                [44.0, -20.0, -50.0],
                [36.0, -8.0, -70.0],
                [36.0, -6.0, -125.0],
            ],
            3.5,
        ),
    );
    head.0
}

/// The factor by which an ellipsoid of semi-axes `semi` scales so that
/// points outside the scaled one lie at least `reach` mm outside it (`reach`
/// ≥ 0), or points inside it at least −`reach` deep (`reach` < 0). With f
/// the implicit function (Σ (q/a)² − 1) and a_min the shortest semi-axis,
/// |∇f| ≤ 2√(f + 1) / a_min, so the signed distance f/|∇f| is at least reach
/// outside the ellipsoid scaled by k + √(k² + 1), and at most reach inside
/// the one scaled by √(k² + 1) − k, with k = |reach| / a_min.
fn reach_scale(semi: [f32; 3], reach: f32) -> f32 {
    let a_min = semi[0].min(semi[1]).min(semi[2]);
    let k = reach.abs() / a_min;
    let root = (k * k + 1.0).sqrt();
    if reach >= 0.0 { root + k } else { root - k }
}

/// The share of a voxel inside a surface at signed distance `d` voxels: 1 deep
/// inside, 0 far outside, a smooth step over ±[`EDGE_VOXELS`].
fn coverage(d: f32) -> f32 {
    let t = ((EDGE_VOXELS - d) / (2.0 * EDGE_VOXELS)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// SplitMix64: a fast, well-mixed hash of the voxel index for the noise.
fn splitmix64(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    x = (x ^ (x >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    x ^ (x >> 31)
}

/// Zero-mean triangular noise in −NOISE_HU/2 ..= NOISE_HU/2 for a voxel index.
fn noise_hu(index: u64) -> f32 {
    let h = splitmix64(index);
    let unit = |bits: u64| (bits & 0xff_ffff) as f32 / 16_777_216.0;
    (unit(h) + unit(h >> 32) - 1.0) * (NOISE_HU * 0.5)
}

/// Generates the head phantom as a cube of `size`³ voxels.
///
/// `size` must lie in [`MIN_SIZE`]..=[`MAX_SIZE`]. The cube is [`EDGE_MM`] wide
/// whatever the size, so the spacing is `EDGE_MM / size` on every axis, and it is
/// centred on the physical origin.
pub fn head(size: u32) -> Result<Volume, Error> {
    if !(MIN_SIZE..=MAX_SIZE).contains(&size) {
        return Err(Error::OutOfRange {
            what: "phantom size",
            value: size.to_string(),
            expected: format!("an edge length in voxels from {MIN_SIZE} to {MAX_SIZE}"),
        });
    }
    let grid = Grid::new(size);
    let parts = anatomy();
    let bounds: Vec<[[f32; 2]; 3]> = parts.iter().map(|p| p.shape.bounds(grid.reach())).collect();
    let n = grid.n();
    let mut voxels = vec![0u16; n * n * n];
    voxels
        .par_chunks_mut(n * n)
        .enumerate()
        .for_each(|(k, slice)| fill_slice(grid, &parts, &bounds, k, slice));
    // Worked out in f32, as the phantom always has, so its stores keep the
    // same numbers.
    let spacing = EDGE_MM / size as f32;
    let centre = -(size as f32 - 1.0) * 0.5 * spacing;
    let geometry = Geometry {
        dims: [size; 3],
        spacing: [f64::from(spacing); 3],
        origin: [f64::from(centre); 3],
        direction: IDENTITY_DIRECTION,
    };
    let mut volume = Volume::new(
        "head phantom",
        geometry,
        VoxelData::U16(voxels),
        ValueMap {
            slope: 1.0,
            intercept: -STORED_OFFSET,
        },
    )?;
    volume.unit = Some("HU".into());
    volume.modality = Some("CT".into());
    Ok(volume)
}

/// The voxel grid of a `size`³ phantom, in millimetres.
#[derive(Debug, Clone, Copy)]
struct Grid {
    size: u32,
    /// Voxel spacing, mm.
    spacing: f32,
}

impl Grid {
    fn new(size: u32) -> Grid {
        Grid {
            size,
            spacing: EDGE_MM / size as f32,
        }
    }

    /// Voxels along each axis.
    fn n(self) -> usize {
        self.size as usize
    }

    /// The coordinate of voxel `i`'s centre along an axis, mm.
    fn centre(self, i: usize) -> f32 {
        (i as f32 + 0.5) * self.spacing - EDGE_MM * 0.5
    }

    /// How far from a surface, mm, a voxel's share is still strictly between
    /// 0 and 1 (with a margin for rounding).
    fn reach(self) -> f32 {
        (EDGE_VOXELS + SPAN_MARGIN_VOXELS) * self.spacing
    }

    /// The first voxel whose centre lies at or after `x`.
    fn first(self, x: f32) -> usize {
        ((x + EDGE_MM * 0.5) / self.spacing - 0.5).ceil().max(0.0) as usize
    }

    /// The last voxel whose centre lies at or before `x`, or `None` when none does.
    fn last(self, x: f32) -> Option<usize> {
        let i = ((x + EDGE_MM * 0.5) / self.spacing - 0.5).floor();
        if i < 0.0 {
            None
        } else {
            Some((i as usize).min(self.n() - 1))
        }
    }
}

/// Fills z-slice `k` (`n`² stored values), row by row.
fn fill_slice(grid: Grid, parts: &[Part], bounds: &[[[f32; 2]; 3]], k: usize, slice: &mut [u16]) {
    let n = grid.n();
    let z = grid.centre(k);
    let near = |range: [f32; 2], t: f32| range[0] <= t && t <= range[1];
    let here: Vec<(&Part, [f32; 2])> = parts
        .iter()
        .zip(bounds)
        .filter(|(_, b)| near(b[2], z))
        .map(|(p, b)| (p, b[1]))
        .collect();
    let mut row = vec![AIR_HU; n];
    for (j, stored) in slice.chunks_mut(n).enumerate() {
        // Index y grows towards posterior (LPS); the anatomy's y grows anterior.
        let y = -grid.centre(j);
        row.fill(AIR_HU);
        for (part, _) in here.iter().filter(|(_, range)| near(*range, y)) {
            paint_row(grid, part, y, z, &mut row);
        }
        let row_start = ((k * n + j) * n) as u64;
        for ((out, hu), i) in stored.iter_mut().zip(&row).zip(0u64..) {
            let value = hu + noise_hu(row_start + i) + STORED_OFFSET;
            *out = value.round().clamp(0.0, f32::from(u16::MAX)) as u16;
        }
    }
}

/// Paints `part` on the row at (`y`, `z`): its value over the voxels deep
/// inside, and a blend by their share over the voxels in the soft band.
fn paint_row(grid: Grid, part: &Part, y: f32, z: f32, row: &mut [f32]) {
    let reach = grid.reach();
    let Some((o0, o1)) = part.span(y, z, reach) else {
        return;
    };
    let (first, Some(last)) = (grid.first(o0), grid.last(o1)) else {
        return;
    };
    if first > last {
        return;
    }
    let blend = |i: usize, v: &mut f32| {
        let d = part.signed_distance([grid.centre(i), y, z]) / grid.spacing;
        let c = coverage(d);
        *v = *v * (1.0 - c) + part.hu * c;
    };
    let inner = part
        .span(y, z, -reach)
        .and_then(|(i0, i1)| Some((grid.first(i0).max(first), grid.last(i1)?.min(last))))
        .filter(|(a, b)| a <= b);
    match inner {
        Some((a, b)) => {
            row[first..a]
                .iter_mut()
                .zip(first..)
                .for_each(|(v, i)| blend(i, v));
            row[a..=b].fill(part.hu);
            row[b + 1..=last]
                .iter_mut()
                .zip(b + 1..)
                .for_each(|(v, i)| blend(i, v));
        }
        None => row[first..=last]
            .iter_mut()
            .zip(first..)
            .for_each(|(v, i)| blend(i, v)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The physical value at a point in mm (x left, y anterior, z superior).
    fn hu_at(v: &Volume, p: [f32; 3]) -> f32 {
        let n = v.geometry.dims[0];
        let spacing = EDGE_MM / n as f32;
        let idx = |t: f32| (((t + EDGE_MM * 0.5) / spacing) as u32).min(n - 1);
        v.physical_at(idx(p[0]), idx(-p[1]), idx(p[2])) as f32
    }

    #[test]
    fn tissues_have_their_hounsfield_values() {
        let v = head(256).expect("phantom");
        let near = |got: f32, want: f32| (got - want).abs() <= NOISE_HU * 0.5 + 0.5;
        for (what, p, want) in [
            ("air", [110.0, 110.0, 110.0], AIR_HU),
            ("scalp", [0.0, -10.0, 110.0], SKIN),
            ("skull base", [38.0, -14.0, -40.0], BONE),
            ("grey matter", [20.0, -10.0, 88.0], GREY),
            ("white matter", [30.0, -10.0, 40.0], WHITE),
            ("lateral ventricle", [11.0, -6.0, 32.0], CSF),
            ("eyeball", [32.0, 65.0, -4.0], VITREOUS),
            ("nasal cavity", [4.0, 56.0, -30.0], AIR_HU),
            ("maxillary sinus", [-28.0, 50.0, -36.0], AIR_HU),
            ("orbital fat", [32.0, 45.0, -4.0], ORBITAL_FAT),
            ("foramen magnum", [0.0, -20.0, -52.0], CSF),
            ("spinal cord", [0.0, -30.0, -100.0], BRAINSTEM),
            ("dens", [0.0, -8.0, -70.0], BONE),
            ("carotid", [24.0, 2.0, -100.0], ARTERY),
            ("carotid", [-24.0, 2.0, -100.0], ARTERY),
            ("lesion", [-32.0, 36.0, 34.0], LESION),
            ("oedema", [-32.0, 36.0, 44.0], OEDEMA),
            ("neck muscle", [0.0, -55.0, -110.0], MUSCLE),
        ] {
            let got = hu_at(&v, p);
            assert!(
                near(got, want),
                "{what} at {p:?}: {got} HU, expected {want}"
            );
        }
        // Vessels not much wider than the edges keep some partial volume at
        // their centre, as in a scan: within 30 HU of their contrast, well
        // above soft tissue and below the bone ramp.
        for (what, p, want) in [
            ("basilar artery", [0.0, -9.0, -24.0], ARTERY),
            ("superior sagittal sinus", [0.0, -10.0, 93.0], VEIN),
        ] {
            let got = hu_at(&v, p);
            assert!(
                (want - 30.0..=want + NOISE_HU).contains(&got),
                "{what} at {p:?}: {got} HU, expected 30 HU below {want} or more"
            );
        }
    }

    #[test]
    fn noise_is_zero_mean_and_small() {
        let v = head(64).expect("phantom");
        // Air outside the head: the mean of many voxels is −1000 within a fraction of an HU.
        let corner: Vec<f32> = (56..64)
            .flat_map(|z| (0..8).flat_map(move |y| (0..8).map(move |x| (x, y, z))))
            .map(|(x, y, z)| v.physical_at(x, y, z) as f32)
            .collect();
        let mean = corner.iter().sum::<f32>() / corner.len() as f32;
        assert!((mean - AIR_HU).abs() < 1.0, "mean air {mean}");
        assert!(
            corner
                .iter()
                .all(|h| (h - AIR_HU).abs() <= NOISE_HU * 0.5 + 0.5)
        );
    }

    #[test]
    fn generation_is_deterministic() {
        let a = head(48).expect("phantom");
        let b = head(48).expect("phantom");
        assert_eq!(a.voxels, b.voxels);
    }

    /// Rows filled through their deep and outer intervals give exactly what
    /// evaluating every structure at every voxel gives.
    #[test]
    fn rows_match_evaluating_every_structure_at_every_voxel() {
        for size in [MIN_SIZE, 40] {
            let v = head(size).expect("phantom");
            let grid = Grid::new(size);
            let parts = anatomy();
            let n = grid.n();
            let mut differ = 0;
            for k in 0..n {
                for j in 0..n {
                    for i in 0..n {
                        let p = [grid.centre(i), -grid.centre(j), grid.centre(k)];
                        let hu = parts.iter().fold(AIR_HU, |v, part| {
                            let c = coverage(part.signed_distance(p) / grid.spacing);
                            v * (1.0 - c) + part.hu * c
                        });
                        let index = ((k * n + j) * n + i) as u64;
                        let value = hu + noise_hu(index) + STORED_OFFSET;
                        let want = value.round().clamp(0.0, f32::from(u16::MAX));
                        let got = v.voxels.get(index as usize) as f32;
                        if got != want {
                            differ += 1;
                        }
                    }
                }
            }
            assert_eq!(differ, 0, "{differ} voxels differ at {size}³");
        }
    }

    #[test]
    fn geometry_is_centred_with_isotropic_spacing() {
        let v = head(64).expect("phantom");
        let g = v.geometry;
        assert_eq!(g.dims, [64; 3]);
        assert_eq!(g.spacing_f32(), [EDGE_MM / 64.0; 3]);
        let last_centre = g.origin[0] + 63.0 * g.spacing[0];
        assert!((g.origin[0] + last_centre).abs() < 1e-3);
        assert_eq!(v.unit.as_deref(), Some("HU"));
        assert_eq!(v.modality.as_deref(), Some("CT"));
        // Air and bone at their values: the range spans them, noise included,
        // and nothing lies beyond them.
        let v = head(128).expect("phantom");
        let [lo, hi] = v.value_range;
        assert!((-1006.0..=-994.0).contains(&lo), "{lo}");
        assert!((994.0..=1006.0).contains(&hi), "{hi}");
    }

    #[test]
    fn the_head_is_left_right_symmetric_but_for_the_lesion() {
        // Mirrored voxels differ by noise only, except near the lesion in the
        // right frontal lobe.
        let v = head(64).expect("phantom");
        let spacing = EDGE_MM / 64.0;
        let mm = |i: u32| (i as f32 + 0.5) * spacing - EDGE_MM * 0.5;
        for z in 0..64 {
            for y in 0..64 {
                for x in 0..32 {
                    let to_lesion = [mm(x) + 32.0, -mm(y) - 36.0, mm(z) - 34.0];
                    if dot(to_lesion, to_lesion).sqrt() < 13.0 + 2.0 * EDGE_VOXELS * spacing {
                        continue;
                    }
                    let (a, b) = (v.physical_at(x, y, z), v.physical_at(63 - x, y, z));
                    assert!(
                        (a - b).abs() <= f64::from(NOISE_HU) + 1.0,
                        "({x},{y},{z}): {a} vs {b}"
                    );
                }
            }
        }
    }

    #[test]
    fn edges_are_soft_and_monotone_across_the_vault() {
        // Up through the vault at (30, −10), from the outer table's core to the
        // scalp's fat, HU falls from bone to soft tissue through intermediate
        // values over a few voxels, not in one step.
        let v = head(256).expect("phantom");
        let spacing = EDGE_MM / 256.0;
        let index = |t: f32| ((t + EDGE_MM * 0.5) / spacing) as u32;
        let (x, y) = (index(30.0), index(10.0));
        let profile: Vec<f32> = (index(85.0)..index(110.0))
            .map(|z| v.physical_at(x, y, z) as f32)
            .collect();
        // The outer table, 2.5 mm thick, peaks near 900 HU between its edges.
        let core = profile.iter().rposition(|h| *h > 800.0);
        let outside = core.and_then(|c| Some(c + profile[c..].iter().position(|h| *h < 60.0)?));
        let (Some(core), Some(outside)) = (core, outside) else {
            panic!("no bone to soft tissue transition in {profile:?}");
        };
        let edge = &profile[core..=outside];
        assert!((3..=5).contains(&edge.len()), "{edge:?}");
        assert!(edge.iter().any(|h| *h > 200.0 && *h < 850.0), "{edge:?}");
        for w in edge.windows(2) {
            assert!(w[1] <= w[0] + NOISE_HU, "{edge:?}");
        }
    }

    #[test]
    fn capsule_rows_hold_exactly_the_points_within_reach() {
        // A tilted capsule: points inside the interval are within the radius,
        // points just outside it are not.
        let shape = capsule([-10.0, 3.0, -4.0], [20.0, -6.0, 9.0], 5.0);
        for (y, z) in [(0.0, 0.0), (-4.0, 7.0), (5.0, -5.0), (3.0, -8.0)] {
            let (x0, x1) = shape.span(y, z, 0.0).expect("the row meets the capsule");
            for x in [x0, x1] {
                let d = shape.signed_distance([x, y, z]);
                assert!(d.abs() < 1e-3, "({x}, {y}, {z}): distance {d}");
            }
            assert!(shape.signed_distance([x0 - 0.01, y, z]) > 0.0);
            assert!(shape.signed_distance([x1 + 0.01, y, z]) > 0.0);
        }
        assert!(shape.span(30.0, 0.0, 0.0).is_none());
    }

    #[test]
    fn coverage_is_a_smooth_step() {
        assert_eq!(coverage(-10.0), 1.0);
        assert_eq!(coverage(10.0), 0.0);
        assert!((coverage(0.0) - 0.5).abs() < 1e-6);
        assert!(coverage(-0.5) > coverage(0.5));
    }

    #[test]
    fn sizes_out_of_range_are_refused() {
        for size in [0, MIN_SIZE - 1, MAX_SIZE + 1] {
            let err = head(size).expect_err("size out of range");
            let msg = err.to_string();
            assert!(
                msg.contains("phantom size") && msg.contains("from 16 to 512"),
                "{msg}"
            );
        }
    }
}
