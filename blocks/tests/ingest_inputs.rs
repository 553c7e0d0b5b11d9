//! The readers on small generated files: what they must accept (every format,
//! byte orders, compression, DICOM geometry and pixel rules) and the bad inputs
//! they must refuse with a message naming the file, the field and what was
//! expected — without panicking and without allocating what a header claims.

use std::io::Write;
use std::path::Path;

use blocks::ingest::raw::{self, RawOptions};
use blocks::ingest::stream::SampleType;
use blocks::ingest::{self, OpenOptions, VolumeSource};
use blocks::{Error, VoxelData, VoxelType};
use dicom_core::{DataElement, PrimitiveValue, VR};
use dicom_dictionary_std::tags;
use dicom_object::{FileMetaTableBuilder, InMemDicomObject};
use flate2::Compression as Level;
use flate2::write::{GzEncoder, ZlibEncoder};

fn temp() -> tempfile::TempDir {
    tempfile::tempdir().expect("temp dir")
}

fn write(path: &Path, bytes: &[u8]) {
    std::fs::write(path, bytes).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
}

fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut e = GzEncoder::new(Vec::new(), Level::default());
    e.write_all(bytes).expect("gzip");
    e.finish().expect("gzip")
}

fn zlib(bytes: &[u8]) -> Vec<u8> {
    let mut e = ZlibEncoder::new(Vec::new(), Level::default());
    e.write_all(bytes).expect("zlib");
    e.finish().expect("zlib")
}

fn open(path: &Path) -> Result<Box<dyn VolumeSource>, Error> {
    ingest::open(path, &OpenOptions::default())
}

fn load(path: &Path) -> blocks::Volume {
    let mut source = open(path).unwrap_or_else(|e| panic!("{e}"));
    ingest::load(source.as_mut()).unwrap_or_else(|e| panic!("{e}"))
}

/// The error's message, which must name `file` (its file name).
fn message_naming(result: Result<impl std::fmt::Debug, Error>, file: &str) -> String {
    let msg = result.expect_err("bad input must be refused").to_string();
    assert!(msg.contains(file), "message does not name {file}: {msg}");
    msg
}

/// 4 × 3 × 2 voxels of 16 bits: values 0, 100, 200, …
fn ramp_u16() -> Vec<u16> {
    (0..24).map(|i| i * 100).collect()
}

fn le_bytes(v: &[u16]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

fn be_bytes(v: &[u16]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_be_bytes()).collect()
}

// ---- formats that must load -------------------------------------------------

#[test]
fn raw_reads_layout_from_the_name_or_the_options_and_swaps_big_endian() {
    let dir = temp();
    let le = dir.path().join("ramp_4x3x2_uint16.raw");
    write(&le, &le_bytes(&ramp_u16()));
    let be = dir.path().join("ramp_4x3x2_uint16be.raw");
    write(&be, &be_bytes(&ramp_u16()));
    assert_eq!(load(&le).voxels, VoxelData::U16(ramp_u16()));
    assert_eq!(load(&be).voxels, VoxelData::U16(ramp_u16()));

    // No layout in the name: options give it, with a header offset and spacing.
    let plain = dir.path().join("scan.bin");
    let mut bytes = vec![0xAB; 10];
    bytes.extend(le_bytes(&ramp_u16()));
    write(&plain, &bytes);
    let options = OpenOptions {
        series: None,
        raw: RawOptions {
            dims: Some([4, 3, 2]),
            sample: Some(SampleType::Voxel(VoxelType::U16)),
            big_endian: Some(false),
            offset: 10,
            spacing: Some([0.5, 0.5, 2.0]),
            direction: None,
        },
        ..OpenOptions::default()
    };
    let mut source = ingest::open(&plain, &options).expect("raw with options");
    assert_eq!(source.info().geometry.spacing, [0.5, 0.5, 2.0]);
    let v = ingest::load(source.as_mut()).expect("load");
    assert_eq!(v.voxels, VoxelData::U16(ramp_u16()));
}

#[test]
fn raw_takes_a_direction_and_keeps_the_voxels() {
    let dir = temp();
    let path = dir.path().join("ramp_4x3x2_uint16.raw");
    write(&path, &le_bytes(&ramp_u16()));
    // Stored top to bottom: index axis z points inferior.
    let flipped = OpenOptions {
        raw: RawOptions {
            direction: Some(raw::flip_axes(raw::parse_flip("z").expect("z"))),
            ..RawOptions::default()
        },
        ..OpenOptions::default()
    };
    let mut source = ingest::open(&path, &flipped).expect("raw with a flipped z");
    let info = source.info().clone();
    assert_eq!(
        info.geometry.direction,
        [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]]
    );
    assert!(
        !info.notes.iter().any(|n| n.contains("direction")),
        "{:?}",
        info.notes
    );
    let v = ingest::load(source.as_mut()).expect("load");
    assert_eq!(v.voxels, VoxelData::U16(ramp_u16()));
    assert_eq!(v.geometry.direction[2], [0.0, 0.0, -1.0]);
    // No direction: the identity, as before.
    assert_eq!(
        open(&path).expect("plain").info().geometry.direction,
        blocks::geometry::IDENTITY_DIRECTION
    );
}

