//! The in-scattering directions of global light: a subdivided octahedron
//! turned towards the light, in farthest-first order, with Henyey–Greenstein
//! weights (eqs. 11, 13).

use glam::Vec3;

/// One in-scattering direction of the refinement sequence.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScatterDirection {
    /// Unit vector (model space) the light is gathered from.
    pub towards: [f32; 3],
    /// Gather from the light's direction at each voxel instead (the first step).
    pub to_light: bool,
    /// Phase-function weight φ_j.
    pub weight: f32,
    /// Blend weight of this step: φ_j / Σ_{i≤j} φ_i (eq. 13 when φ is uniform).
    pub blend: f32,
}

/// The vertices of an octahedron subdivided `levels` times, on the unit sphere
/// (6, 18, 66, 258 vertices).
pub fn subdivided_octahedron(levels: u32) -> Vec<Vec3> {
    let mut vertices = vec![
        Vec3::X,
        Vec3::NEG_X,
        Vec3::Y,
        Vec3::NEG_Y,
        Vec3::Z,
        Vec3::NEG_Z,
    ];
    let mut faces: Vec<[usize; 3]> = vec![
        [0, 2, 4],
        [2, 1, 4],
        [1, 3, 4],
        [3, 0, 4],
        [2, 0, 5],
        [1, 2, 5],
        [3, 1, 5],
        [0, 3, 5],
    ];
    for _ in 0..levels {
        let mut midpoints = std::collections::HashMap::new();
        let mut midpoint = |a: usize, b: usize, vertices: &mut Vec<Vec3>| {
            *midpoints.entry((a.min(b), a.max(b))).or_insert_with(|| {
                vertices.push(((vertices[a] + vertices[b]) * 0.5).normalize());
                vertices.len() - 1
            })
        };
        let mut next = Vec::with_capacity(faces.len() * 4);
        for [a, b, c] in faces {
            let ab = midpoint(a, b, &mut vertices);
            let bc = midpoint(b, c, &mut vertices);
            let ca = midpoint(c, a, &mut vertices);
            next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        faces = next;
    }
    vertices
}

/// The J in-scattering directions in refinement order: the light's direction
/// first (per voxel), then the vertices of the smallest subdivided octahedron
/// with at least J vertices, turned so one vertex points at the light (that one
/// is the light's direction) and ordered farthest-first so that every prefix
/// covers the sphere evenly. Weights follow the Henyey–Greenstein phase
/// function of asymmetry `g` about the light's direction seen from the volume's
/// centre (`to_light`, model space).
pub fn scatter_directions(directions: u32, g: f32, to_light: Vec3) -> Vec<ScatterDirection> {
    let to_light = to_light.normalize_or(Vec3::Z);
    let levels = (0..4)
        .find(|&l| subdivided_octahedron(l).len() >= directions as usize)
        .unwrap_or(3);
    let rotation = glam::Quat::from_rotation_arc(Vec3::X, to_light);
    let rest: Vec<Vec3> = subdivided_octahedron(levels)
        .into_iter()
        .skip(1)
        .map(|v| rotation * v)
        .collect();
    // Farthest-first order, starting from the light's direction.
    let mut chosen = vec![to_light];
    let mut left = rest;
    while chosen.len() < directions as usize && !left.is_empty() {
        let (i, _) = left
            .iter()
            .enumerate()
            .map(|(i, v)| {
                (
                    i,
                    chosen
                        .iter()
                        .map(|c| c.dot(*v))
                        .fold(f32::NEG_INFINITY, f32::max),
                )
            })
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap_or((0, 0.0));
        chosen.push(left.swap_remove(i));
    }
    let phase = |cos: f32| (1.0 - g * g) / (1.0 + g * g - 2.0 * g * cos).powf(1.5);
    let mut total = 0.0;
    chosen
        .iter()
        .enumerate()
        .map(|(j, v)| {
            let weight = phase(v.dot(to_light));
            total += weight;
            ScatterDirection {
                towards: (*v).into(),
                to_light: j == 0,
                weight,
                blend: weight / total,
            }
        })
        .collect()
}
