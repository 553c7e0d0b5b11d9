//! [`Geometry`]: where a volume's voxels sit in patient space — dimensions,
//! spacing, origin and direction — with its invariants and the quantities
//! derived from it. Readers produce one, volumes, stores, GPU textures and the
//! server's dataset listing hold one.
//!
//! Voxel (i, j, k) sits at `origin + i·spacing₀·d₀ + j·spacing₁·d₁ + k·spacing₂·d₂`
//! (LPS millimetres for medical data), dᵢ being the columns of `direction`.
//! Values are `f64`, as readers produce them and stores keep them; the GPU's
//! `f32` values come from the `*_f32` methods, which round each value once, so
//! every path to the GPU computes with the same `f32` numbers.

use std::fmt;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::Error;

/// The identity direction matrix: index axes along the physical axes.
pub const IDENTITY_DIRECTION: [[f64; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

/// The smallest |determinant| of a direction matrix: below it the index axes
/// do not span space and cannot place voxels.
const MIN_DETERMINANT: f64 = 1e-6;

/// A voxel grid placed in physical space.
///
/// Its invariants — at least one voxel per axis, finite positive spacing, a
/// finite origin, directions that span space — are checked by
/// [`Geometry::check`] where a geometry comes in: the readers,
/// [`crate::Volume::new`] and [`crate::store::Store`]'s metadata. Serialized
/// as the four keys `dims`, `spacing`, `origin`, `direction` (flattened into
/// the store's metadata and the server's dataset listing).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Geometry {
    /// Voxels along x, y and z.
    pub dims: [u32; 3],
    /// Distance between voxel centres along the index axes x, y and z, mm.
    pub spacing: [f64; 3],
    /// The physical position of voxel (0, 0, 0)'s centre, mm (patient LPS for
    /// medical data).
    pub origin: [f64; 3],
    /// Unit vectors of the index axes x, y, z in physical space (the columns of
    /// the direction matrix; [`IDENTITY_DIRECTION`] when unknown).
    pub direction: [[f64; 3]; 3],
}

/// A part of a [`Geometry`], as a [`GeometryFault`] names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GeometryPart {
    /// [`Geometry::dims`].
    Dims,
    /// [`Geometry::spacing`].
    Spacing,
    /// [`Geometry::origin`].
    Origin,
    /// [`Geometry::direction`].
    Direction,
}

impl GeometryPart {
    /// The field's name: `dims`, `spacing`, `origin` or `direction`.
    pub fn name(self) -> &'static str {
        match self {
            GeometryPart::Dims => "dims",
            GeometryPart::Spacing => "spacing",
            GeometryPart::Origin => "origin",
            GeometryPart::Direction => "direction",
        }
    }
}

/// A broken invariant of a [`Geometry`]: the part at fault and what was expected.
#[derive(Debug, Clone, PartialEq)]
pub struct GeometryFault {
    /// The part at fault.
    pub part: GeometryPart,
    /// The value found and what was expected, e.g.
    /// `[1.0, 0.0, 1.0]: expected finite positive spacings (mm)`.
    pub message: String,
}

impl fmt::Display for GeometryFault {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.part.name(), self.message)
    }
}

/// The header fields (or DICOM attributes) a reader took each part of a
/// geometry from, for messages that name them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GeometryFields {
    /// Where the dimensions came from.
    pub dims: &'static str,
    /// Where the spacing came from.
    pub spacing: &'static str,
    /// Where the origin came from.
    pub origin: &'static str,
    /// Where the direction came from.
    pub direction: &'static str,
}

impl GeometryFields {
    /// The field that gave `part`.
    pub fn of(&self, part: GeometryPart) -> &'static str {
        match part {
            GeometryPart::Dims => self.dims,
            GeometryPart::Spacing => self.spacing,
            GeometryPart::Origin => self.origin,
            GeometryPart::Direction => self.direction,
        }
    }
}

impl Geometry {
    /// `dims` voxels `spacing` apart along the physical axes, voxel (0, 0, 0)
    /// at the physical origin (not checked: see [`Geometry::check`]).
    pub fn new(dims: [u32; 3], spacing: [f64; 3]) -> Geometry {
        Geometry {
            dims,
            spacing,
            origin: [0.0; 3],
            direction: IDENTITY_DIRECTION,
        }
    }

