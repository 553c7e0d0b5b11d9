//! [`DicomSeries`]: a checked, sorted series of slices as a [`VolumeSource`],
//! read a slab of slices at a time with the slices decoded in parallel.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, PoisonError};

use dicom_object::DefaultDicomObject;

use rayon::prelude::*;

use super::geometry;
use super::pixels::{self, PixelFormat};
use super::slice_header::SliceHeader;
use crate::ingest::{
    Format, Study, VolumeInfo, VolumeSource, check_dims, check_slab, check_value_map,
};
use crate::{Error, ValueMap, VoxelData, VoxelType};

/// A DICOM series as a [`VolumeSource`].
#[derive(Debug)]
pub struct DicomSeries {
    info: VolumeInfo,
    slices: Vec<SliceHeader>,
    format: PixelFormat,
    /// Per-slice rescale to f32, when slices disagree on it.
    rescale_each: bool,
    /// The value padded pixels take, in the output domain.
    padding_replacement: Option<f64>,
    /// The multi-frame file read last, kept for the next slab's frames (a
    /// file is read whole: held once, not once per slab).
    last_file: Mutex<Option<(PathBuf, Arc<DefaultDicomObject>)>>,
}

impl DicomSeries {
    /// Checks `slices` (one pixel format, one geometry), sorts them along the
    /// stacking direction and works out the volume's geometry and value map.
    /// `path` is the folder or file the series came from.
    pub(super) fn new(path: &Path, mut slices: Vec<SliceHeader>) -> Result<DicomSeries, Error> {
        // The first file as listed, before sorting: it stands for the series
        // where all slices agree, and messages name it.
        let first = slices[0].clone();
        let mut notes = Vec::new();
        let format = PixelFormat::of_series(&slices)?;
        if format.monochrome1 {
            notes.push("MONOCHROME1: values inverted so that higher is brighter".to_owned());
        }
        let dims = check_dims(
            path,
            "Rows, Columns and slices",
            [
                u64::from(first.columns),
                u64::from(first.rows),
                slices.len() as u64,
            ],
            u64::from(format.sample_bytes()),
        )?;
        for s in &slices {
            check_value_map(
                &s.path,
                "RescaleSlope (0028,1053) and RescaleIntercept (0028,1052)",
                ValueMap {
                    slope: s.slope as f32,
                    intercept: s.intercept as f32,
                },
                format.voxel_type(),
            )?;
        }
        let geometry = geometry::place(&first, &mut slices, dims, &mut notes)?;
        let rescale_each = slices
            .iter()
            .any(|s| s.slope != first.slope || s.intercept != first.intercept);
        let (voxel_type, value_map) = if rescale_each {
            notes.push("RescaleSlope/RescaleIntercept differ between slices: each slice rescaled to physical values (float32)".to_owned());
            (VoxelType::F32, ValueMap::IDENTITY)
        } else {
            (
                format.voxel_type(),
                ValueMap {
                    slope: first.slope as f32,
                    intercept: first.intercept as f32,
                },
            )
        };
        let info = VolumeInfo {
            path: path.to_owned(),
            format: Format::Dicom,
            geometry,
            voxel_type,
            value_map,
            unit: unit(&first),
            modality: first.modality.clone(),
            description: first.series_description.clone(),
            study: study(&first),
            notes,
        };
        let mut series = DicomSeries {
            info,
            slices,
            format,
            rescale_each,
            padding_replacement: None,
            last_file: Mutex::new(None),
        };
        if series.slices.iter().any(|s| s.padding.is_some()) {
            series.padding_replacement = Some(series.lowest_unpadded_value()?);
            series.info.notes.push(format!(
                "PixelPaddingValue: padded pixels set to the lowest other value ({})",
                series.padding_replacement.unwrap_or_default()
            ));
        }
        Ok(series)
    }

    /// The SeriesInstanceUID.
    pub fn series_uid(&self) -> &str {
        &self.slices[0].series_uid
    }

