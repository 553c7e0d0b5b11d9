//! Headerless raw volumes: dimensions, type and byte order come from the command
//! line ([`RawOptions`]) or from a file name like `engine_256x256x128_uint8.raw`
//! or `cthead_256x256x113_uint16be.raw` (`be`/`le` after the type give the byte
//! order; little-endian otherwise). Spacing comes from the command line or is
//! taken as 1 mm.
//!
//! Orientation: a raw file cannot say which way its axes point, so a scan
//! stored top to bottom would render upside down. [`RawOptions::direction`]
//! gives the index axes' directions in patient LPS (identity when not given);
//! [`flip_axes`], [`parse_direction`] and [`parse_flip`] build it from the
//! command line.

use std::path::Path;

use super::header::field;
use super::stream::{Compression, SampleType, StreamLayout, StreamSource};
use super::{Format, VolumeInfo, check_dims};
use crate::geometry::{GeometryFields, IDENTITY_DIRECTION, determinant};
use crate::{Error, Geometry, ValueMap, VoxelType};

/// The layout of a raw file, as given on the command line.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RawOptions {
    /// Voxels along x, y, z.
    pub dims: Option<[u64; 3]>,
    /// The sample type.
    pub sample: Option<SampleType>,
    /// Byte order of multi-byte samples.
    pub big_endian: Option<bool>,
    /// Bytes to skip at the start of the file (a header voxserve does not read).
    pub offset: u64,
    /// Voxel spacing, mm.
    pub spacing: Option<[f64; 3]>,
    /// Unit vectors of the index axes x, y, z in patient LPS: the columns of
    /// the direction matrix, as [`Geometry::direction`] holds them. `None`
    /// is the identity.
    pub direction: Option<[[f64; 3]; 3]>,
}

impl RawOptions {
    /// Whether any part of the layout was given (so the input is raw whatever its name).
    pub fn is_given(&self) -> bool {
        self.dims.is_some() || self.sample.is_some()
    }

    /// The options given at all (layout, byte order, offset, geometry), by
    /// their command-line names: a file whose header says these must not get
    /// them, or they would be silently ignored.
    pub fn given(&self) -> Vec<&'static str> {
        let mut given = Vec::new();
        for (set, name) in [
            (self.dims.is_some(), "--raw-dims"),
            (self.sample.is_some(), "--raw-type"),
            (self.big_endian.is_some(), "--raw-endian"),
            (self.offset != 0, "--raw-offset"),
            (self.spacing.is_some(), "--raw-spacing"),
            (self.direction.is_some(), "--raw-direction or --raw-flip"),
        ] {
            if set {
                given.push(name);
            }
        }
        given
    }
}

/// A sample type by its name: the voxel type names (`uint8` … `float32`, `float`)
/// and `float64`/`double`.
pub fn sample_type(name: &str) -> Option<SampleType> {
    match name {
        "float64" | "double" => Some(SampleType::F64),
        _ => VoxelType::from_name(name).map(SampleType::Voxel),
    }
}

/// The names [`sample_type`] accepts, for messages.
pub const SAMPLE_NAMES: &str = "uint8, int8, uint16, int16, uint32, int32, float32, float64";

/// What a file name says: dimensions, sample type and byte order, e.g.
/// `engine_256x256x128_uint8.raw` → ([256, 256, 128], uint8, None).
pub fn parse_name(name: &str) -> Option<([u64; 3], SampleType, Option<bool>)> {
    let stem = name.rsplit_once('.').map_or(name, |(s, _)| s);
    let mut dims = None;
    let mut sample = None;
    for token in stem.split(['_', '-', '.']) {
        let parts: Vec<&str> = token.split('x').collect();
        if parts.len() == 3
            && let (Ok(x), Ok(y), Ok(z)) = (parts[0].parse(), parts[1].parse(), parts[2].parse())
        {
            dims = Some([x, y, z]);
            continue;
        }
        let lower = token.to_ascii_lowercase();
        let (base, endian) = match lower.strip_suffix("be") {
            Some(b) if sample_type(b).is_some() => (b.to_owned(), Some(true)),
            _ => match lower.strip_suffix("le") {
                Some(b) if sample_type(b).is_some() => (b.to_owned(), Some(false)),
                _ => (lower.clone(), None),
            },
        };
        if let Some(t) = sample_type(&base) {
            sample = Some((t, endian));
        }
    }
    let (sample, endian) = sample?;
    Some((dims?, sample, endian))
}

