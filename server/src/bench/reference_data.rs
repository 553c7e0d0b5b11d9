//! The real datasets voxserve is checked and measured on, from `../shared/data`
//! (beside the repository, never copied into it): where each file is, how to
//! read it, and a transfer function that shows its structure. Tests and
//! benchmarks share this list so their numbers describe the same views.

use std::path::{Path, PathBuf};

use blocks::ingest::OpenOptions;
use blocks::ingest::raw::RawOptions;
use blocks::{Preset, TfPoint, TransferFunction};

/// One real dataset.
#[derive(Debug, Clone)]
pub struct ReferenceDataset {
    /// The file or DICOM folder.
    pub path: PathBuf,
    /// What the file's header (or name) does not say.
    pub options: OpenOptions,
    /// A transfer function that shows the structure, over physical values.
    pub transfer_function: TransferFunction,
}

/// Every name [`reference_dataset`] knows.
pub const NAMES: [&str; 4] = ["engine", "bonsai", "cthead", "vhf"];

fn points(list: &[(f32, [f32; 3], f32)]) -> TransferFunction {
    let points = list
        .iter()
        .map(|&(v, rgb, a)| TfPoint::new(v, rgb, a))
        .collect();
    TransferFunction::new(points).expect("the points below are ordered, finite and in 0..=1")
}

fn spacing(s: [f64; 3]) -> OpenOptions {
    OpenOptions {
        raw: RawOptions {
            spacing: Some(s),
            ..RawOptions::default()
        },
        ..OpenOptions::default()
    }
}

/// The dataset `name` in the data folder `dir` (`../shared/data`), or `None` for
/// an unknown name. The file may still be missing: check [`ReferenceDataset::path`].
pub fn reference_dataset(dir: &Path, name: &str) -> Option<ReferenceDataset> {
    let (file, options, transfer_function) = match name {
        // CT of an engine block: metal above ~40 of 255, air and noise below.
        "engine" => (
            "raw/engine_256x256x128_uint8.raw",
            spacing([1.0; 3]),
            points(&[
                (40.0, [0.6, 0.6, 0.7], 0.0),
                (80.0, [0.8, 0.8, 0.9], 0.3),
                (255.0, [1.0, 1.0, 1.0], 0.9),
            ]),
        ),
        // CT of a bonsai: leaves and twigs from ~40, trunk and pot denser.
        "bonsai" => (
            "raw/bonsai_256x256x256_uint8.raw",
            spacing([1.0; 3]),
            points(&[
                (40.0, [0.3, 0.6, 0.2], 0.0),
                (60.0, [0.3, 0.6, 0.2], 0.25),
                (110.0, [0.6, 0.4, 0.2], 0.5),
                (255.0, [0.9, 0.85, 0.8], 0.9),
            ]),
        ),
        // CT head in raw scanner units: faint skin at ~600, bone above ~1200.
        "cthead" => (
            "raw/cthead_256x256x113_uint16be.raw",
            spacing([1.0, 1.0, 2.0]),
            points(&[
                (500.0, [0.9, 0.6, 0.5], 0.0),
                (700.0, [0.9, 0.6, 0.5], 0.15),
                (1100.0, [0.9, 0.6, 0.5], 0.05),
                (1300.0, [1.0, 1.0, 0.9], 0.9),
            ]),
        ),
        // Visible Human Female head, DICOM in Hounsfield units: the bone preset.
        "vhf" => (
            "dicom/vhf_head",
            OpenOptions::default(),
            Preset::CtBone.transfer_function([-1024.0, 3071.0]),
        ),
        _ => return None,
    };
    Some(ReferenceDataset {
        path: dir.join(file),
        options,
        transfer_function,
    })
}