    /// Checks the invariants: at least one voxel along every axis, finite
    /// positive spacings, a finite origin, and finite directions of which no
    /// two are parallel (a flat direction matrix cannot place voxels).
    pub fn check(&self) -> Result<(), GeometryFault> {
        let fault = |part, message| Err(GeometryFault { part, message });
        let Geometry {
            dims,
            spacing,
            origin,
            direction,
        } = *self;
        if dims.contains(&0) {
            return fault(
                GeometryPart::Dims,
                format!("{dims:?}: expected at least one voxel along every axis"),
            );
        }
        if !spacing.iter().all(|s| s.is_finite() && *s > 0.0) {
            return fault(
                GeometryPart::Spacing,
                format!("{spacing:?}: expected finite positive spacings (mm)"),
            );
        }
        if !origin.iter().all(|o| o.is_finite()) {
            return fault(
                GeometryPart::Origin,
                format!("{origin:?}: expected a finite origin"),
            );
        }
        let det = determinant(direction);
        if !(direction.iter().flatten().all(|x| x.is_finite()) && det.abs() > MIN_DETERMINANT) {
            return fault(
                GeometryPart::Direction,
                format!("axes {direction:?}: expected three independent directions"),
            );
        }
        Ok(())
    }

    /// The geometry, [checked](Geometry::check), or an [`Error::Field`] about
    /// `path` naming the field in `fields` that gave the part at fault.
    pub fn checked(self, path: &Path, fields: &GeometryFields) -> Result<Geometry, Error> {
        self.check().map_err(|fault| Error::Field {
            path: path.to_owned(),
            field: fields.of(fault.part).to_owned(),
            message: fault.message,
        })?;
        Ok(self)
    }

    /// The number of voxels.
    pub fn voxel_count(&self) -> u64 {
        self.slice_voxels() * u64::from(self.dims[2])
    }

    /// The number of voxels in one z-slice.
    pub fn slice_voxels(&self) -> u64 {
        u64::from(self.dims[0]) * u64::from(self.dims[1])
    }

    /// The extent of the volume's box along the index axes, mm: each voxel
    /// covers one spacing around its centre, so the box is `dims · spacing`.
    pub fn extent_mm(&self) -> [f64; 3] {
        std::array::from_fn(|i| f64::from(self.dims[i]) * self.spacing[i])
    }

    /// The smallest spacing, mm: the reference step that opacities are given for.
    pub fn min_spacing(&self) -> f64 {
        self.spacing.iter().copied().fold(f64::INFINITY, f64::min)
    }

    /// The geometry of level `level` of a store's pyramid: ⌈dims / 2^l⌉ voxels
    /// 2^l spacings apart, the first at the centre of level 0's first box of
    /// 2^l voxels.
    pub fn level(&self, level: usize) -> Geometry {
        let factor = f64::from(1u32 << level);
        let shift = (factor - 1.0) / 2.0;
        let d = self.direction;
        Geometry {
            dims: crate::store::level_dims(self.dims, level),
            spacing: self.spacing.map(|s| s * factor),
            origin: std::array::from_fn(|i| {
                self.origin[i]
                    + (0..3)
                        .map(|a| shift * self.spacing[a] * d[a][i])
                        .sum::<f64>()
            }),
            direction: d,
        }
    }

    /// The spacing in `f32`, as the GPU uses it.
    pub fn spacing_f32(&self) -> [f32; 3] {
        self.spacing.map(|s| s as f32)
    }

    /// The origin in `f32`.
    pub fn origin_f32(&self) -> [f32; 3] {
        self.origin.map(|o| o as f32)
    }

    /// The direction matrix's columns in `f32`, as the GPU uses them.
    pub fn direction_f32(&self) -> [[f32; 3]; 3] {
        self.direction.map(|c| c.map(|x| x as f32))
    }

    /// [`Geometry::extent_mm`] computed in `f32` from [`Geometry::spacing_f32`],
    /// as the GPU's placement of the volume uses it.
    pub fn extent_mm_f32(&self) -> [f32; 3] {
        let spacing = self.spacing_f32();
        std::array::from_fn(|i| self.dims[i] as f32 * spacing[i])
    }

    /// [`Geometry::min_spacing`] in `f32`.
    pub fn min_spacing_f32(&self) -> f32 {
        self.spacing_f32()
            .iter()
            .copied()
            .fold(f32::INFINITY, f32::min)
    }
}