/// Opens a raw file with `options`, filling gaps from the file name.
pub fn open(path: &Path, options: &RawOptions) -> Result<StreamSource, Error> {
    let mut notes = Vec::new();
    let layout = Layout::resolve(path, options, &mut notes)?;
    let spacing = options.spacing.unwrap_or_else(|| {
        notes.push("spacing not given: assumed 1 mm on every axis".to_owned());
        [1.0; 3]
    });
    let direction = match options.direction {
        Some(columns) => checked_direction(path, columns, &mut notes)?,
        None => IDENTITY_DIRECTION,
    };
    let dims = check_dims(path, "dims", layout.dims, layout.sample.size() as u64)?;
    let geometry = Geometry {
        direction,
        ..Geometry::new(dims, spacing)
    }
    .checked(
        path,
        &GeometryFields {
            dims: "dims",
            spacing: "spacing",
            origin: "origin",
            direction: "direction",
        },
    )?;
    check_size(path, options.offset, dims, layout.sample)?;
    let info = VolumeInfo {
        path: path.to_owned(),
        format: Format::Raw,
        geometry,
        voxel_type: layout.sample.voxel_type(),
        value_map: ValueMap::IDENTITY,
        unit: None,
        modality: None,
        description: None,
        study: crate::ingest::Study::default(),
        notes,
    };
    StreamSource::new(
        info,
        StreamLayout {
            data_path: path.to_owned(),
            compression: Compression::None,
            file_offset: options.offset,
            skip: 0,
            sample: layout.sample,
            big_endian: layout.big_endian,
        },
    )
}

/// Dimensions, sample type and byte order: from the options, else from the
/// file name.
struct Layout {
    dims: [u64; 3],
    sample: SampleType,
    big_endian: bool,
}

impl Layout {
    /// Refuses a file whose dimensions or type neither the options nor the name
    /// give; an unknown byte order of multi-byte samples is taken as
    /// little-endian, with a note.
    fn resolve(
        path: &Path,
        options: &RawOptions,
        notes: &mut Vec<String>,
    ) -> Result<Layout, Error> {
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let from_name = parse_name(&name);
        let dims = options.dims.or(from_name.map(|n| n.0)).ok_or_else(|| {
            field(
                path,
                "dims",
                "not given: expected --raw-dims XxYxZ or a file name like volume_256x256x128_uint8.raw",
            )
        })?;
        let sample = options
            .sample
            .or(from_name.map(|n| n.1))
            .ok_or_else(|| {
                field(
                    path,
                    "type",
                    format!("not given: expected --raw-type (one of {SAMPLE_NAMES}) or the type in the file name"),
                )
            })?;
        let big_endian = match options.big_endian.or(from_name.and_then(|n| n.2)) {
            Some(b) => b,
            None => {
                if sample.size() > 1 {
                    notes.push("byte order not given: assumed little-endian".to_owned());
                }
                false
            }
        };
        Ok(Layout {
            dims,
            sample,
            big_endian,
        })
    }
}

/// Checks that the file holds exactly the voxels after the header offset: a
/// raw file has nothing else to tell a wrong layout by.
fn check_size(path: &Path, offset: u64, dims: [u32; 3], sample: SampleType) -> Result<(), Error> {
    let size = super::header::file_len(path)?;
    let needed = super::stream::volume_bytes(dims, sample);
    let available = size.saturating_sub(offset);
    if available != needed {
        return Err(field(
            path,
            "size",
            format!(
                "{available} bytes after a {offset}-byte header offset, but {} × {} × {} voxels of \
                 {} bytes take {needed}: expected the file size to match (check dims, type and \
                 header offset)",
                dims[0],
                dims[1],
                dims[2],
                sample.size()
            ),
        ));
    }
    Ok(())
}

