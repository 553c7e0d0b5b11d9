//! Every file in `../shared/data` loads with the right dimensions, voxel type and
//! spacing, its voxels match statistics computed independently (numpy, nibabel
//! and pydicom read the same files: minimum, maximum and exact sum of the stored
//! values), and a physical fact about each scan holds.
//!
//! Slabs are read 5 slices at a time so slab boundaries fall inside the data.

use std::path::Path;

use blocks::ingest::raw::RawOptions;
use blocks::ingest::{self, Format, OpenOptions, VolumeInfo, VolumeSource};
use blocks::{VoxelData, VoxelType};
use voxserve_tests::data::shared_data;

/// Stored-value statistics gathered slab by slab.
#[derive(Debug, PartialEq)]
struct Stats {
    min: f64,
    max: f64,
    sum: f64,
    count: u64,
}

fn read_stats(source: &mut dyn VolumeSource) -> Stats {
    let nz = source.info().geometry.dims[2];
    let mut s = Stats {
        min: f64::INFINITY,
        max: f64::NEG_INFINITY,
        sum: 0.0,
        count: 0,
    };
    let mut z = 0;
    while z < nz {
        let d = 5.min(nz - z);
        let slab = source.read_slab(z, d).unwrap_or_else(|e| panic!("{e}"));
        for i in 0..slab.len() {
            let v = slab.get(i);
            s.min = s.min.min(v);
            s.max = s.max.max(v);
            s.sum += v;
            s.count += 1;
        }
        z += d;
    }
    s
}

fn open(path: &Path, options: &OpenOptions) -> Box<dyn VolumeSource> {
    ingest::open(path, options).unwrap_or_else(|e| panic!("{e}"))
}

/// Checks dims, type, spacing and the independent statistics; returns the info.
fn check(
    source: &mut dyn VolumeSource,
    dims: [u32; 3],
    voxel_type: VoxelType,
    spacing: [f64; 3],
    (min, max, sum): (f64, f64, f64),
) -> VolumeInfo {
    let info = source.info().clone();
    let name = info.name();
    assert_eq!(info.geometry.dims, dims, "{name}: dims");
    assert_eq!(info.voxel_type, voxel_type, "{name}: voxel type");
    for (got, want) in info.geometry.spacing.iter().zip(spacing) {
        assert!(
            (got - want).abs() < 1e-4,
            "{name}: spacing {:?}, expected {spacing:?}",
            info.geometry.spacing
        );
    }
    let stats = read_stats(source);
    assert_eq!(
        stats.count,
        dims.iter().map(|&d| u64::from(d)).product::<u64>(),
        "{name}: voxel count"
    );
    assert_eq!(
        (stats.min, stats.max, stats.sum),
        (min, max, sum),
        "{name}: stored min, max, sum"
    );
    info
}

fn raw(spacing: Option<[f64; 3]>) -> OpenOptions {
    OpenOptions {
        raw: RawOptions {
            spacing,
            ..RawOptions::default()
        },
        ..OpenOptions::default()
    }
}

