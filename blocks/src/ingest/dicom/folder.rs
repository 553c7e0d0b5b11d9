//! The image series of a folder: [`FolderScan`] reads every file's header,
//! groups the images by SeriesInstanceUID and then by geometry, lists them
//! ([`SeriesSummary`]) and opens the one asked for.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use rayon::prelude::*;

use super::series::DicomSeries;
use super::slice_header::{SliceHeader, has_dicom_marker, read_header};
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
    /// Reads the headers of every DICOM file in `folder` (not its subfolders;
    /// files whose names start with a dot are passed over). Symbolic links are
    /// followed to regular files inside the folder (anywhere with
    /// `allow_outside`). Files that are not DICOM, and DICOM files without an
    /// image, are skipped with a warning naming them; a damaged DICOM file is an
    /// error.
    pub fn new(folder: &Path, allow_outside: bool) -> Result<FolderScan, Error> {
        let (files, mut skipped) = candidate_files(folder, allow_outside)?;
        let headers: Vec<(PathBuf, Vec<SliceHeader>)> = files
            .into_par_iter()
            .map(|p| read_header(&p).map(|h| (p, h)))
            .collect::<Result<_, _>>()?;
        let mut images = Vec::new();
        for (path, frames) in headers {
            if frames.is_empty() {
                skipped.push((path, "a DICOM file without an image".to_owned()));
            }
            images.extend(frames);
        }
        if images.is_empty() {
            return Err(field(
                folder,
                "images",
                format!(
                    "none found: expected DICOM image files in the folder{}",
                    listing(&skipped, "; skipped ")
                ),
            ));
        }
        if !skipped.is_empty() {
            tracing::warn!(
                "{}: {} file(s) skipped, not read as part of a series{}",
                folder.display(),
                skipped.len(),
                listing(&skipped, ": ")
            );
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

/// Files skipped, each with the reason.
type Skipped = Vec<(PathBuf, String)>;

/// The most skipped files a message names one by one.
const NAMED_SKIPPED: usize = 10;

/// `skipped` files as `prefix` and a list of names with reasons (the first
/// [`NAMED_SKIPPED`], then a count), or nothing when there are none.
fn listing(skipped: &[(PathBuf, String)], prefix: &str) -> String {
    if skipped.is_empty() {
        return String::new();
    }
    let mut names: Vec<String> = skipped
        .iter()
        .take(NAMED_SKIPPED)
        .map(|(p, why)| {
            let name = p.file_name().map_or_else(
                || p.display().to_string(),
                |n| n.to_string_lossy().into_owned(),
            );
            format!("{name} ({why})")
        })
        .collect();
    if skipped.len() > NAMED_SKIPPED {
        names.push(format!("and {} more", skipped.len() - NAMED_SKIPPED));
    }
    format!("{prefix}{} file(s): {}", skipped.len(), names.join(", "))
}

/// The files of `folder` that may be DICOM (sorted), and those skipped with
/// why: not a regular file, a symbolic link leading outside the folder (unless
/// `allow_outside`) or nowhere, or no `DICM` marker.
fn candidate_files(folder: &Path, allow_outside: bool) -> Result<(Vec<PathBuf>, Skipped), Error> {
    let io_err = |source| Error::Io {
        path: folder.to_owned(),
        source,
    };
    let home = folder.canonicalize().map_err(io_err)?;
    let mut entries: Vec<std::fs::DirEntry> = std::fs::read_dir(folder)
        .map_err(io_err)?
        .filter_map(Result::ok)
        .filter(|e| !e.file_name().to_string_lossy().starts_with('.'))
        .collect();
    entries.sort_by_key(std::fs::DirEntry::path);
    let (mut files, mut skipped) = (Vec::new(), Vec::new());
    for entry in entries {
        let path = entry.path();
        let Ok(kind) = entry.file_type() else {
            continue;
        };
        if kind.is_dir() {
            continue; // subfolders are not read
        }
        if kind.is_symlink() {
            match path.canonicalize() {
                Err(_) => {
                    skipped.push((path, "a broken symbolic link".to_owned()));
                    continue;
                }
                Ok(target) if !allow_outside && !target.starts_with(&home) => {
                    skipped.push((
                        path,
                        format!(
                            "a symbolic link to {}, outside the folder; --allow-data-outside reads it",
                            target.display()
                        ),
                    ));
                    continue;
                }
                Ok(target) if target.is_dir() => continue,
                Ok(_) => {}
            }
        }
        if !path.is_file() {
            skipped.push((path, "not a regular file".to_owned()));
        } else if !has_dicom_marker(&path)? {
            skipped.push((path, "not DICOM: no DICM marker at byte 128".to_owned()));
        } else {
            files.push(path);
        }
    }
    Ok((files, skipped))
}

/// Opens the DICOM series in `folder`: the only one, or the one `series` names.
/// Symbolic links to files outside the folder are read only with
/// `allow_outside`.
pub fn open_folder(
    folder: &Path,
    series: Option<&str>,
    allow_outside: bool,
) -> Result<DicomSeries, Error> {
    FolderScan::new(folder, allow_outside)?.open(series)
}

/// Opens a single DICOM file: a one-slice volume, or the frames of an
/// enhanced multi-frame image stacked.
pub fn open_file(path: &Path) -> Result<DicomSeries, Error> {
    let frames = read_header(path)?;
    if frames.is_empty() {
        return Err(field(
            path,
            "Rows (0028,0010)",
            "missing: expected an image",
        ));
    }
    DicomSeries::new(path, frames)
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
