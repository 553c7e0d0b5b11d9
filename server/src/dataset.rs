//! [`Dataset`]: a volume the server offers under an id, and [`DatasetInfo`], what
//! clients learn about it.

use std::path::Path;
use std::sync::Arc;

use blocks::ingest::{self, OpenOptions};

use blocks::{Preset, Volume};
use serde::Serialize;

/// The id of the built-in phantom.
pub const PHANTOM_ID: &str = "phantom";

/// A volume offered under an id.
#[derive(Debug, Clone)]
pub struct Dataset {
    /// The id in URLs (`dataset=ID`).
    pub id: String,
    /// The volume.
    pub volume: Arc<Volume>,
}

/// A transfer-function preset as clients list it.
#[derive(Debug, Clone, Serialize)]
pub struct PresetInfo {
    /// The name in URLs.
    pub name: &'static str,
    /// A one-line description.
    pub description: &'static str,
}

/// What `GET /api/datasets` says about a dataset.
#[derive(Debug, Clone, Serialize)]
pub struct DatasetInfo {
    /// The id in URLs.
    pub id: String,
    /// A display name.
    pub name: String,
    /// Voxels along x, y, z.
    pub dims: [u32; 3],
    /// Voxel spacing (mm).
    pub spacing: [f32; 3],
    /// Position of the first voxel's centre (mm).
    pub origin: [f32; 3],
    /// `uint8`, `uint16`, …
    pub voxel_type: &'static str,
    /// Smallest and largest physical value.
    pub value_range: [f32; 2],
    /// Unit of the physical values, when known.
    pub unit: Option<String>,
    /// Imaging modality, when known.
    pub modality: Option<String>,
    /// The transfer-function presets offered.
    pub presets: Vec<PresetInfo>,
    /// The preset a client should start with.
    pub default_preset: &'static str,
}

impl Dataset {
    /// The built-in head phantom at `size`³ voxels.
    pub fn phantom(size: u32) -> Result<Dataset, blocks::Error> {
        Ok(Dataset {
            id: PHANTOM_ID.to_owned(),
            volume: Arc::new(blocks::phantom::head(size)?),
        })
    }

    /// A volume file, DICOM folder or brick store read into memory, under an id
    /// made from its name (`engine_256x256x128_uint8.raw` → `engine_256x256x128_uint8`).
    pub fn load(path: &Path, options: &OpenOptions) -> Result<Dataset, blocks::Error> {
        let volume = if blocks::store::Store::is_store(path) {
            blocks::store::Store::open(path)?.load_level(0)?
        } else {
            let mut source = ingest::open(path, options)?;
            ingest::load(source.as_mut())?
        };
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "volume".to_owned());
        let id = [
            ".nii.gz", ".raw", ".nrrd", ".nhdr", ".nii", ".mha", ".mhd", ".dcm",
        ]
        .iter()
        .find_map(|ext| name.strip_suffix(ext))
        .unwrap_or(&name)
        .to_owned();
        Ok(Dataset {
            id,
            volume: Arc::new(volume),
        })
    }

    /// The preset to start with: CT bone for CT, MR for MR, generic otherwise.
    pub fn default_preset(&self) -> Preset {
        match self.volume.modality.as_deref() {
            Some("CT") => Preset::CtBone,
            Some("MR") => Preset::Mr,
            _ => Preset::Generic,
        }
    }

    /// The public description.
    pub fn info(&self) -> DatasetInfo {
        let v = &self.volume;
        DatasetInfo {
            id: self.id.clone(),
            name: v.name.clone(),
            dims: v.dims,
            spacing: v.spacing,
            origin: v.origin,
            voxel_type: v.voxel_type().name(),
            value_range: v.value_range,
            unit: v.unit.clone(),
            modality: v.modality.clone(),
            presets: Preset::ALL
                .iter()
                .map(|p| PresetInfo {
                    name: p.name(),
                    description: p.description(),
                })
                .collect(),
            default_preset: self.default_preset().name(),
        }
    }
}
