//! Placing a series in patient LPS: the index axes from ImageOrientationPatient,
//! the slices sorted along their normal by ImagePositionPatient, the slice
//! spacing from position differences (checked for duplicates, gaps and uneven
//! steps), and a gantry tilt kept as a sheared affine.

use super::slice_header::SliceHeader;
use crate::geometry::GeometryFields;
use crate::ingest::header::field;
use crate::ingest::{ORTHONORMAL_TOLERANCE, check_orthonormal};
use crate::{Error, Geometry};

/// The attributes each part of a series' geometry comes from.
const GEOMETRY_FIELDS: GeometryFields = GeometryFields {
    dims: "Rows, Columns and slices",
    spacing: "PixelSpacing (0028,0030)",
    origin: "ImagePositionPatient (0020,0032)",
    direction: "ImageOrientationPatient (0020,0037)",
};

/// Relative tolerance on slice spacing: differences between neighbouring slice
/// positions may deviate this much from the median difference.
pub const SPACING_TOLERANCE: f64 = 0.01;
/// Stacking directions further than this from the normal (radians, 0.06°) are
/// a gantry tilt.
const TILT_TOLERANCE: f64 = 1e-3;
/// The largest gantry tilt accepted, degrees (CT gantries tilt up to about 30°).
const MAX_GANTRY_TILT_DEG: f64 = 45.0;

/// Places `slices` — a volume of `dims` — in patient LPS, sorting them along
/// the stacking direction. `first` is the series' first file as listed (before
/// sorting): its orientation and pixel spacing stand for the series (grouping
/// made them equal), and it is the file messages name. Assumptions made go to
/// `notes`.
pub(super) fn place(
    first: &SliceHeader,
    slices: &mut [SliceHeader],
    dims: [u32; 3],
    notes: &mut Vec<String>,
) -> Result<Geometry, Error> {
    let (row_dir, col_dir) = match first.orientation {
        Some(o) => ([o[0], o[1], o[2]], [o[3], o[4], o[5]]),
        None if slices.len() == 1 => {
            notes.push("no ImageOrientationPatient: assumed axial".to_owned());
            ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
        }
        None => {
            return Err(field(
                &first.path,
                "ImageOrientationPatient (0020,0037)",
                "missing: expected it to stack the slices",
            ));
        }
    };
    let normal = cross(row_dir, col_dir);
    // The row and column directions, with their normal, must be orthonormal.
    check_orthonormal(
        &first.path,
        "ImageOrientationPatient (0020,0037)",
        [row_dir, col_dir, normal],
    )?;
    let [row_spacing, column_spacing] = first.pixel_spacing.unwrap_or_else(|| {
        notes.push("no PixelSpacing: assumed 1 mm".to_owned());
        [1.0, 1.0]
    });
    let (slice_dir, slice_spacing) = if slices.len() == 1 {
        let s = first
            .spacing_between_slices
            .or(first.slice_thickness)
            .unwrap_or(1.0);
        (normal, if s > 0.0 { s } else { 1.0 })
    } else {
        stack_slices(slices, [row_dir, col_dir, normal], notes)?
    };
    Geometry {
        dims,
        spacing: [column_spacing, row_spacing, slice_spacing],
        // After sorting, slice 0 is the lowest along the stacking direction.
        origin: slices[0].position.unwrap_or([0.0; 3]),
        direction: [row_dir, col_dir, slice_dir],
    }
    .checked(&first.path, &GEOMETRY_FIELDS)
}

/// Sorts `slices` along the normal of `axes` (row, column, normal), checks
/// their spacing, and returns the stacking direction and slice spacing (a
/// sheared direction when the gantry is tilted).
fn stack_slices(
    slices: &mut [SliceHeader],
    axes: [[f64; 3]; 3],
    notes: &mut Vec<String>,
) -> Result<([f64; 3], f64), Error> {
    let normal = axes[2];
    for s in slices.iter() {
        if s.position.is_none() {
            return Err(field(
                &s.path,
                "ImagePositionPatient (0020,0032)",
                format!(
                    "missing{}: expected it on every slice to place the slice",
                    if s.frames > 1 {
                        format!(" for frame {}", s.frame + 1)
                    } else {
                        String::new()
                    }
                ),
            ));
        }
    }
    let at = |s: &SliceHeader| dot(s.position.unwrap_or_default(), normal);
    slices.sort_by(|a, b| at(a).total_cmp(&at(b)));
    let distances: Vec<f64> = slices.windows(2).map(|w| at(&w[1]) - at(&w[0])).collect();
    let mut sorted = distances.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    for (w, d) in slices.windows(2).zip(&distances) {
        let (a, b) = (&w[0], &w[1]);
        let place = |s: &SliceHeader| format!("{} (at {:.3} mm)", s.label(), at(s));
        if *d < 1e-3 {
            return Err(field(
                &b.path,
                "ImagePositionPatient (0020,0032)",
                format!(
                    "same position as {}: expected one slice per position (duplicates or repeated acquisitions)",
                    place(a)
                ),
            ));
        }
        if (d - median).abs() > SPACING_TOLERANCE * median {
            let missing = (d / median).round() - 1.0;
            let message = if missing >= 1.0 {
                format!(
                    "missing slice: from {} to {} the gap is {d:.3} mm, expected {median:.3} mm (about {missing} slice(s) missing)",
                    place(a),
                    place(b)
                )
            } else {
                format!(
                    "uneven slice spacing: from {} to {} the gap is {d:.3} mm, expected {median:.3} mm ± {}%",
                    place(a),
                    place(b),
                    SPACING_TOLERANCE * 100.0
                )
            };
            return Err(field(&b.path, "ImagePositionPatient (0020,0032)", message));
        }
    }
    let (first, last) = (
        slices[0].position.unwrap_or_default(),
        slices[slices.len() - 1].position.unwrap_or_default(),
    );
    let steps = (slices.len() - 1) as f64;
    let step = [0, 1, 2].map(|i| (last[i] - first[i]) / steps);
    let length = dot(step, step).sqrt();
    let along = dot(step, normal) / length;
    if along < 1.0 - TILT_TOLERANCE {
        let angle = along.clamp(-1.0, 1.0).acos().to_degrees();
        let unit = step.map(|x| x / length);
        // A gantry tilts about one image axis: the stacking direction stays
        // perpendicular to it, and the tilt is moderate.
        let about_an_axis = axes[..2]
            .iter()
            .any(|&a| dot(unit, a).abs() <= ORTHONORMAL_TOLERANCE);
        if !about_an_axis || angle > MAX_GANTRY_TILT_DEG {
            return Err(field(
                &slices[slices.len() - 1].path,
                "ImagePositionPatient (0020,0032)",
                format!(
                    "the slices are stacked along {unit:?}, {angle:.2}° off their normal \
                     {normal:?}: expected a stack along the normal, or a gantry tilt (about the \
                     row or the column direction, at most {MAX_GANTRY_TILT_DEG}°)"
                ),
            ));
        }
        notes.push(format!(
            "gantry tilt of {angle:.2}°: slices are stacked {length:.3} mm apart along a direction \
             {angle:.2}° off their normal; kept as a sheared affine"
        ));
        Ok((unit, length))
    } else {
        Ok((normal, median))
    }
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