#[test]
fn raw_volumes_load() {
    let Some(data) = shared_data("raw_volumes_load") else {
        return;
    };
    /// File, dims, voxel type, spacing, stored (min, max, sum).
    type Case = (&'static str, [u32; 3], VoxelType, [f64; 3], (f64, f64, f64));
    let cases: [Case; 6] = [
        (
            "engine_256x256x128_uint8.raw",
            [256, 256, 128],
            VoxelType::U8,
            [1.0; 3],
            (0.0, 255.0, 187_475_057.0),
        ),
        (
            "bonsai_256x256x256_uint8.raw",
            [256, 256, 256],
            VoxelType::U8,
            [1.0; 3],
            (0.0, 255.0, 230_038_784.0),
        ),
        (
            "hydrogen_atom_128x128x128_uint8.raw",
            [128, 128, 128],
            VoxelType::U8,
            [1.0; 3],
            (0.0, 250.0, 5_990_975.0),
        ),
        (
            "cthead_256x256x113_uint16be.raw",
            [256, 256, 113],
            VoxelType::U16,
            [1.0, 1.0, 2.0],
            (0.0, 3272.0, 2_810_724_494.0),
        ),
        (
            "headsq_64x64x93_uint16le.raw",
            [64, 64, 93],
            VoxelType::U16,
            [3.2, 3.2, 1.5],
            (0.0, 3926.0, 193_392_317.0),
        ),
        (
            "walnut_128x96x114_uint16le.raw",
            [128, 96, 114],
            VoxelType::U16,
            [0.0156; 3],
            (0.0, 22526.0, 2_873_024_118.0),
        ),
    ];
    for (name, dims, t, spacing, stats) in cases {
        let mut source = open(&data.join("raw").join(name), &raw(Some(spacing)));
        let info = check(source.as_mut(), dims, t, spacing, stats);
        assert_eq!(info.format, Format::Raw);
    }
    // Physical fact: the engine is mostly air (dark), with metal above 40/255.
    let mut engine = open(&data.join("raw/engine_256x256x128_uint8.raw"), &raw(None));
    let slab = engine.read_slab(0, 128).expect("engine");
    let bright = (0..slab.len()).filter(|&i| slab.get(i) > 40.0).count() as f64 / slab.len() as f64;
    assert!(
        (0.05..0.5).contains(&bright),
        "engine: {bright} of voxels above 40"
    );
}

#[test]
fn the_big_endian_ct_head_reads_as_its_little_endian_conversion() {
    let Some(data) = shared_data("the_big_endian_ct_head_reads_as_its_little_endian_conversion")
    else {
        return;
    };
    let path = data.join("raw/cthead_256x256x113_uint16be.raw");
    let bytes = std::fs::read(&path).expect("cthead");
    let swapped: Vec<u16> = bytes
        .chunks_exact(2)
        .map(|b| u16::from_le_bytes([b[1], b[0]]))
        .collect();
    let mut source = open(&path, &raw(Some([1.0, 1.0, 2.0])));
    let volume = ingest::load(source.as_mut()).expect("load");
    assert_eq!(volume.voxels, VoxelData::U16(swapped));
    // Bone (above ~1200 raw units) is present but a small part of the head.
    let bone = (0..volume.voxel_count())
        .filter(|&i| volume.voxels.get(i) > 1200.0)
        .count();
    let share = bone as f64 / volume.voxel_count() as f64;
    assert!((0.01..0.2).contains(&share), "cthead bone share {share}");
}

#[test]
fn nrrd_metaimage_and_nifti_files_load_with_geometry() {
    let Some(data) = shared_data("nrrd_metaimage_and_nifti_files_load_with_geometry") else {
        return;
    };
    let none = OpenOptions::default();
    let mut tooth = open(&data.join("nrrd/tooth.nrrd"), &none);
    check(
        tooth.as_mut(),
        [103, 94, 161],
        VoxelType::U8,
        [1.0; 3],
        (0.0, 255.0, 160_814_065.0),
    );

    let mut nucleon = open(&data.join("nrrd/nucleon.nrrd"), &none);
    let info = check(
        nucleon.as_mut(),
        [41, 41, 41],
        VoxelType::U8,
        [1.0; 3],
        (0.0, 249.0, 2_715_326.0),
    );
    assert!(
        info.path.ends_with("nucleon.nrrd"),
        "the detached header is the volume's path"
    );

    let mut lidc = open(&data.join("mha/LIDC2.mha"), &none);
    let info = check(
        lidc.as_mut(),
        [256, 256, 133],
        VoxelType::U8,
        [1.40625, 1.40625, 2.5],
        (0.0, 255.0, 61_489_178.0),
    );
    // RPS: y runs anterior and z inferior in LPS; the volume spans y 0..360 and z 0..332.5.
    let d = info.geometry.direction;
    assert!(
        (d[1][1] + 1.0).abs() < 1e-9 && (d[2][2] + 1.0).abs() < 1e-9,
        "{d:?}"
    );
    assert!(
        (info.geometry.origin[1] - 360.0).abs() < 1e-6
            && (info.geometry.origin[2] - 332.5).abs() < 1e-6,
        "{:?}",
        info.geometry.origin
    );

    let mut seg = open(&data.join("nifti/seg3D_MR.nii.gz"), &none);
    let info = check(
        seg.as_mut(),
        [160, 232, 160],
        VoxelType::U8,
        [1.0, 0.898437, 0.898437],
        (0.0, 255.0, 330_743_732.0),
    );
    assert!(
        (f64::from(info.value_map.slope) - 2.007843).abs() < 1e-6,
        "scl_slope {:?}",
        info.value_map
    );
    // sform in RAS → LPS: x flips, so its direction is −x; origin as nibabel's affine, negated in x and y.
    assert_eq!(info.geometry.direction[0], [-1.0, -0.0, 0.0]);
    assert!(
        (info.geometry.origin[0] - 388.26001).abs() < 1e-4
            && (info.geometry.origin[1] - 81.119957).abs() < 1e-4
    );

    let mut stroke = open(&data.join("nifti/stroke_T1.nii.gz"), &none);
    let info = check(
        stroke.as_mut(),
        [124, 160, 140],
        VoxelType::U8,
        [1.0; 3],
        (0.0, 252.0, 123_430_146.0),
    );
    // An oblique sform: the directions stay orthonormal.
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let d = info.geometry.direction;
    for (i, j) in [(0, 1), (0, 2), (1, 2)] {
        assert!(
            dot(d[i], d[j]).abs() < 1e-5,
            "axes {i} and {j} not orthogonal: {d:?}"
        );
    }
    assert!((d[0][0] + 0.993592).abs() < 1e-5, "{d:?}");
    assert!(
        (info.geometry.origin[2] + 27.925539).abs() < 1e-4,
        "{:?}",
        info.geometry.origin
    );
}

#[test]
fn the_vhf_head_ct_series_loads_in_hounsfield_units() {
    let Some(data) = shared_data("the_vhf_head_ct_series_loads_in_hounsfield_units") else {
        return;
    };
    let mut source = open(&data.join("dicom/vhf_head"), &OpenOptions::default());
    let info = check(
        source.as_mut(),
        [512, 512, 234],
        VoxelType::I16,
        [1.0, 1.0, 1.0],
        (0.0, 4087.0, 7_036_780_162.0),
    );
    assert_eq!(info.format, Format::Dicom);
    assert_eq!(info.modality.as_deref(), Some("CT"));
    assert_eq!(info.unit.as_deref(), Some("HU"));
    assert_eq!(
        (info.value_map.slope, info.value_map.intercept),
        (1.0, -1024.0)
    );
    // 234 slices 1 mm apart from z = 1500 mm, axial.
    assert_eq!(info.geometry.origin, [0.0, 0.0, 1500.0]);
    assert_eq!(
        info.geometry.direction,
        blocks::geometry::IDENTITY_DIRECTION
    );
    let volume = ingest::load(source.as_mut()).expect("load");
    let hu = |x: u32, y: u32, z: u32| volume.physical_at(x, y, z);
    // Air in the corners of every slice is near −1000 HU.
    let corner: f64 = (0..234).map(|z| hu(5, 5, z)).sum::<f64>() / 234.0;
    assert!((-1030.0..=-990.0).contains(&corner), "air {corner} HU");
    // The skull is bone: above +300 HU, about 1% of the volume.
    let bone = (0..volume.voxel_count())
        .filter(|&i| volume.value_map.physical(volume.voxels.get(i)) > 300.0)
        .count();
    let share = bone as f64 / volume.voxel_count() as f64;
    assert!((0.005..0.03).contains(&share), "bone share {share}");
    assert!(
        volume.value_range[1] > 1000.0,
        "dense bone above 1000 HU: {:?}",
        volume.value_range
    );
}

#[test]
fn the_nine_transfer_syntaxes_decode_to_identical_pixels() {
    let Some(data) = shared_data("the_nine_transfer_syntaxes_decode_to_identical_pixels") else {
        return;
    };
    let mut reference = None;
    for i in 1..=9 {
        let path = data.join(format!("dicom/transfer_syntaxes/{i}.dcm"));
        let mut source = open(&path, &OpenOptions::default());
        let info = check(
            source.as_mut(),
            [384, 384, 1],
            VoxelType::U16,
            [3.25, 3.25, 3.6],
            (0.0, 2362.0, 38_036_663.0),
        );
        assert_eq!(info.modality.as_deref(), Some("MR"));
        let voxels = source.read_slab(0, 1).expect("pixels");
        match &reference {
            None => reference = Some(voxels),
            Some(r) => assert!(r == &voxels, "{i}.dcm decodes differently from 1.dcm"),
        }
    }
    // The folder holds nine copies of one image at one position: refused, not stacked.
    let err = ingest::open(
        &data.join("dicom/transfer_syntaxes"),
        &OpenOptions::default(),
    )
    .expect_err("nine slices at one position");
    assert!(err.to_string().contains("same position as"), "{err}");
}