/// Columns shorter than this are refused rather than normalised: a direction
/// that small is a typo or an underflow, not an orientation.
const MIN_COLUMN_LENGTH: f64 = 1e-6;
/// Columns whose length is further than this from 1 are normalised, with a note.
const UNIT_TOLERANCE: f64 = 1e-3;
/// The smallest |determinant| of the unit columns: below it two axes are
/// (nearly) parallel and the voxels cannot be placed.
const MIN_DETERMINANT: f64 = 1e-3;

/// The direction matrix given for a raw file, checked: every column finite and
/// not zero (columns that are not unit length are normalised, with a note in
/// `notes`), and no two columns (nearly) parallel.
fn checked_direction(
    path: &Path,
    columns: [[f64; 3]; 3],
    notes: &mut Vec<String>,
) -> Result<[[f64; 3]; 3], Error> {
    let mut direction = columns;
    for (axis, column) in ["x", "y", "z"].into_iter().zip(&mut direction) {
        let length = column.iter().map(|c| c * c).sum::<f64>().sqrt();
        if !length.is_finite() || length < MIN_COLUMN_LENGTH {
            return Err(field(
                path,
                "direction",
                format!(
                    "column {axis} {column:?}: expected a finite, non-zero vector (the direction \
                     of index axis {axis} in LPS)"
                ),
            ));
        }
        if (length - 1.0).abs() > UNIT_TOLERANCE {
            notes.push(format!(
                "direction: column {axis} {column:?} has length {length:.4}: normalised to unit length"
            ));
            *column = column.map(|c| c / length);
        }
    }
    let det = determinant(direction);
    if det.abs() <= MIN_DETERMINANT {
        return Err(field(
            path,
            "direction",
            format!(
                "columns {direction:?} have determinant {det:.2e}: expected three independent unit \
                 vectors, no two (nearly) parallel (|determinant| above {MIN_DETERMINANT})"
            ),
        ));
    }
    super::check_orthonormal(path, "direction", direction)?;
    Ok(direction)
}

/// The identity direction with the axes `flip` chooses (x, y, z) reversed: for
/// a volume stored, say, top to bottom (`[false, false, true]`).
pub fn flip_axes(flip: [bool; 3]) -> [[f64; 3]; 3] {
    let mut direction = IDENTITY_DIRECTION;
    for (column, flipped) in direction.iter_mut().zip(flip) {
        if flipped {
            *column = column.map(|c| -c);
        }
    }
    direction
}

/// Reads a direction matrix as nine comma-separated numbers
/// `x1,y1,z1,x2,y2,z2,x3,y3,z3`, column by column: the LPS unit vector of index
/// axis x first, then y, then z.
pub fn parse_direction(text: &str) -> Result<[[f64; 3]; 3], String> {
    let parsed: Option<Vec<f64>> = text.split(',').map(|p| p.trim().parse().ok()).collect();
    match parsed {
        Some(v) if v.len() == 9 && v.iter().all(|x| x.is_finite()) => {
            Ok([[v[0], v[1], v[2]], [v[3], v[4], v[5]], [v[6], v[7], v[8]]])
        }
        _ => Err(format!(
            "expected nine finite numbers x1,y1,z1,x2,y2,z2,x3,y3,z3: the LPS unit vectors of \
             index axes x, y and z, one after the other (identity: 1,0,0,0,1,0,0,0,1), got \
             '{text}'"
        )),
    }
}