/// Splits the columns of an affine's 3×3 part into spacings (their lengths) and
/// unit directions. A zero column is refused by [`Geometry::check`].
pub fn spacing_and_direction(columns: [[f64; 3]; 3]) -> ([f64; 3], [[f64; 3]; 3]) {
    let norm = |c: [f64; 3]| (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
    let spacing = columns.map(norm);
    let mut direction = columns;
    for (d, s) in direction.iter_mut().zip(spacing) {
        if s > 0.0 {
            *d = d.map(|x| x / s);
        }
    }
    (spacing, direction)
}

/// The determinant of the matrix whose columns are `d`: zero when two columns
/// are parallel.
pub fn determinant(d: [[f64; 3]; 3]) -> f64 {
    d[0][0] * (d[1][1] * d[2][2] - d[1][2] * d[2][1])
        - d[1][0] * (d[0][1] * d[2][2] - d[0][2] * d[2][1])
        + d[2][0] * (d[0][1] * d[1][2] - d[0][2] * d[1][1])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid() -> Geometry {
        Geometry {
            dims: [4, 3, 5],
            spacing: [0.5, 0.75, 2.0],
            origin: [10.0, -20.0, 30.0],
            direction: IDENTITY_DIRECTION,
        }
    }

    #[test]
    fn derived_quantities() {
        let g = grid();
        assert_eq!(g.voxel_count(), 60);
        assert_eq!(g.slice_voxels(), 12);
        assert_eq!(g.extent_mm(), [2.0, 2.25, 10.0]);
        assert_eq!(g.extent_mm_f32(), [2.0, 2.25, 10.0]);
        assert_eq!(g.min_spacing(), 0.5);
        assert_eq!(g.min_spacing_f32(), 0.5);
    }

    #[test]
    fn f32_values_are_rounded_once_from_f64() {
        let g = Geometry::new([3, 1, 1], [0.1, 0.2, 0.3]);
        assert_eq!(g.spacing_f32(), [0.1f32, 0.2, 0.3]);
        // The f32 extent multiplies the rounded spacing, as the GPU path always has.
        assert_eq!(g.extent_mm_f32()[0], 3.0 * 0.1f32);
    }

    #[test]
    fn each_invariant_names_its_part() {
        let part = |g: Geometry| g.check().expect_err("invalid").part;
        let mut g = grid();
        g.dims[1] = 0;
        assert_eq!(part(g), GeometryPart::Dims);
        let mut g = grid();
        g.spacing[2] = -1.0;
        assert_eq!(part(g), GeometryPart::Spacing);
        g.spacing[2] = f64::NAN;
        assert_eq!(part(g), GeometryPart::Spacing);
        let mut g = grid();
        g.origin[0] = f64::INFINITY;
        assert_eq!(part(g), GeometryPart::Origin);
        let mut g = grid();
        g.direction[1] = g.direction[0];
        let fault = g.check().expect_err("parallel axes");
        assert_eq!(fault.part, GeometryPart::Direction);
        assert!(
            fault
                .message
                .contains("expected three independent directions"),
            "{fault}"
        );
        assert!(grid().check().is_ok());
    }

    #[test]
    fn checked_names_the_readers_field() {
        let fields = GeometryFields {
            dims: "sizes",
            spacing: "spacings",
            origin: "space origin",
            direction: "space directions",
        };
        let mut g = grid();
        g.spacing[0] = 0.0;
        let msg = g
            .checked(Path::new("a.nrrd"), &fields)
            .expect_err("zero spacing")
            .to_string();
        assert_eq!(
            msg,
            "a.nrrd: spacings: [0.0, 0.75, 2.0]: expected finite positive spacings (mm)"
        );
    }

    #[test]
    fn a_level_is_coarser_and_centred_on_its_first_box() {
        let g = Geometry {
            direction: [[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
            ..grid()
        };
        let l1 = g.level(1);
        assert_eq!(l1.dims, [2, 2, 3]);
        assert_eq!(l1.spacing, [1.0, 1.5, 4.0]);
        // Half a level-0 spacing along each index axis, in physical space.
        assert_eq!(l1.origin, [10.0 - 0.375, -20.0 + 0.25, 31.0]);
        assert_eq!(g.level(0), g);
    }

    #[test]
    fn spacing_and_direction_split_affine_columns() {
        let (s, d) = spacing_and_direction([[-2.0, 0.0, 0.0], [0.0, 0.0, 3.0], [0.0, 0.5, 0.0]]);
        assert_eq!(s, [2.0, 3.0, 0.5]);
        assert_eq!(d, [[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]]);
    }
}