#[test]
fn bad_raw_directions_are_refused_naming_the_field() {
    let dir = temp();
    let path = dir.path().join("ramp_4x3x2_uint16.raw");
    write(&path, &le_bytes(&ramp_u16()));
    let with = |direction: [[f64; 3]; 3]| {
        let options = OpenOptions {
            raw: RawOptions {
                direction: Some(direction),
                ..RawOptions::default()
            },
            ..OpenOptions::default()
        };
        ingest::open(&path, &options)
    };
    let cases: [([[f64; 3]; 3], &str); 4] = [
        (
            [[1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
            "direction: column y [0.0, 0.0, 0.0]: expected a finite, non-zero vector",
        ),
        (
            [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, f64::INFINITY]],
            "direction: column z [0.0, 0.0, inf]: expected a finite, non-zero vector",
        ),
        (
            [[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
            "expected three independent unit vectors",
        ),
        (
            [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 1.0, 0.0009]],
            "expected three independent unit vectors",
        ),
    ];
    for (direction, expected) in cases {
        let msg = message_naming(with(direction), "ramp_4x3x2_uint16.raw");
        assert!(msg.contains("ramp_4x3x2_uint16.raw: direction: "), "{msg}");
        assert!(msg.contains(expected), "{msg}");
    }
    // A column that is not unit length is normalised, and the note says so.
    let info = with([[0.0, 3.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
        .expect("normalised")
        .info()
        .clone();
    assert_eq!(info.geometry.direction[0], [0.0, 1.0, 0.0]);
    assert!(
        info.notes
            .iter()
            .any(|n| n.contains("column x [0.0, 3.0, 0.0] has length 3.0000: normalised")),
        "{:?}",
        info.notes
    );
}

#[test]
fn raw_options_for_a_file_with_headers_are_refused_naming_them() {
    let dir = temp();
    let path = dir.path().join("headed.nrrd");
    let mut bytes =
        b"NRRD0004\ntype: uint16\ndimension: 3\nsizes: 4 3 2\nendian: little\nencoding: raw\n\n"
            .to_vec();
    bytes.extend(le_bytes(&ramp_u16()));
    write(&path, &bytes);
    let options = OpenOptions {
        raw: RawOptions {
            spacing: Some([1.0, 1.0, 2.0]),
            direction: Some(raw::flip_axes([false, false, true])),
            ..RawOptions::default()
        },
        ..OpenOptions::default()
    };
    let msg = message_naming(ingest::open(&path, &options), "headed.nrrd");
    assert!(
        msg.contains("--raw-spacing, --raw-direction or --raw-flip: raw-file options"),
        "{msg}"
    );
    // Without them the file opens.
    assert!(ingest::open(&path, &OpenOptions::default()).is_ok());
}

#[test]
fn nrrd_attached_detached_and_gzip_read_the_same_voxels_with_geometry() {
    let dir = temp();
    let header = |extra: &str| {
        format!(
            "NRRD0004\n# a comment\ntype: unsigned short\ndimension: 3\nspace: right-anterior-superior\n\
             sizes: 4 3 2\nspace directions: (0.5,0,0) (0,0.5,0) (0,0,2)\nspace origin: (10,20,30)\n\
             endian: big\nkey:=value\n{extra}"
        )
    };
    let attached = dir.path().join("a.nrrd");
    let mut bytes = header("encoding: raw\n\n").into_bytes();
    bytes.extend(be_bytes(&ramp_u16()));
    write(&attached, &bytes);

    let gz = dir.path().join("g.nrrd");
    let mut bytes = header("encoding: gzip\n\n").into_bytes();
    bytes.extend(gzip(&be_bytes(&ramp_u16())));
    write(&gz, &bytes);

    write(&dir.path().join("d.raw"), &be_bytes(&ramp_u16()));
    let detached = dir.path().join("d.nhdr");
    write(
        &detached,
        header("encoding: raw\ndata file: d.raw\n").as_bytes(),
    );

    for path in [&attached, &gz, &detached] {
        let source = open(path).unwrap_or_else(|e| panic!("{e}"));
        let info = source.info();
        assert_eq!(info.geometry.dims, [4, 3, 2]);
        assert_eq!(info.geometry.spacing, [0.5, 0.5, 2.0]);
        // RAS → LPS flips x and y.
        assert_eq!(info.geometry.origin, [-10.0, -20.0, 30.0]);
        assert_eq!(info.geometry.direction[0], [-1.0, 0.0, 0.0]);
        assert_eq!(info.geometry.direction[1], [0.0, -1.0, 0.0]);
        assert_eq!(
            load(path).voxels,
            VoxelData::U16(ramp_u16()),
            "{}",
            path.display()
        );
    }
}

#[test]
fn metaimage_attached_compressed_and_detached_read_the_same_voxels() {
    let dir = temp();
    let header = |extra: &str, data: &str| {
        format!(
            "ObjectType = Image\nNDims = 3\nDimSize = 4 3 2\nElementType = MET_USHORT\n\
             ElementSpacing = 1 1 2.5\nOffset = 1 2 3\nTransformMatrix = 1 0 0 0 -1 0 0 0 -1\n\
             BinaryDataByteOrderMSB = False\n{extra}ElementDataFile = {data}\n"
        )
    };
    let mha = dir.path().join("a.mha");
    let mut bytes = header("", "LOCAL").into_bytes();
    bytes.extend(le_bytes(&ramp_u16()));
    write(&mha, &bytes);

    let zmha = dir.path().join("z.mha");
    let mut bytes = header("CompressedData = True\n", "LOCAL").into_bytes();
    bytes.extend(zlib(&le_bytes(&ramp_u16())));
    write(&zmha, &bytes);

    write(&dir.path().join("d.raw"), &le_bytes(&ramp_u16()));
    let mhd = dir.path().join("d.mhd");
    write(&mhd, header("", "d.raw").as_bytes());

    for path in [&mha, &zmha, &mhd] {
        let info = open(path).unwrap_or_else(|e| panic!("{e}")).info().clone();
        assert_eq!(info.geometry.spacing, [1.0, 1.0, 2.5]);
        assert_eq!(info.geometry.origin, [1.0, 2.0, 3.0]);
        assert_eq!(
            info.geometry.direction,
            [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]
        );
        assert_eq!(
            load(path).voxels,
            VoxelData::U16(ramp_u16()),
            "{}",
            path.display()
        );
    }
}

/// A NIfTI-1 header (348 bytes + 4 extension bytes) for 4 × 3 × 2 voxels.
fn nifti_header(datatype: i16, bitpix: i16, slope: f32, inter: f32) -> Vec<u8> {
    let mut h = vec![0u8; 352];
    let put = |h: &mut Vec<u8>, at: usize, b: &[u8]| h[at..at + b.len()].copy_from_slice(b);
    put(&mut h, 0, &348i32.to_le_bytes());
    for (i, d) in [3i16, 4, 3, 2, 1, 1, 1, 1].iter().enumerate() {
        put(&mut h, 40 + 2 * i, &d.to_le_bytes());
    }
    put(&mut h, 70, &datatype.to_le_bytes());
    put(&mut h, 72, &bitpix.to_le_bytes());
    for (i, p) in [1.0f32, 2.0, 2.0, 3.0].iter().enumerate() {
        put(&mut h, 76 + 4 * i, &p.to_le_bytes());
    }
    put(&mut h, 108, &352f32.to_le_bytes()); // vox_offset
    put(&mut h, 112, &slope.to_le_bytes());
    put(&mut h, 116, &inter.to_le_bytes());
    h[123] = 2; // xyzt_units: mm
    put(&mut h, 254, &1i16.to_le_bytes()); // sform_code
    // sform (RAS): x = 2i + 100, y = 2j, z = 3k - 5
    for (at, row) in [
        (280, [2.0f32, 0.0, 0.0, 100.0]),
        (296, [0.0, 2.0, 0.0, 0.0]),
        (312, [0.0, 0.0, 3.0, -5.0]),
    ] {
        for (i, v) in row.iter().enumerate() {
            put(&mut h, at + 4 * i, &v.to_le_bytes());
        }
    }
    put(&mut h, 344, b"n+1\0");
    h
}

#[test]
fn nifti_plain_and_gzip_read_voxels_scaling_and_sform() {
    let dir = temp();
    let mut bytes = nifti_header(512, 16, 0.5, -10.0);
    bytes.extend(le_bytes(&ramp_u16()));
    let nii = dir.path().join("v.nii");
    write(&nii, &bytes);
    let niigz = dir.path().join("v.nii.gz");
    write(&niigz, &gzip(&bytes));
    for path in [&nii, &niigz] {
        let info = open(path).unwrap_or_else(|e| panic!("{e}")).info().clone();
        assert_eq!(info.value_map.slope, 0.5);
        assert_eq!(info.value_map.intercept, -10.0);
        assert_eq!(info.geometry.spacing, [2.0, 2.0, 3.0]);
        assert_eq!(info.geometry.origin, [-100.0, 0.0, -5.0]); // RAS → LPS
        assert_eq!(info.geometry.direction[0], [-1.0, 0.0, 0.0]);
        assert_eq!(load(path).voxels, VoxelData::U16(ramp_u16()));
    }
}

// ---- DICOM --------------------------------------------------------------------

/// One generated DICOM slice.
#[derive(Clone)]
struct Slice {
    series: &'static str,
    position: [f64; 3],
    orientation: [f64; 6],
    bits_stored: u16,
    signed: bool,
    photometric: &'static str,
    slope: f64,
    intercept: f64,
    padding: Option<u16>,
    pixels: Vec<u16>,
}

impl Default for Slice {
    fn default() -> Slice {
        Slice {
            series: "1.2.3.4",
            position: [0.0; 3],
            orientation: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0],
            bits_stored: 16,
            signed: false,
            photometric: "MONOCHROME2",
            slope: 1.0,
            intercept: 0.0,
            padding: None,
            pixels: (0..12).map(|i| i * 10).collect(),
        }
    }
}

fn ds(values: &[f64]) -> String {
    values
        .iter()
        .map(|v| format!("{v}"))
        .collect::<Vec<_>>()
        .join("\\")
}

fn write_dicom(path: &Path, s: &Slice, instance: usize) {
    let mut obj = InMemDicomObject::new_empty();
    let mut put = |tag, vr, value: PrimitiveValue| {
        obj.put(DataElement::new(tag, vr, value));
    };
    put(
        tags::SOP_CLASS_UID,
        VR::UI,
        "1.2.840.10008.5.1.4.1.1.2".into(),
    );
    put(
        tags::SOP_INSTANCE_UID,
        VR::UI,
        format!("{}.{instance}", s.series).into(),
    );
    put(tags::MODALITY, VR::CS, "CT".into());
    put(tags::PATIENT_NAME, VR::PN, "Doe^Jane".into());
    put(tags::PATIENT_ID, VR::LO, "MRN-0042".into());
    put(tags::PATIENT_BIRTH_DATE, VR::DA, "19700131".into());
    put(tags::STUDY_DATE, VR::DA, "20261124".into());
    put(tags::STUDY_DESCRIPTION, VR::LO, "CT HEAD WO".into());
    put(tags::SERIES_DESCRIPTION, VR::LO, "AXIAL 2.5".into());
    put(tags::SLICE_THICKNESS, VR::DS, "2.5".into());
    put(tags::SERIES_INSTANCE_UID, VR::UI, s.series.into());
    // InstanceNumber runs against position, so sorting by it would be wrong.
    put(
        tags::INSTANCE_NUMBER,
        VR::IS,
        format!("{}", 100 - instance).into(),
    );
    put(tags::IMAGE_POSITION_PATIENT, VR::DS, ds(&s.position).into());
    put(
        tags::IMAGE_ORIENTATION_PATIENT,
        VR::DS,
        ds(&s.orientation).into(),
    );
    put(tags::PIXEL_SPACING, VR::DS, ds(&[0.5, 0.25]).into());
    put(tags::ROWS, VR::US, PrimitiveValue::from(3u16));
    put(tags::COLUMNS, VR::US, PrimitiveValue::from(4u16));
    put(tags::SAMPLES_PER_PIXEL, VR::US, PrimitiveValue::from(1u16));
    put(
        tags::PHOTOMETRIC_INTERPRETATION,
        VR::CS,
        s.photometric.into(),
    );
    put(tags::BITS_ALLOCATED, VR::US, PrimitiveValue::from(16u16));
    put(
        tags::BITS_STORED,
        VR::US,
        PrimitiveValue::from(s.bits_stored),
    );
    put(
        tags::HIGH_BIT,
        VR::US,
        PrimitiveValue::from(s.bits_stored - 1),
    );
    put(
        tags::PIXEL_REPRESENTATION,
        VR::US,
        PrimitiveValue::from(u16::from(s.signed)),
    );
    put(tags::RESCALE_SLOPE, VR::DS, ds(&[s.slope]).into());
    put(tags::RESCALE_INTERCEPT, VR::DS, ds(&[s.intercept]).into());
    if let Some(p) = s.padding {
        put(tags::PIXEL_PADDING_VALUE, VR::US, PrimitiveValue::from(p));
    }
    put(
        tags::PIXEL_DATA,
        VR::OW,
        PrimitiveValue::U16(s.pixels.clone().into()),
    );
    let file = obj
        .with_meta(FileMetaTableBuilder::new().transfer_syntax("1.2.840.10008.1.2.1"))
        .expect("meta");
    file.write_to_file(path).expect("write DICOM");
}

/// Writes `slices` into a new folder, file names in reverse order of position.
fn dicom_folder(slices: &[Slice]) -> tempfile::TempDir {
    let dir = temp();
    for (i, s) in slices.iter().enumerate() {
        write_dicom(
            &dir.path().join(format!("img{:03}.dcm", slices.len() - i)),
            s,
            i,
        );
    }
    dir
}

fn stack(zs: &[f64]) -> Vec<Slice> {
    zs.iter()
        .enumerate()
        .map(|(i, &z)| Slice {
            position: [0.0, 0.0, z],
            pixels: (0..12).map(|p| (i * 100 + p) as u16).collect(),
            ..Slice::default()
        })
        .collect()
}

#[test]
fn dicom_slices_are_sorted_by_position_with_spacing_from_positions() {
    let slices = stack(&[10.0, 12.5, 15.0, 17.5]);
    // Shuffle the write order: neither file names nor InstanceNumber give the order.
    let shuffled = vec![
        slices[2].clone(),
        slices[0].clone(),
        slices[3].clone(),
        slices[1].clone(),
    ];
    let dir = dicom_folder(&shuffled);
    let source = open(dir.path()).unwrap_or_else(|e| panic!("{e}"));
    let info = source.info().clone();
    assert_eq!(info.geometry.dims, [4, 3, 4]);
    assert_eq!(info.geometry.spacing, [0.25, 0.5, 2.5]);
    assert_eq!(info.geometry.origin, [0.0, 0.0, 10.0]);
    assert_eq!(info.unit.as_deref(), Some("HU"));
    // Patient and study as the headers name them, for the viewer's corners.
    let study = &info.study;
    assert_eq!(study.patient_name.as_deref(), Some("Doe^Jane"));
    assert_eq!(study.patient_id.as_deref(), Some("MRN-0042"));
    assert_eq!(study.patient_birth_date.as_deref(), Some("19700131"));
    assert_eq!(study.study_date.as_deref(), Some("20261124"));
    assert_eq!(study.study_description.as_deref(), Some("CT HEAD WO"));
    assert_eq!(study.series_description.as_deref(), Some("AXIAL 2.5"));
    assert_eq!(study.slice_thickness_mm, Some(2.5));
    // The store keeps them.
    let out = temp();
    let mut source = open(dir.path()).unwrap_or_else(|e| panic!("{e}"));
    let target = out.path().join("series.zarr");
    blocks::store::ingest(
        source.as_mut(),
        &target,
        &blocks::store::IngestOptions::default(),
        &mut |_| {},
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let store = blocks::store::Store::open(target.as_path()).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(&store.meta().study, study);
    let v = load(dir.path());
    // Slice k holds k * 100 + pixel index.
    for k in 0..4 {
        assert_eq!(v.voxels.get(k * 12), (k * 100) as f64, "slice {k} in place");
    }
}

#[test]
fn dicom_bits_stored_sign_extension_monochrome1_and_rescale() {
    // 12 stored bits, signed: 0x0FFF is -1, 0x0800 is -2048; the high bits are noise.
    let mut s = Slice {
        bits_stored: 12,
        signed: true,
        slope: 2.0,
        intercept: -5.0,
        ..Slice::default()
    };
    s.pixels = vec![0xF0FF, 0x0800, 0x07FF, 5, 0, 1, 2, 3, 4, 5, 6, 7];
    s.pixels[0] = 0xFFFF;
    let dir = dicom_folder(std::slice::from_ref(&s));
    let v = load(dir.path());
    assert_eq!(v.voxel_type(), VoxelType::I16);
    assert_eq!(v.voxels.get(0), -1.0);
    assert_eq!(v.voxels.get(1), -2048.0);
    assert_eq!(v.voxels.get(2), 2047.0);
    assert_eq!((v.value_map.slope, v.value_map.intercept), (2.0, -5.0));

    // MONOCHROME1, unsigned 12 bits: v → 4095 − v.
    let m = Slice {
        bits_stored: 12,
        photometric: "MONOCHROME1",
        ..Slice::default()
    };
    let dir = dicom_folder(std::slice::from_ref(&m));
    let v = load(dir.path());
    assert_eq!(v.voxels.get(0), 4095.0);
    assert_eq!(v.voxels.get(1), 4095.0 - 10.0);
}

#[test]
fn dicom_padding_takes_the_lowest_real_value_and_per_slice_rescale_gives_floats() {
    let mut slices = stack(&[0.0, 1.0]);
    for s in &mut slices {
        s.padding = Some(9999);
        s.pixels[0] = 9999;
    }
    let dir = dicom_folder(&slices);
    let v = load(dir.path());
    // The lowest non-padding value is slice 0's pixel 1 (= 1).
    assert_eq!(v.voxels.get(0), 1.0);
    assert_eq!(v.voxels.get(12), 1.0);
    assert!(
        v.value_range[1] < 9999.0,
        "padding is out of the value range"
    );

    let mut slices = stack(&[0.0, 1.0]);
    slices[1].slope = 2.0;
    slices[1].intercept = -1000.0;
    let dir = dicom_folder(&slices);
    let v = load(dir.path());
    assert_eq!(v.voxel_type(), VoxelType::F32);
    assert_eq!(v.voxels.get(12), 100.0 * 2.0 - 1000.0);
}

#[test]
fn dicom_gantry_tilt_becomes_a_sheared_affine_with_a_note() {
    // Axial slices stepping 1 mm in z and 0.5 mm in y: 26.6° tilt.
    let slices: Vec<Slice> = (0..4)
        .map(|i| Slice {
            position: [0.0, 0.5 * f64::from(i), f64::from(i)],
            ..Slice::default()
        })
        .collect();
    let dir = dicom_folder(&slices);
    let source = open(dir.path()).unwrap_or_else(|e| panic!("{e}"));
    let info = source.info();
    assert!(
        info.notes
            .iter()
            .any(|n| n.contains("gantry tilt of 26.57°")),
        "{:?}",
        info.notes
    );
    let d = info.geometry.direction[2];
    assert!(
        (d[1] - 0.5 / 1.25f64.sqrt()).abs() < 1e-9 && (d[2] - 1.0 / 1.25f64.sqrt()).abs() < 1e-9,
        "{d:?}"
    );
    assert!((info.geometry.spacing[2] - 1.25f64.sqrt()).abs() < 1e-9);
}

#[test]
fn dicom_folder_with_several_series_lists_them_and_series_picks_one() {
    let mut slices = stack(&[0.0, 1.0]);
    slices.extend(stack(&[0.0, 1.0, 2.0]).into_iter().map(|s| Slice {
        series: "1.2.3.5",
        ..s
    }));
    let dir = dicom_folder(&slices);
    let msg = message_naming(open(dir.path()), &dir.path().display().to_string());
    assert!(
        msg.contains("holds 2 DICOM series; choose one with --series"),
        "{msg}"
    );
    assert!(
        msg.contains("1.2.3.4  CT 2 slices of 4x3") && msg.contains("1.2.3.5  CT 3 slices"),
        "{msg}"
    );
    let options = OpenOptions {
        series: Some("1.2.3.5".into()),
        ..OpenOptions::default()
    };
    let source = ingest::open(dir.path(), &options).expect("chosen series");
    assert_eq!(source.info().geometry.dims, [4, 3, 3]);
    let options = OpenOptions {
        series: Some("9.9".into()),
        ..OpenOptions::default()
    };
    let msg = ingest::open(dir.path(), &options)
        .expect_err("unknown")
        .to_string();
    assert!(
        msg.contains("--series: '9.9': expected one of 1.2.3.4, 1.2.3.5"),
        "{msg}"
    );
}

// ---- bad input ------------------------------------------------------------------

#[test]
fn truncated_raw_data_and_a_size_mismatch_are_refused() {
    let dir = temp();
    let short = dir.path().join("short_4x3x2_uint16.raw");
    write(&short, &le_bytes(&ramp_u16())[..40]);
    let msg = message_naming(open(&short), "short_4x3x2_uint16.raw");
    assert!(
        msg.contains("size: 40 bytes") && msg.contains("take 48"),
        "{msg}"
    );
    let long = dir.path().join("long_4x3x2_uint8.raw");
    write(&long, &[0; 30]);
    let msg = message_naming(open(&long), "long_4x3x2_uint8.raw");
    assert!(msg.contains("expected the file size to match"), "{msg}");

    // An attached NRRD whose data stops short.
    let nrrd = dir.path().join("cut.nrrd");
    let mut bytes =
        b"NRRD0004\ntype: uint8\ndimension: 3\nsizes: 4 3 2\nencoding: raw\n\n".to_vec();
    bytes.extend([1u8; 20]);
    write(&nrrd, &bytes);
    let msg = message_naming(open(&nrrd), "cut.nrrd");
    assert!(
        msg.contains("truncated voxel data") && msg.contains("promises 24 bytes"),
        "{msg}"
    );
}

#[test]
fn corrupt_gzip_and_zlib_streams_are_refused() {
    let dir = temp();
    let nrrd = dir.path().join("bad.nrrd");
    let mut bytes =
        b"NRRD0004\ntype: uint8\ndimension: 3\nsizes: 4 3 2\nencoding: gzip\n\n".to_vec();
    let mut stream = gzip(&[7u8; 24]);
    let n = stream.len();
    stream[12..n - 8].fill(0xFF); // wreck the deflate data
    bytes.extend(stream);
    write(&nrrd, &bytes);
    let mut source = open(&nrrd).expect("the header is fine");
    let msg = message_naming(source.read_slab(0, 2), "bad.nrrd");
    assert!(msg.contains("corrupt gzip data"), "{msg}");

    let mha = dir.path().join("bad.mha");
    let mut bytes = b"NDims = 3\nDimSize = 4 3 2\nElementType = MET_UCHAR\nCompressedData = True\nElementDataFile = LOCAL\n".to_vec();
    bytes.extend([0x78, 0x9c, 0xFF, 0xFF, 0xFF, 0x00, 0x13]);
    write(&mha, &bytes);
    let mut source = open(&mha).expect("the header is fine");
    let msg = message_naming(source.read_slab(0, 2), "bad.mha");
    assert!(msg.contains("corrupt zlib data"), "{msg}");

    let gz = dir.path().join("bad.nii.gz");
    write(&gz, &[0x1f, 0x8b, 8, 0, 0, 0, 0, 0, 0, 3, 0xFF, 0xFF, 0xFF]);
    let msg = message_naming(open(&gz), "bad.nii.gz");
    assert!(
        msg.contains("corrupt gzip data") || msg.contains("header"),
        "{msg}"
    );
}

#[test]
fn a_missing_detached_data_file_is_named() {
    let dir = temp();
    let nhdr = dir.path().join("v.nhdr");
    write(
        &nhdr,
        b"NRRD0004\ntype: uint8\ndimension: 3\nsizes: 4 3 2\nencoding: raw\ndata file: gone.raw\n",
    );
    let msg = message_naming(open(&nhdr), "v.nhdr");
    assert!(
        msg.contains("data file: ") && msg.contains("gone.raw not found"),
        "{msg}"
    );
    let mhd = dir.path().join("v.mhd");
    write(
        &mhd,
        b"NDims = 3\nDimSize = 4 3 2\nElementType = MET_UCHAR\nElementDataFile = gone.raw\n",
    );
    let msg = message_naming(open(&mhd), "v.mhd");
    assert!(msg.contains("gone.raw not found"), "{msg}");
}

#[test]
fn an_unknown_nifti_datatype_is_named() {
    let dir = temp();
    let nii = dir.path().join("rgb.nii");
    let mut bytes = nifti_header(128, 24, 1.0, 0.0);
    bytes.extend([0u8; 72]);
    write(&nii, &bytes);
    let msg = message_naming(open(&nii), "rgb.nii");
    assert!(
        msg.contains("datatype: 128 (rgb24): expected uint8 (2)"),
        "{msg}"
    );
}

#[test]
fn a_dicom_folder_with_a_missing_slice_or_a_duplicate_is_refused() {
    let dir = dicom_folder(&stack(&[0.0, 1.0, 2.0, 4.0, 5.0]));
    let msg = message_naming(open(dir.path()), ".dcm");
    assert!(
        msg.contains("missing slice") && msg.contains("gap is 2.000 mm, expected 1.000 mm"),
        "{msg}"
    );

    let dir = dicom_folder(&stack(&[0.0, 1.0, 2.3, 3.0]));
    let msg = message_naming(open(dir.path()), ".dcm");
    assert!(msg.contains("uneven slice spacing"), "{msg}");

    let dir = dicom_folder(&stack(&[0.0, 1.0, 1.0, 2.0]));
    let msg = message_naming(open(dir.path()), ".dcm");
    assert!(msg.contains("same position as"), "{msg}");
}

#[test]
fn non_dicom_files_in_a_dicom_folder_are_skipped_and_named_when_nothing_is_left() {
    let dir = dicom_folder(&stack(&[0.0, 1.0]));
    write(&dir.path().join("README.txt"), b"not an image");
    // Hidden files are passed over.
    write(&dir.path().join(".DS_Store"), b"\0\0\0\x01Bud1");
    let source = open(dir.path()).expect("the series, README.txt skipped");
    assert_eq!(source.info().geometry.dims, [4, 3, 2]);
    // With no image left, the error names what was skipped and why.
    let only = temp();
    write(&only.path().join("README.txt"), b"not an image");
    let msg = message_naming(open(only.path()), "README.txt");
    assert!(
        msg.contains("none found") && msg.contains("not DICOM: no DICM marker at byte 128"),
        "{msg}"
    );
}

#[test]
fn absurd_header_dimensions_are_refused_before_allocating() {
    let dir = temp();
    let nrrd = dir.path().join("huge.nrrd");
    write(&nrrd, b"NRRD0004\ntype: uint8\ndimension: 3\nsizes: 1000000 1000000 1000000\nencoding: raw\n\n\0\0\0\0");
    let msg = message_naming(open(&nrrd), "huge.nrrd");
    assert!(
        msg.contains("sizes: 1000000 × 1000000 × 1000000") && msg.contains("per slice"),
        "{msg}"
    );

    let mha = dir.path().join("huge.mha");
    write(&mha, b"NDims = 3\nDimSize = 1000000 1000000 1000000\nElementType = MET_SHORT\nElementDataFile = LOCAL\n");
    let msg = message_naming(open(&mha), "huge.mha");
    assert!(msg.contains("DimSize"), "{msg}");

    // Plausible slices, but far more voxels than the compressed stream can hold.
    let gz = dir.path().join("big.nrrd");
    let mut bytes =
        b"NRRD0004\ntype: uint8\ndimension: 3\nsizes: 1024 1024 100000\nencoding: gzip\n\n"
            .to_vec();
    bytes.extend(gzip(&[0u8; 100]));
    write(&gz, &bytes);
    let msg = message_naming(open(&gz), "big.nrrd");
    assert!(
        msg.contains("more than the") && msg.contains("gzip stream can expand to"),
        "{msg}"
    );

    // NIfTI dims are 16-bit: the largest it can claim, 65535³, is refused too.
    let nii = dir.path().join("huge.nii");
    let mut bytes = nifti_header(2, 8, 1.0, 0.0);
    for i in 1..=3 {
        bytes[40 + 2 * i..42 + 2 * i].copy_from_slice(&65535u16.to_le_bytes());
    }
    bytes.extend([0u8; 16]);
    write(&nii, &bytes);
    let msg = message_naming(open(&nii), "huge.nii");
    assert!(msg.contains("dim: 65535 × 65535 × 65535"), "{msg}");

    let raw = dir.path().join("huge_1000000x1000000x1000000_uint8.raw");
    write(&raw, &[0; 8]);
    let msg = message_naming(open(&raw), "huge_1000000x1000000x1000000_uint8.raw");
    assert!(msg.contains("dims: "), "{msg}");
}

#[test]
fn headers_with_bad_fields_name_them() {
    let dir = temp();
    let cases: [(&str, &[u8], &str); 7] = [
        ("t.nrrd", b"NRRD0004\ntype: complex\ndimension: 3\nsizes: 1 1 1\nencoding: raw\n\n\0", "type: 'complex'"),
        ("e.nrrd", b"NRRD0004\ntype: short\ndimension: 3\nsizes: 1 1 1\nencoding: raw\n\n\0\0", "endian: missing"),
        ("c.nrrd", b"NRRD0004\ntype: uint8\ndimension: 3\nsizes: 1 1 1\nencoding: bzip2\n\n\0", "encoding: 'bzip2': expected raw or gzip"),
        ("s.nrrd", b"NRRD0004\ntype: uint8\ndimension: 3\nsizes: 1 1\nencoding: raw\n\n\0", "sizes: '1 1': expected 3 numbers"),
        ("m.nrrd", b"NRRX0004\n\n", "magic"),
        ("f.nrrd", b"NRRD0004\ntype: uint8\ndimension: 3\nsizes: 1 1 1\nencoding: raw\nspace directions: (1,0,0) (2,0,0) (0,0,1)\n\n\0", "expected three independent directions"),
        ("k.mha", b"NDims = 3\nDimSize = 1 1 1\nElementType = MET_LONG\nElementDataFile = LOCAL\n\0", "ElementType: 'MET_LONG'"),
    ];
    for (name, bytes, expected) in cases {
        let path = dir.path().join(name);
        write(&path, bytes);
        let msg = message_naming(open(&path), name);
        assert!(msg.contains(expected), "{name}: {msg}");
    }
    let unknown = dir.path().join("mystery.dat");
    write(&unknown, b"hello");
    let msg = message_naming(open(&unknown), "mystery.dat");
    assert!(msg.contains("unknown volume format"), "{msg}");
}

#[test]
fn compressed_slabs_read_out_of_order_match_in_order_reads() {
    let dir = temp();
    let path = dir.path().join("order.nrrd");
    let voxels: Vec<u8> = (0..4 * 3 * 10).map(|i| (i * 7 % 251) as u8).collect();
    let mut bytes =
        b"NRRD0004\ntype: uint8\ndimension: 3\nsizes: 4 3 10\nencoding: gzip\n\n".to_vec();
    bytes.extend(gzip(&voxels));
    write(&path, &bytes);
    let mut source = open(&path).expect("open");
    let late = source.read_slab(7, 3).expect("slab 7..10");
    let early = source.read_slab(1, 2).expect("slab 1..3 after going back");
    assert_eq!(late, VoxelData::U8(voxels[84..120].to_vec()));
    assert_eq!(early, VoxelData::U8(voxels[12..36].to_vec()));
    let msg = source
        .read_slab(9, 5)
        .expect_err("past the end")
        .to_string();
    assert!(
        msg.contains("slab: slices 9..14: expected a non-empty range within 0..10"),
        "{msg}"
    );
}

// ---- hostile inputs (issue 14) ----------------------------------------------
// The binary runs a larger generated corpus of these: server/tests/malformed.rs.

/// The error of opening `path` and reading all its voxels.
fn scan_error(path: &Path, options: &OpenOptions) -> String {
    let result = ingest::open(path, options).and_then(|mut s| ingest::scan(s.as_mut(), |_| {}));
    result.expect_err("must be refused").to_string()
}

#[test]
fn infinite_float_voxels_are_refused_naming_the_slice_and_nan_stays_missing() {
    let dir = temp();
    let floats = |bad: f32, at: usize| -> Vec<u8> {
        (0..24)
            .flat_map(|i| (if i == at { bad } else { 1.0f32 }).to_le_bytes())
            .collect()
    };
    let inf = dir.path().join("inf_4x3x2_float32.raw");
    write(&inf, &floats(f32::INFINITY, 12 + 5));
    let msg = scan_error(&inf, &OpenOptions::default());
    assert!(
        msg.contains("inf_4x3x2_float32.raw: voxel data: slice 1 holds inf at voxel (x 1, y 1)"),
        "{msg}"
    );
    let nan = dir.path().join("nan_4x3x2_float32.raw");
    write(&nan, &floats(f32::NAN, 3));
    let mut source = open(&nan).expect("open");
    let stats = ingest::scan(source.as_mut(), |_| {}).expect("NaN is a missing value");
    assert_eq!((stats.nans, stats.stored_range), (1, [1.0, 1.0]));
}

/// An RLE Lossless file of 4 × 4 8-bit pixels whose one segment decodes to a
/// single byte: dicom-rs 0.10's RLE decoder indexes past it and panics.
fn write_rle_short_segment(path: &Path) {
    use dicom_core::value::PixelFragmentSequence;
    let mut fragment = vec![0u8; 64];
    fragment[..4].copy_from_slice(&1u32.to_le_bytes()); // one segment
    fragment[4..8].copy_from_slice(&64u32.to_le_bytes()); // at byte 64
    fragment.extend_from_slice(&[0, 5]); // a literal run of one byte
    let mut obj = InMemDicomObject::new_empty();
    for (tag, vr, value) in [
        (tags::SOP_CLASS_UID, VR::UI, "1.2.840.10008.5.1.4.1.1.2"),
        (tags::SOP_INSTANCE_UID, VR::UI, "1.2.3.4.5"),
        (tags::SERIES_INSTANCE_UID, VR::UI, "1.2.3.4"),
        (tags::PHOTOMETRIC_INTERPRETATION, VR::CS, "MONOCHROME2"),
    ] {
        obj.put(DataElement::new(tag, vr, PrimitiveValue::from(value)));
    }
    for (tag, value) in [
        (tags::ROWS, 4u16),
        (tags::COLUMNS, 4),
        (tags::SAMPLES_PER_PIXEL, 1),
        (tags::BITS_ALLOCATED, 8),
        (tags::BITS_STORED, 8),
        (tags::HIGH_BIT, 7),
        (tags::PIXEL_REPRESENTATION, 0),
    ] {
        obj.put(DataElement::new(tag, VR::US, PrimitiveValue::from(value)));
    }
    obj.put(DataElement::new(
        tags::PIXEL_DATA,
        VR::OB,
        PixelFragmentSequence::new_fragments(vec![fragment]),
    ));
    obj.with_meta(FileMetaTableBuilder::new().transfer_syntax("1.2.840.10008.1.2.5"))
        .expect("meta")
        .write_to_file(path)
        .expect("write DICOM");
}

#[test]
fn a_panic_in_the_rle_decoder_is_an_error_naming_the_file() {
    let dir = temp();
    let path = dir.path().join("rle.dcm");
    write_rle_short_segment(&path);
    let msg = scan_error(&path, &OpenOptions::default());
    assert!(
        msg.contains("rle.dcm: the RLE Lossless (1.2.840.10008.1.2.5) pixel data decoder failed")
            && msg.contains("index out of bounds"),
        "{msg}"
    );
    // The real file with the flipped byte: server/tests/malformed.rs, when the
    // shared data is there.
}

/// Sets the 4-byte length of the explicit-VR element `tag` with VR `vr`.
fn set_long_length(bytes: &mut [u8], tag: (u16, u16), vr: &[u8; 2], len: u32) {
    let mut header = tag.0.to_le_bytes().to_vec();
    header.extend_from_slice(&tag.1.to_le_bytes());
    header.extend_from_slice(vr);
    let at = bytes
        .windows(header.len())
        .position(|w| w == header.as_slice())
        .expect("element");
    bytes[at + 8..at + 12].copy_from_slice(&len.to_le_bytes());
}

#[test]
fn dicom_lengths_past_the_end_of_the_file_are_refused_before_reading() {
    let dir = temp();
    let good = dir.path().join("good.dcm");
    write_dicom(&good, &Slice::default(), 0);
    let bytes = std::fs::read(&good).expect("read");
    for (name, tag, vr, what) in [
        ("pixels.dcm", (0x7fe0, 0x0010), b"OW", "element (7FE0,0010)"),
        (
            "meta.dcm",
            (0x0002, 0x0001),
            b"OB",
            "file meta element (0002,0001)",
        ),
    ] {
        let mut b = bytes.clone();
        set_long_length(&mut b, tag, vr, 0xFFFF_FFF0);
        let path = dir.path().join(name);
        write(&path, &b);
        let msg = scan_error(&path, &OpenOptions::default());
        assert!(
            msg.contains(&format!(
                "{name}: {what}: declares 4294967280 bytes at byte"
            )),
            "{msg}"
        );
    }
}

#[test]
fn detached_data_files_must_be_regular_files_in_the_headers_folder() {
    let root = temp();
    let dir = root.path().join("headers");
    std::fs::create_dir(&dir).expect("dir");
    write(&root.path().join("outside.raw"), &[1u8; 24]);
    write(&dir.join("inside.raw"), &[1u8; 24]);
    let header = |name: &str, data: &str| {
        let p = dir.join(name);
        let text = format!(
            "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 4 3 2\nencoding: raw\ndata file: {data}\n"
        );
        write(&p, text.as_bytes());
        p
    };
    let allow = OpenOptions {
        allow_data_outside: true,
        ..OpenOptions::default()
    };
    for data in ["/etc/passwd", "../outside.raw"] {
        let p = header("away.nhdr", data);
        let msg = message_naming(open(&p), "away.nhdr");
        assert!(
            msg.contains("data file: '")
                && msg.contains("outside the header's folder")
                && msg.contains("--allow-data-outside"),
            "{msg}"
        );
        assert!(
            ingest::open(&p, &allow).is_ok(),
            "{data} with --allow-data-outside"
        );
    }
    // A link inside the folder to a file outside it is outside too.
    std::os::unix::fs::symlink(root.path().join("outside.raw"), dir.join("link.raw"))
        .expect("symlink");
    let msg = message_naming(open(&header("link.nhdr", "link.raw")), "link.nhdr");
    assert!(msg.contains("outside the header's folder"), "{msg}");
    assert!(open(&header("in.nhdr", "inside.raw")).is_ok());
    // A device never ends: refused at once, even where outside data is allowed.
    let p = header("zero.nhdr", "/dev/zero\nline skip: 1000000000000");
    let msg = ingest::open(&p, &allow).expect_err("a device").to_string();
    assert!(
        msg.contains("zero.nhdr: data file: '/dev/zero' is not a regular file"),
        "{msg}"
    );
    let start = std::time::Instant::now();
    let msg = message_naming(
        open(&header(
            "lines.nhdr",
            "inside.raw\nline skip: 1000000000000",
        )),
        "lines.nhdr",
    );
    assert!(
        msg.contains("line skip: 1000000000000 lines") && msg.contains("ends first"),
        "{msg}"
    );
    assert!(start.elapsed().as_secs() < 2);
}

#[test]
fn sizes_from_headers_that_overflow_are_refused() {
    let dir = temp();
    let mha = dir.path().join("wrap.mha");
    let mut b = b"NDims = 3\nDimSize = 4 3 2\nElementType = MET_UCHAR\nHeaderSize = 18446744073709551500\nElementDataFile = LOCAL\n".to_vec();
    b.extend_from_slice(&[1u8; 24]);
    write(&mha, &b);
    let msg = message_naming(open(&mha), "wrap.mha");
    assert!(
        msg.contains("HeaderSize: 18446744073709551500: the voxels would start past the end"),
        "{msg}"
    );
    let nrrd = dir.path().join("skip.nrrd");
    let mut b = b"NRRD0004\ntype: uint8\ndimension: 3\nsizes: 4 3 2\nencoding: gzip\nbyte skip: 18446744073709551615\n\n".to_vec();
    b.extend(gzip(&[1u8; 24]));
    write(&nrrd, &b);
    let msg = message_naming(open(&nrrd), "skip.nrrd");
    assert!(
        msg.contains("byte skip: 18446744073709551615 bytes to skip"),
        "{msg}"
    );
    let raw = dir.path().join("v.bin");
    write(&raw, &[0u8; 8]);
    let options = OpenOptions {
        raw: RawOptions {
            dims: Some([4_294_967_296, 4_294_967_296, 1]),
            sample: Some(SampleType::Voxel(VoxelType::U8)),
            ..RawOptions::default()
        },
        ..OpenOptions::default()
    };
    let msg = message_naming(ingest::open(&raw, &options), "v.bin");
    assert!(
        msg.contains("4294967296 voxels along x is out of range: expected 1 to 4294967295"),
        "{msg}"
    );
}

#[test]
fn absurd_scaling_and_an_empty_nifti_are_refused_clearly() {
    let dir = temp();
    let p = dir.path().join("slope.nii");
    let mut b = nifti_header(2, 8, 3e38, 0.0);
    b.extend_from_slice(&[1u8; 24]);
    write(&p, &b);
    let msg = message_naming(open(&p), "slope.nii");
    assert!(
        msg.contains("scl_slope and scl_inter: slope")
            && msg.contains("expected physical values within ±1e30"),
        "{msg}"
    );
    let empty = dir.path().join("empty.nii.gz");
    write(&empty, &[]);
    let msg = message_naming(open(&empty), "empty.nii.gz");
    assert!(
        msg.contains("header: the file ends before the header does") && !msg.contains("Error {"),
        "{msg}"
    );
}

#[test]
fn directions_that_are_not_orthonormal_are_refused() {
    let dir = temp();
    let mha = dir.path().join("scaled.mha");
    let mut b = b"NDims = 3\nDimSize = 4 3 2\nElementType = MET_UCHAR\nTransformMatrix = 1000 0 0 0 0.001 0 0 0 1\nElementDataFile = LOCAL\n".to_vec();
    b.extend_from_slice(&[1u8; 24]);
    write(&mha, &b);
    let msg = message_naming(open(&mha), "scaled.mha");
    assert!(
        msg.contains("TransformMatrix: the direction of index axis x"),
        "{msg}"
    );
    let dcm = dicom_folder(&[Slice {
        orientation: [2.0, 0.0, 0.0, 0.0, 0.5, 0.0],
        ..Slice::default()
    }]);
    let msg = open(dcm.path())
        .expect_err("scaled orientation")
        .to_string();
    assert!(
        msg.contains("ImageOrientationPatient (0020,0037): the direction of index axis x"),
        "{msg}"
    );
    let nii = dir.path().join("quaternion.nii");
    let mut h = nifti_header(2, 8, 1.0, 0.0);
    h[252..254].copy_from_slice(&1i16.to_le_bytes()); // qform_code
    h[254..256].copy_from_slice(&0i16.to_le_bytes()); // no sform
    for (i, q) in [0.6f32, 0.6, 0.6].iter().enumerate() {
        h[256 + 4 * i..260 + 4 * i].copy_from_slice(&q.to_le_bytes());
    }
    h.extend_from_slice(&[1u8; 24]);
    write(&nii, &h);
    let msg = message_naming(open(&nii), "quaternion.nii");
    assert!(
        msg.contains("quatern_b, quatern_c, quatern_d: (0.6") && msg.contains("expected at most 1"),
        "{msg}"
    );
    // Stacked off the normal, but about neither image axis: no gantry does that.
    let sheared: Vec<Slice> = (0..4)
        .map(|i| Slice {
            position: [0.5 * f64::from(i), 0.5 * f64::from(i), f64::from(i)],
            ..Slice::default()
        })
        .collect();
    let folder = dicom_folder(&sheared);
    let msg = open(folder.path()).expect_err("shear").to_string();
    assert!(
        msg.contains("expected a stack along the normal, or a gantry tilt"),
        "{msg}"
    );
}

#[test]
fn symlinked_dicom_slices_are_read_inside_the_folder_and_named_outside_it() {
    let elsewhere = dicom_folder(&stack(&[0.0, 1.0]));
    let folder = temp();
    for name in ["img001.dcm", "img002.dcm"] {
        std::os::unix::fs::symlink(elsewhere.path().join(name), folder.path().join(name))
            .expect("symlink");
    }
    let msg = message_naming(open(folder.path()), "img001.dcm");
    assert!(
        msg.contains("none found")
            && msg.contains("a symbolic link to")
            && msg.contains("outside the folder; --allow-data-outside reads it"),
        "{msg}"
    );
    let allow = OpenOptions {
        allow_data_outside: true,
        ..OpenOptions::default()
    };
    assert_eq!(
        ingest::open(folder.path(), &allow)
            .expect("allowed")
            .info()
            .geometry
            .dims[2],
        2
    );
    // Links to files inside the folder (here in a subfolder, which is not read
    // itself) are followed.
    let inside = temp();
    let data = inside.path().join("data");
    std::fs::create_dir(&data).expect("subfolder");
    for name in ["img001.dcm", "img002.dcm"] {
        std::fs::copy(elsewhere.path().join(name), data.join(name)).expect("copy");
        std::os::unix::fs::symlink(data.join(name), inside.path().join(name)).expect("symlink");
    }
    assert_eq!(
        open(inside.path())
            .expect("links inside")
            .info()
            .geometry
            .dims[2],
        2
    );
}
