//! [`Texture3d`]: a one-channel 3D texture sampled the way a GPU samples one with
//! linear filtering and clamp-to-edge addressing, for the CPU twins.

use glam::Vec3;

/// Texel values x fastest, sampled at texture coordinates in 0..1 with texel
/// centres at (i + 0.5) / n.
#[derive(Debug, Clone)]
pub struct Texture3d {
    dims: [u32; 3],
    texels: Vec<f32>,
}

impl Texture3d {
    /// A texture of `dims` texels; `texels.len()` must equal their product.
    pub fn new(dims: [u32; 3], texels: Vec<f32>) -> Texture3d {
        assert_eq!(
            texels.len(),
            dims.iter().map(|&d| d as usize).product::<usize>(),
            "texel count must match dims {dims:?}"
        );
        Texture3d { dims, texels }
    }

    /// Texels along x, y, z.
    pub fn dims(&self) -> [u32; 3] {
        self.dims
    }

    /// The texel at integer coordinates, clamped to the edge.
    pub fn load(&self, x: i32, y: i32, z: i32) -> f32 {
        let clamp = |v: i32, n: u32| v.clamp(0, n as i32 - 1) as usize;
        let (nx, ny) = (self.dims[0] as usize, self.dims[1] as usize);
        let (x, y, z) = (
            clamp(x, self.dims[0]),
            clamp(y, self.dims[1]),
            clamp(z, self.dims[2]),
        );
        self.texels[(z * ny + y) * nx + x]
    }

    /// Trilinear sample at texture coordinates `tc` (what `textureSampleLevel`
    /// returns with a linear, clamp-to-edge sampler).
    pub fn sample_level(&self, tc: Vec3) -> f32 {
        let dims = Vec3::new(
            self.dims[0] as f32,
            self.dims[1] as f32,
            self.dims[2] as f32,
        );
        let p = tc * dims - 0.5;
        let base = p.floor();
        let f = p - base;
        let (x, y, z) = (base.x as i32, base.y as i32, base.z as i32);
        let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
        let c00 = lerp(self.load(x, y, z), self.load(x + 1, y, z), f.x);
        let c10 = lerp(self.load(x, y + 1, z), self.load(x + 1, y + 1, z), f.x);
        let c01 = lerp(self.load(x, y, z + 1), self.load(x + 1, y, z + 1), f.x);
        let c11 = lerp(
            self.load(x, y + 1, z + 1),
            self.load(x + 1, y + 1, z + 1),
            f.x,
        );
        lerp(lerp(c00, c10, f.y), lerp(c01, c11, f.y), f.z)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn texel_centres_return_texels_and_midpoints_average() {
        let t = Texture3d::new([2, 1, 1], vec![0.0, 1.0]);
        assert_eq!(t.sample_level(Vec3::new(0.25, 0.5, 0.5)), 0.0);
        assert_eq!(t.sample_level(Vec3::new(0.75, 0.5, 0.5)), 1.0);
        assert_eq!(t.sample_level(Vec3::new(0.5, 0.5, 0.5)), 0.5);
    }

    #[test]
    fn outside_the_texture_clamps_to_the_edge() {
        let t = Texture3d::new([2, 1, 1], vec![0.25, 1.0]);
        assert_eq!(t.sample_level(Vec3::new(-3.0, 0.5, 0.5)), 0.25);
        assert_eq!(t.sample_level(Vec3::new(7.0, 9.0, -1.0)), 1.0);
    }
}