    /// The lowest non-padding value of the series in the output domain (one pass
    /// over the pixels, made only for series that declare padding).
    fn lowest_unpadded_value(&self) -> Result<f64, Error> {
        let lows = self.each_slice(0..self.slices.len(), |obj, s| {
            pixels::lowest_unpadded(obj, s, &self.format, self.rescale_each)
        })?;
        let low = lows.into_iter().fold(f64::INFINITY, f64::min);
        Ok(if low.is_finite() { low } else { 0.0 })
    }

    /// `f` on slices `range` in order, each with its file read: single-frame
    /// files in parallel; the frames of a multi-frame file in parallel from
    /// one read of it, kept for the next call.
    fn each_slice<T: Send>(
        &self,
        range: std::ops::Range<usize>,
        f: impl Fn(&DefaultDicomObject, &SliceHeader) -> Result<T, Error> + Sync,
    ) -> Result<Vec<T>, Error> {
        let slices = &self.slices[range];
        if slices.iter().all(|s| s.frames == 1) {
            return slices.par_iter().map(|s| f(&pixels::open(s)?, s)).collect();
        }
        let mut files: Vec<&Path> = slices.iter().map(|s| s.path.as_path()).collect();
        files.sort();
        files.dedup();
        let mut out: Vec<Option<T>> = slices.iter().map(|_| None).collect();
        for file in files {
            let obj = self.file(slices.iter().find(|s| s.path == file).unwrap_or(&slices[0]))?;
            let done: Vec<(usize, T)> = slices
                .par_iter()
                .enumerate()
                .filter(|(_, s)| s.path == file)
                .map(|(i, s)| f(&obj, s).map(|v| (i, v)))
                .collect::<Result<_, _>>()?;
            for (i, v) in done {
                out[i] = Some(v);
            }
        }
        Ok(out.into_iter().flatten().collect())
    }

    /// The file of slice `s`, read whole, or the one kept from last time
    /// (one file kept at a time).
    fn file(&self, s: &SliceHeader) -> Result<Arc<DefaultDicomObject>, Error> {
        let mut last = self
            .last_file
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        if let Some((path, obj)) = last.as_ref()
            && *path == s.path
        {
            return Ok(Arc::clone(obj));
        }
        *last = None;
        let obj = Arc::new(pixels::open(s)?);
        *last = Some((s.path.clone(), Arc::clone(&obj)));
        Ok(obj)
    }
}

/// Patient and study as the first slice names them.
fn study(first: &SliceHeader) -> Study {
    let text = |t: &Option<String>| t.as_deref().map(Study::text);
    Study {
        patient_name: text(&first.patient_name),
        patient_id: text(&first.patient_id),
        patient_birth_date: text(&first.patient_birth_date),
        study_date: text(&first.study_date),
        study_description: text(&first.study_description),
        series_description: text(&first.series_description),
        slice_thickness_mm: first.slice_thickness,
    }
}

/// The unit of physical values: RescaleType when it names one, HU for CT,
/// Units for PET.
fn unit(first: &SliceHeader) -> Option<String> {
    match (&first.rescale_type, first.modality.as_deref()) {
        (Some(t), _) if t != "US" => Some(t.clone()),
        (_, Some("CT")) => Some("HU".to_owned()),
        (_, Some("PT")) => first.units.clone(),
        _ => None,
    }
}

impl VolumeSource for DicomSeries {
    fn info(&self) -> &VolumeInfo {
        &self.info
    }

    fn read_slab(&mut self, z0: u32, depth: u32) -> Result<VoxelData, Error> {
        check_slab(&self.info, z0, depth)?;
        let fill = self.padding_replacement.unwrap_or(0.0);
        let slices = self.each_slice(z0 as usize..(z0 + depth) as usize, |obj, s| {
            pixels::decode(
                obj,
                s,
                &self.format,
                self.rescale_each,
                fill,
                self.info.voxel_type,
            )
        })?;
        let mut out = VoxelData::zeros(self.info.voxel_type, 0);
        for s in slices {
            out.append(s)?;
        }
        Ok(out)
    }
}