/// Reads the axes to flip as letters among x, y and z, each at most once (`z`,
/// `xz`).
pub fn parse_flip(text: &str) -> Result<[bool; 3], String> {
    let expected = || {
        format!(
            "expected one or more of the letters x, y, z, each at most once (like z or xz), got '{text}'"
        )
    };
    if text.is_empty() {
        return Err(expected());
    }
    let mut flip = [false; 3];
    for letter in text.chars() {
        let axis = match letter {
            'x' => 0,
            'y' => 1,
            'z' => 2,
            _ => return Err(expected()),
        };
        if flip[axis] {
            return Err(expected());
        }
        flip[axis] = true;
    }
    Ok(flip)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_give_dims_type_and_byte_order() {
        assert_eq!(
            parse_name("engine_256x256x128_uint8.raw"),
            Some(([256, 256, 128], SampleType::Voxel(VoxelType::U8), None))
        );
        assert_eq!(
            parse_name("cthead_256x256x113_uint16be.raw"),
            Some((
                [256, 256, 113],
                SampleType::Voxel(VoxelType::U16),
                Some(true)
            ))
        );
        assert_eq!(
            parse_name("walnut_128x96x114_uint16le.raw"),
            Some((
                [128, 96, 114],
                SampleType::Voxel(VoxelType::U16),
                Some(false)
            ))
        );
        assert_eq!(
            parse_name("sim-64x64x64-float64.raw"),
            Some(([64, 64, 64], SampleType::F64, None))
        );
        assert_eq!(parse_name("volume.raw"), None);
        assert_eq!(parse_name("scan_12x12_uint8.raw"), None);
    }

    #[test]
    fn flip_axes_reverses_the_chosen_columns() {
        assert_eq!(flip_axes([false; 3]), IDENTITY_DIRECTION);
        assert_eq!(
            flip_axes([false, false, true]),
            [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]]
        );
        assert_eq!(
            flip_axes([true, true, false]),
            [[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]]
        );
    }

    #[test]
    fn directions_parse_column_by_column_or_say_what_was_expected() {
        assert_eq!(
            parse_direction("0,1,0, 1,0,0, 0,0,-1").expect("nine numbers"),
            [[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]
        );
        for bad in [
            "",
            "1,0,0,0,1,0,0,0",
            "1,0,0,0,1,0,0,0,1,0",
            "1,0,0,0,one,0,0,0,1",
            "1,0,0,0,1,0,0,0,NaN",
        ] {
            let msg = parse_direction(bad).expect_err(bad);
            assert!(
                msg.contains("expected nine finite numbers x1,y1,z1,x2,y2,z2,x3,y3,z3")
                    && msg.contains(&format!("got '{bad}'")),
                "{msg}"
            );
        }
    }

    #[test]
    fn flips_parse_as_letters_or_say_what_was_expected() {
        assert_eq!(parse_flip("z"), Ok([false, false, true]));
        assert_eq!(parse_flip("xz"), Ok([true, false, true]));
        assert_eq!(parse_flip("zyx"), Ok([true, true, true]));
        for bad in ["", "w", "x,z", "zz", "Z", " z"] {
            let msg = parse_flip(bad).expect_err(bad);
            assert!(
                msg.contains("expected one or more of the letters x, y, z")
                    && msg.contains(&format!("got '{bad}'")),
                "{msg}"
            );
        }
    }

    #[test]
    fn directions_are_checked_and_long_columns_normalised() {
        let p = Path::new("scan_4x4x4_uint8.raw");
        let mut notes = Vec::new();
        let d = checked_direction(
            p,
            [[2.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]],
            &mut notes,
        )
        .expect("a long column is normalised");
        assert_eq!(d, [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]]);
        assert!(
            notes.len() == 1 && notes[0].contains("column x [2.0, 0.0, 0.0] has length 2.0000"),
            "{notes:?}"
        );
        let mut notes = Vec::new();
        checked_direction(p, flip_axes([true, false, true]), &mut notes).expect("a flip");
        assert!(notes.is_empty(), "{notes:?}");
        let zero = [[1.0, 0.0, 0.0], [0.0; 3], [0.0, 0.0, 1.0]];
        let msg = checked_direction(p, zero, &mut notes)
            .expect_err("zero")
            .to_string();
        assert!(
            msg.contains("scan_4x4x4_uint8.raw: direction: column y [0.0, 0.0, 0.0]: expected a finite, non-zero vector"),
            "{msg}"
        );
        let nan = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, f64::NAN, 1.0]];
        let msg = checked_direction(p, nan, &mut notes)
            .expect_err("NaN")
            .to_string();
        assert!(msg.contains("direction: column z [0.0, NaN, 1.0]"), "{msg}");
        let parallel = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 1.0, 0.0005]];
        let msg = checked_direction(p, parallel, &mut notes)
            .expect_err("parallel")
            .to_string();
        assert!(
            msg.contains("direction: columns")
                && msg.contains("expected three independent unit vectors"),
            "{msg}"
        );
    }
}
