//! The image series of a folder: [`FolderScan`] reads every file's header,
//! groups the images by SeriesInstanceUID and then by geometry, lists them
//! ([`SeriesSummary`]) and opens the one asked for.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use rayon::prelude::*;

use super::series::DicomSeries;
use super::slice_header::{SliceHeader, read_header};
use crate::Error;
use crate::ingest::header::field;

/// One series (of one geometry) found in a folder.
#[derive(Debug)]
struct Stack {
    id: String,
    slices: Vec<SliceHeader>,
}

/// What a listing says about one series of a folder.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SeriesSummary {
    /// The id `--series` takes: the SeriesInstanceUID, with `/N` appended when
    /// the series holds images of several geometries.
    pub id: String,
    /// Modality, when given.
    pub modality: Option<String>,
    /// SeriesDescription, when given.
    pub description: Option<String>,
    /// Number of images.
    pub slices: usize,
    /// Columns × rows.
    pub size: [u32; 2],
}

impl std::fmt::Display for SeriesSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}  {} {} slices of {}x{}",
            self.id,
            self.modality.as_deref().unwrap_or("?"),
            self.slices,
            self.size[0],
            self.size[1]
        )?;
        if let Some(d) = &self.description {
            write!(f, "  \"{d}\"")?;
        }
        Ok(())
    }
}

/// The image series found in a folder, headers read.
#[derive(Debug)]
pub struct FolderScan {
    folder: PathBuf,
    stacks: Vec<Stack>,
}

impl FolderScan {
    /// Reads the headers of every file in `folder` (not its subfolders; files
    /// whose names start with a dot are skipped, files without an image are
    /// passed over, any other non-DICOM file is an error).
    pub fn new(folder: &Path) -> Result<FolderScan, Error> {
        let io_err = |source| Error::Io {
            path: folder.to_owned(),
            source,
        };
        let mut files: Vec<PathBuf> = std::fs::read_dir(folder)
            .map_err(io_err)?
            .filter_map(Result::ok)
            .filter(|e| e.file_type().is_ok_and(|t| t.is_file()))
            .filter(|e| !e.file_name().to_string_lossy().starts_with('.'))
            .map(|e| e.path())
            .collect();
        files.sort();
        let headers: Vec<Option<SliceHeader>> = files
            .par_iter()
            .map(|p| read_header(p))
            .collect::<Result<_, _>>()?;
        let images: Vec<SliceHeader> = headers.into_iter().flatten().collect();
        if images.is_empty() {
            return Err(field(
                folder,
                "images",
                "none found: expected DICOM image files in the folder",
            ));
        }
        Ok(FolderScan {
            folder: folder.to_owned(),
            stacks: group(images),
        })
    }

    /// One line per series.
    pub fn summaries(&self) -> Vec<SeriesSummary> {
        self.stacks.iter().map(FolderScan::summary_of).collect()
    }

    /// Opens the only series, or the one `series` names.
    pub fn open(self, series: Option<&str>) -> Result<DicomSeries, Error> {
        let folder = self.folder;
        let count = self.stacks.len();
        let listing = |stacks: &[Stack]| {
            stacks
                .iter()
                .map(|s| format!("  {}", FolderScan::summary_of(s)))
                .collect::<Vec<_>>()
                .join("\n")
        };
        let stack = match series {
            Some(wanted) => {
                let known: Vec<String> = self.stacks.iter().map(|s| s.id.clone()).collect();
                self.stacks
                    .into_iter()
                    .find(|s| s.id == wanted)
                    .ok_or_else(|| {
                        field(
                            &folder,
                            "--series",
                            format!("'{wanted}': expected one of {}", known.join(", ")),
                        )
                    })?
            }
            None if count == 1 => self
                .stacks
                .into_iter()
                .next()
                .ok_or_else(|| field(&folder, "images", "none found"))?,
            None => {
                return Err(Error::SeveralSeries {
                    path: folder.clone(),
                    count,
                    listing: listing(&self.stacks),
                });
            }
        };
        DicomSeries::new(&folder, stack.slices)
    }

    fn summary_of(stack: &Stack) -> SeriesSummary {
        let first = &stack.slices[0];
        SeriesSummary {
            id: stack.id.clone(),
            modality: first.modality.clone(),
            description: first.series_description.clone(),
            slices: stack.slices.len(),
            size: [first.columns, first.rows],
        }
    }
}

/// Opens the DICOM series in `folder`: the only one, or the one `series` names.
pub fn open_folder(folder: &Path, series: Option<&str>) -> Result<DicomSeries, Error> {
    FolderScan::new(folder)?.open(series)
}

/// Opens a single DICOM file as a one-slice volume.
pub fn open_file(path: &Path) -> Result<DicomSeries, Error> {
    let header = read_header(path)?
        .ok_or_else(|| field(path, "Rows (0028,0010)", "missing: expected an image"))?;
    DicomSeries::new(path, vec![header])
}

/// Groups images by series UID, then by geometry; ids are the UID, or
/// `UID/1`, `UID/2`, … when a series holds several geometries.
fn group(images: Vec<SliceHeader>) -> Vec<Stack> {
    let mut by_series: BTreeMap<String, BTreeMap<String, Vec<SliceHeader>>> = BTreeMap::new();
    for image in images {
        by_series
            .entry(image.series_uid.clone())
            .or_default()
            .entry(image.geometry_key())
            .or_default()
            .push(image);
    }
    let mut stacks = Vec::new();
    for (uid, geometries) in by_series {
        let several = geometries.len() > 1;
        for (i, (_, slices)) in geometries.into_iter().enumerate() {
            let id = if several {
                format!("{uid}/{}", i + 1)
            } else {
                uid.clone()
            };
            stacks.push(Stack { id, slices });
        }
    }
    stacks
}
