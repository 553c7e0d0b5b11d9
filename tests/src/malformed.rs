//! A corpus of malformed and hostile inputs, generated small into a folder:
//! every reader (raw names, NRRD attached/detached/gzip, NIfTI `.nii`/`.nii.gz`,
//! MetaImage `.mha`/`.mhd`, DICOM files and folders) fed truncations, absurd
//! sizes, overflowing offsets, bad types, bad directions, infinite data,
//! paths leading elsewhere and a dependency's panic.
//!
//! [`corpus`] writes the files and returns the table of [`Case`]s: what to run
//! and what the error must name. `server/tests/malformed.rs` runs the real
//! binary on each. Add a case (a malformed brick store, say) by pushing one
//! more [`Case`]: a name, the input, extra arguments and the words its error
//! must contain.

use std::io::Write;
use std::path::{Path, PathBuf};

use dicom_core::value::PixelFragmentSequence;
use dicom_core::{DataElement, PrimitiveValue, VR};
use dicom_dictionary_std::tags;
use dicom_object::{FileMetaTableBuilder, InMemDicomObject};

/// The subcommand a case runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Run {
    /// `voxserve info INPUT`.
    Info,
    /// `voxserve info INPUT`, then `voxserve ingest INPUT --out …`.
    InfoAndIngest,
    /// `voxserve info STORE`, then `voxserve verify STORE`.
    InfoAndVerify,
    /// `voxserve verify STORE` (damage that only reading every byte finds).
    Verify,
}

/// One malformed input and what its error must say.
#[derive(Debug, Clone)]
pub struct Case {
    /// A short name, for the report.
    pub name: String,
    /// The file or folder given to voxserve.
    pub input: PathBuf,
    /// Arguments after the input (raw layout flags, `--allow-data-outside`).
    pub args: Vec<String>,
    /// What to run.
    pub run: Run,
    /// Words the error must contain besides the input's file name (a field,
    /// what was expected).
    pub expect: Vec<String>,
}

/// A table of cases being written into one folder.
#[derive(Debug)]
pub struct Corpus {
    dir: PathBuf,
    /// The cases so far.
    pub cases: Vec<Case>,
}

impl Corpus {
    /// An empty corpus writing into `dir`.
    pub fn new(dir: &Path) -> Corpus {
        Corpus {
            dir: dir.to_owned(),
            cases: Vec::new(),
        }
    }

    /// The path of `name` in the corpus folder.
    pub fn path(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }

    /// Writes `bytes` as `name` and adds an `info` case expecting `expect`.
    pub fn file(&mut self, name: &str, bytes: &[u8], expect: &[&str]) -> &mut Case {
        let path = self.path(name);
        write(&path, bytes);
        self.case(name, path, expect)
    }

    /// Writes an 8 × 8 Explicit VR Little Endian DICOM slice as `name`, changed
    /// by `edit`, and adds an `info` case expecting `expect`.
    pub fn dicom(
        &mut self,
        name: &str,
        edit: impl FnOnce(&mut InMemDicomObject),
        expect: &[&str],
    ) -> &mut Case {
        let path = self.path(name);
        dicom_slice(&path, 8, 8, EXPLICIT_LE, edit);
        self.case(name, path, expect)
    }

    /// Adds an `info` case on `input` (already written) expecting `expect`.
    pub fn case(&mut self, name: &str, input: PathBuf, expect: &[&str]) -> &mut Case {
        self.cases.push(Case {
            name: name.to_owned(),
            input,
            args: Vec::new(),
            run: Run::Info,
            expect: expect.iter().map(|s| (*s).to_owned()).collect(),
        });
        let last = self.cases.len() - 1;
        &mut self.cases[last]
    }
}

impl Case {
    /// Also runs `ingest` on this input.
    pub fn and_ingest(&mut self) -> &mut Case {
        self.run = Run::InfoAndIngest;
        self
    }

    /// Adds arguments after the input.
    pub fn with_args(&mut self, args: &[&str]) -> &mut Case {
        self.args.extend(args.iter().map(|s| (*s).to_owned()));
        self
    }
}

/// Writes `bytes` to `path`.
///
/// # Panics
/// When the file cannot be written.
pub fn write(path: &Path, bytes: &[u8]) {
    std::fs::write(path, bytes).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
}

/// `bytes` gzip-compressed.
pub fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    e.write_all(bytes).expect("gzip in memory");
    e.finish().expect("gzip in memory")
}

/// `bytes` zlib-compressed.
pub fn zlib(bytes: &[u8]) -> Vec<u8> {
    let mut e = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
    e.write_all(bytes).expect("zlib in memory");
    e.finish().expect("zlib in memory")
}

/// `n` little-endian 32-bit floats, all 1 but `bad` at index `at`.
fn floats_with(n: usize, at: usize, bad: f32) -> Vec<u8> {
    (0..n)
        .flat_map(|i| (if i == at { bad } else { 1.0f32 }).to_le_bytes())
        .collect()
}

/// Writes the whole corpus into `dir` (which must exist) and returns its cases.
pub fn corpus(dir: &Path) -> Vec<Case> {
    let mut c = Corpus::new(dir);
    raw_cases(&mut c);
    nrrd_cases(&mut c);
    nifti_cases(&mut c);
    metaimage_cases(&mut c);
    dicom_file_cases(&mut c);
    dicom_folder_cases(&mut c);
    store_cases(&mut c);
    c.cases
}

/// Ingests the 24³ phantom as a store named `name` in the corpus folder.
fn store(c: &Corpus, name: &str) -> PathBuf {
    let path = c.path(name);
    let volume = std::sync::Arc::new(blocks::phantom::head(24).expect("phantom"));
    let mut source = blocks::ingest::MemorySource::new(volume, "phantom");
    blocks::store::ingest(&mut source, &path, &Default::default(), &mut |_| {})
        .unwrap_or_else(|e| panic!("{name}: {e}"));
    path
}

/// Damaged brick stores: missing files, changed metadata, hostile manifests,
/// an older format, an ingest's leftover.
fn store_cases(c: &mut Corpus) {
    let missing_shard = store(c, "missing-shard.zarr");
    std::fs::remove_file(missing_shard.join("0/c/0/0/0")).expect("rm");
    c.case("missing-shard.zarr", missing_shard, &["0/c/0/0/0: missing"])
        .run = Run::InfoAndVerify;
    let missing_stats = store(c, "missing-stats.zarr");
    std::fs::remove_dir_all(missing_stats.join("voxserve/block_histogram/c")).expect("rm");
    c.case(
        "missing-stats.zarr",
        missing_stats,
        &["block_histogram/c/", "missing"],
    )
    .run = Run::InfoAndVerify;
    let respaced = store(c, "respaced.zarr");
    let root = respaced.join("zarr.json");
    let text = std::fs::read_to_string(&root).expect("read");
    // CT → MR at the same length (another preset, another meaning): only the
    // checksum tells.
    let changed = text.replacen("\"modality\": \"CT\"", "\"modality\": \"MR\"", 1);
    assert_ne!(changed, text, "the root metadata names the modality");
    write(&root, changed.as_bytes());
    c.case("respaced.zarr", respaced, &["zarr.json", "SHA-256"])
        .run = Run::InfoAndVerify;
    let huge = store(c, "huge-metadata.zarr");
    write(&huge.join("zarr.json"), &vec![b' '; 40 << 20]);
    c.case(
        "huge-metadata.zarr",
        huge,
        &["zarr.json", "the manifest says"],
    )
    .run = Run::InfoAndVerify;
    let flipped = store(c, "flipped-byte.zarr");
    let shard = flipped.join("0/c/0/0/0");
    let mut bytes = std::fs::read(&shard).expect("read");
    let middle = bytes.len() / 2;
    bytes[middle] ^= 0x10;
    write(&shard, &bytes);
    c.case("flipped-byte.zarr", flipped, &["0/c/0/0/0", "SHA-256"])
        .run = Run::Verify;
    let stray = store(c, "stray-file.zarr");
    write(&stray.join("0/c/7"), b"stray");
    c.case("stray-file.zarr", stray, &["0/c/7", "not in the manifest"])
        .run = Run::Verify;
    manifest_cases(c);
}

/// Stores whose manifest is missing, damaged or hostile, and one of format 1.
fn manifest_cases(c: &mut Corpus) {
    let manifest = blocks::store::manifest::MANIFEST_KEY;
    let no_manifest = store(c, "no-manifest.zarr");
    std::fs::remove_file(no_manifest.join(manifest)).expect("rm");
    c.case("no-manifest.zarr", no_manifest, &["manifest", "missing"])
        .run = Run::InfoAndVerify;
    for (name, edit, expect) in [
        (
            "manifest-garbage.zarr",
            "{\"files\": 7",
            &["manifest: invalid type"][..],
        ),
        (
            "manifest-escape.zarr",
            "../../../etc/passwd",
            &["manifest", "a relative path inside the store"][..],
        ),
        (
            "manifest-md5.zarr",
            "md5",
            &["algorithm", "expected sha256"][..],
        ),
    ] {
        let path = store(c, name);
        let file = path.join(manifest);
        let text = std::fs::read_to_string(&file).expect("read");
        let changed = match edit {
            "md5" => text.replacen("\"sha256\",", "\"md5\",", 1),
            "../../../etc/passwd" => text.replacen("\"0/c/0/0/0\"", "\"../../../etc/passwd\"", 1),
            garbage => garbage.to_owned(),
        };
        write(&file, changed.as_bytes());
        c.case(name, path, expect).run = Run::InfoAndVerify;
    }
    let old = store(c, "format-1.zarr");
    std::fs::remove_file(old.join(manifest)).expect("rm");
    let root = old.join("zarr.json");
    let text = std::fs::read_to_string(&root).expect("read");
    write(
        &root,
        text.replacen("\"format_version\": 2", "\"format_version\": 1", 1)
            .as_bytes(),
    );
    c.case(
        "format-1.zarr",
        old,
        &["format_version: 1: expected 2", "ingest the source again"],
    );
    let partial = c.path(".scan.zarr.partial-1");
    std::fs::create_dir_all(partial.join("0")).expect("mkdir");
    c.case(".scan.zarr.partial-1", partial, &["did not finish"]);
}

fn raw_cases(c: &mut Corpus) {
    c.file(
        "short_4x3x2_uint16.raw",
        &[0u8; 10],
        &["size", "expected the file size"],
    );
    c.file("long_4x3x2_uint8.raw", &[0u8; 100], &["size"]);
    c.file("empty_4x3x2_uint8.raw", &[], &["size"]);
    c.file(
        "huge_100000x100000x100000_uint8.raw",
        &[0u8; 8],
        &["dims", "per slice"],
    );
    c.file("zero_0x3x2_uint8.raw", &[], &["dims", "at least one voxel"]);
    c.file("volume.raw", &[0u8; 24], &["dims", "not given"]);
    // Finding: --raw-dims beyond u32 reported an overflowed slice size.
    c.file(
        "dims-overflow.bin",
        &[0u8; 8],
        &["dims", "out of range", "4294967295"],
    )
    .with_args(&[
        "--raw-dims",
        "4294967296x4294967296x1",
        "--raw-type",
        "uint8",
    ]);
    // Finding: float data holding infinity ingested into an unreadable store.
    c.file(
        "inf_4x3x2_float32.raw",
        &floats_with(24, 13, f32::INFINITY),
        &["voxel data", "slice 1", "inf"],
    )
    .and_ingest();
    c.file(
        "neginf_4x3x2_float32.raw",
        &floats_with(24, 2, f32::NEG_INFINITY),
        &["voxel data", "slice 0", "-inf"],
    )
    .and_ingest();
    c.file(
        "sheared_4x3x2_uint8.raw",
        &[0u8; 24],
        &["direction", "perpendicular"],
    )
    .with_args(&["--raw-direction", "1,0,0,0.5,0.866,0,0,0,1"]);
}

/// A NRRD header for 4 × 3 × 2 uint8 voxels, with `extra` lines, ending with
/// the blank line of an attached header when `attached`.
fn nrrd(extra: &str, attached: bool) -> String {
    format!(
        "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 4 3 2\n{extra}{}",
        if attached { "\n" } else { "" }
    )
}

fn nrrd_cases(c: &mut Corpus) {
    let voxels = [7u8; 24];
    let attached = |extra: &str| {
        let mut b = nrrd(extra, true).into_bytes();
        b.extend_from_slice(&voxels);
        b
    };
    c.file("no-magic.nrrd", b"NRRX0004\n\n", &["magic"]);
    c.file(
        "dimension4.nrrd",
        b"NRRD0004\ntype: uint8\ndimension: 4\nsizes: 2 2 2 2\nencoding: raw\n\n",
        &["dimension"],
    );
    c.file(
        "bad-type.nrrd",
        b"NRRD0004\ntype: complex\ndimension: 3\nsizes: 4 3 2\nencoding: raw\n\n",
        &["type"],
    );
    c.file(
        "huge-sizes.nrrd",
        b"NRRD0004\ntype: uint8\ndimension: 3\nsizes: 100000 100000 100000\nencoding: raw\n\n",
        &["sizes", "per slice"],
    );
    c.file(
        "overflow-sizes.nrrd",
        b"NRRD0004\ntype: uint16\nendian: little\ndimension: 3\nsizes: 18446744073709551615 2 2\nencoding: raw\n\n",
        &["sizes", "out of range"],
    );
    let mut short = nrrd("encoding: raw\n", true).into_bytes();
    short.extend_from_slice(&[1u8; 5]);
    c.file("truncated.nrrd", &short, &["truncated"]);
    c.file("bzip2.nrrd", &attached("encoding: bzip2\n"), &["encoding"]);
    c.file(
        "no-endian.nrrd",
        b"NRRD0004\ntype: short\ndimension: 3\nsizes: 4 3 2\nencoding: raw\n\n",
        &["endian"],
    );
    c.file(
        "bad-endian.nrrd",
        &attached("encoding: raw\nendian: middle\n"),
        &["endian"],
    );
    let mut gz = nrrd("encoding: gzip\n", true).into_bytes();
    gz.extend_from_slice(&[0x1f, 0x8b, 8, 0, 0, 0, 0, 0, 0, 3, 0xde, 0xad, 0xbe, 0xef]);
    c.file("corrupt-gzip.nrrd", &gz, &["gzip"]).and_ingest();
    // Finding: a gzip byte skip overflowed into a nonsensical byte count.
    let mut gz = nrrd("encoding: gzip\nbyte skip: 18446744073709551615\n", true).into_bytes();
    gz.extend_from_slice(&gzip(&voxels));
    c.file("gzip-byte-skip-overflow.nrrd", &gz, &["byte skip"]);
    c.file(
        "raw-byte-skip-overflow.nrrd",
        &attached("encoding: raw\nbyte skip: 18446744073709551615\n"),
        &["byte skip"],
    );
    c.file(
        "byte-skip-past-end.nrrd",
        &attached("encoding: raw\nbyte skip: 1000000\n"),
        &["data offset"],
    );
    // Finding: /dev/zero with a huge line skip never finished.
    let dev_zero = nrrd(
        "encoding: raw\ndata file: /dev/zero\nline skip: 1000000000000\n",
        false,
    );
    c.file(
        "dev-zero.nhdr",
        dev_zero.as_bytes(),
        &["data file", "regular"],
    );
    c.file(
        "dev-zero-allowed.nhdr",
        dev_zero.as_bytes(),
        &["data file", "regular"],
    )
    .with_args(&["--allow-data-outside"]);
    write(&c.path("lines.raw"), b"one\ntwo\n");
    c.file(
        "line-skip-huge.nhdr",
        nrrd(
            "encoding: raw\ndata file: lines.raw\nline skip: 1000000000000\n",
            false,
        )
        .as_bytes(),
        &["line skip", "ends first"],
    );
    // Finding: detached headers could point anywhere.
    c.file(
        "etc-passwd.nhdr",
        nrrd("encoding: raw\ndata file: /etc/passwd\n", false).as_bytes(),
        &[
            "data file",
            "outside the header's folder",
            "--allow-data-outside",
        ],
    )
    .and_ingest();
    let parent = c
        .dir
        .parent()
        .map_or_else(|| c.dir.clone(), Path::to_path_buf);
    write(&parent.join("outside_4x3x2.raw"), &voxels);
    c.file(
        "dotdot.nhdr",
        nrrd("encoding: raw\ndata file: ../outside_4x3x2.raw\n", false).as_bytes(),
        &["data file", "outside the header's folder"],
    );
    c.file(
        "missing-data.nhdr",
        nrrd("encoding: raw\ndata file: gone.raw\n", false).as_bytes(),
        &["data file", "not found"],
    );
    c.file(
        "folder-as-data.nhdr",
        nrrd("encoding: raw\ndata file: .\n", false).as_bytes(),
        &["data file", "a folder"],
    );
    // Finding: non-orthogonal directions were accepted.
    c.file(
        "sheared-directions.nrrd",
        &attached("encoding: raw\nspace: LPS\nspace directions: (1,0,0) (0.5,0.5,0) (0,0,1)\n"),
        &["space directions", "perpendicular"],
    );
    c.file(
        "zero-direction.nrrd",
        &attached("encoding: raw\nspace: LPS\nspace directions: (1,0,0) (0,0,0) (0,0,1)\n"),
        &["space directions"],
    );
    c.file(
        "bad-space.nrrd",
        &attached("encoding: raw\nspace: sideways\n"),
        &["space"],
    );
    let mut endless = b"NRRD0004\n".to_vec();
    endless.extend(std::iter::repeat_n(b"# comment\n".iter().copied(), 110_000).flatten());
    c.file("endless-header.nrrd", &endless, &["header", "no end"]);
    c.file(
        "binary-header.nrrd",
        b"NRRD0004\n\xff\xfe\x00\x01\n\n",
        &["header", "not text"],
    );
    let mut inf =
        "NRRD0004\ntype: float\nendian: little\ndimension: 3\nsizes: 4 3 2\nencoding: raw\n\n"
            .as_bytes()
            .to_vec();
    inf.extend(floats_with(24, 20, f32::INFINITY));
    c.file("inf.nrrd", &inf, &["voxel data", "slice 1"])
        .and_ingest();
}

/// A NIfTI-1 header (348 bytes and 4 extension bytes) for `dim` uint8 voxels,
/// 1 mm, sform identity; `edit` changes it before it is returned.
pub fn nifti_header(dim: [i16; 3], edit: impl FnOnce(&mut Vec<u8>)) -> Vec<u8> {
    let mut h = vec![0u8; 352];
    put(&mut h, 0, &348i32.to_le_bytes());
    for (i, d) in [3i16, dim[0], dim[1], dim[2], 1, 1, 1, 1]
        .iter()
        .enumerate()
    {
        put(&mut h, 40 + 2 * i, &d.to_le_bytes());
    }
    put(&mut h, 70, &2i16.to_le_bytes()); // uint8
    put(&mut h, 72, &8i16.to_le_bytes());
    for (i, p) in [1.0f32, 1.0, 1.0, 1.0].iter().enumerate() {
        put(&mut h, 76 + 4 * i, &p.to_le_bytes());
    }
    put(&mut h, 108, &352f32.to_le_bytes()); // vox_offset
    put(&mut h, 112, &1f32.to_le_bytes()); // scl_slope
    h[123] = 2; // mm
    put(&mut h, 254, &1i16.to_le_bytes()); // sform_code
    for (at, row) in [
        (280, [1.0f32, 0.0, 0.0, 0.0]),
        (296, [0.0, 1.0, 0.0, 0.0]),
        (312, [0.0, 0.0, 1.0, 0.0]),
    ] {
        for (i, v) in row.iter().enumerate() {
            put(&mut h, at + 4 * i, &v.to_le_bytes());
        }
    }
    put(&mut h, 344, b"n+1\0");
    edit(&mut h);
    h
}

/// Writes `bytes` into `h` at `at`.
pub fn put(h: &mut [u8], at: usize, bytes: &[u8]) {
    h[at..at + bytes.len()].copy_from_slice(bytes);
}

fn nifti_cases(c: &mut Corpus) {
    let with_data = |edit: &dyn Fn(&mut Vec<u8>)| {
        let mut b = nifti_header([4, 3, 2], |h| edit(h));
        b.extend_from_slice(&[5u8; 24]);
        b
    };
    // Finding: an empty .nii.gz printed Rust debug text.
    c.file("empty.nii.gz", &[], &["header", "348-byte"]);
    c.file("empty.nii", &[], &["header", "348-byte"]);
    c.file("short-header.nii", &[0u8; 100], &["header"]);
    c.file(
        "bad-magic.nii",
        &with_data(&|h| put(h, 344, b"xyz\0")),
        &["header"],
    );
    c.file(
        "rgb.nii",
        &with_data(&|h| put(h, 70, &128i16.to_le_bytes())),
        &["datatype", "rgb24"],
    );
    c.file(
        "huge-dims.nii",
        &with_data(&|h| {
            for i in 1..=3 {
                put(h, 40 + 2 * i, &32767i16.to_le_bytes());
            }
        }),
        &["dim", "expected at most"],
    );
    c.file(
        "five-volumes.nii",
        &with_data(&|h| {
            put(h, 40, &4i16.to_le_bytes());
            put(h, 48, &5i16.to_le_bytes());
        }),
        &["dim", "single 3D volume"],
    );
    // Finding: scl_slope = 3e38 ingested, and every render answered 500.
    c.file(
        "slope-3e38.nii",
        &with_data(&|h| put(h, 112, &3e38f32.to_le_bytes())),
        &["scl_slope", "expected physical values within"],
    )
    .and_ingest();
    c.file(
        "slope-inf.nii.gz",
        &gzip(&with_data(&|h| put(h, 112, &f32::INFINITY.to_le_bytes()))),
        &["scl_slope", "finite"],
    );
    // Finding: a quaternion with b² + c² + d² > 1 was accepted.
    c.file(
        "quaternion.nii",
        &with_data(&|h| {
            put(h, 252, &1i16.to_le_bytes()); // qform_code
            put(h, 254, &0i16.to_le_bytes()); // no sform
            for (i, q) in [0.7f32, 0.7, 0.7].iter().enumerate() {
                put(h, 256 + 4 * i, &q.to_le_bytes());
            }
        }),
        &["quatern_b", "at most 1"],
    );
    c.file(
        "sheared-sform.nii",
        &with_data(&|h| put(h, 284, &0.5f32.to_le_bytes())),
        &["srow", "perpendicular"],
    );
    c.file(
        "vox-offset-huge.nii",
        &with_data(&|h| put(h, 108, &3e38f32.to_le_bytes())),
        &["data offset"],
    );
    c.file(
        "vox-offset-huge.nii.gz",
        &gzip(&with_data(&|h| put(h, 108, &3e38f32.to_le_bytes()))),
        &["byte skip"],
    );
    c.file(
        "vox-offset-nan.nii",
        &with_data(&|h| put(h, 108, &f32::NAN.to_le_bytes())),
        &["vox_offset"],
    );
    let mut short = nifti_header([4, 3, 2], |_| {});
    short.extend_from_slice(&[1u8; 7]);
    c.file("truncated-data.nii", &short, &["truncated"]);
    let mut bad_gz = gzip(&with_data(&|_| {}));
    let n = bad_gz.len();
    bad_gz.truncate(n - 12);
    c.file("truncated.nii.gz", &bad_gz, &["gzip"]).and_ingest();
    let mut inf = nifti_header([4, 3, 2], |h| {
        put(h, 70, &16i16.to_le_bytes());
        put(h, 72, &32i16.to_le_bytes());
    });
    inf.extend(floats_with(24, 23, f32::INFINITY));
    c.file("inf.nii", &inf, &["voxel data", "slice 1"])
        .and_ingest();
}

/// A MetaImage header for 4 × 3 × 2 uint8 voxels with `extra` lines and
/// `ElementDataFile = data` last.
fn mha(extra: &str, data: &str) -> String {
    format!(
        "ObjectType = Image\nNDims = 3\nDimSize = 4 3 2\nElementType = MET_UCHAR\n{extra}ElementDataFile = {data}\n"
    )
}

fn metaimage_cases(c: &mut Corpus) {
    let voxels = [9u8; 24];
    let local = |extra: &str| {
        let mut b = mha(extra, "LOCAL").into_bytes();
        b.extend_from_slice(&voxels);
        b
    };
    // Finding: HeaderSize wrapped around and read the header text as voxels.
    c.file(
        "headersize-wrap.mha",
        &local("HeaderSize = 18446744073709551500\n"),
        &["HeaderSize"],
    )
    .and_ingest();
    c.file(
        "headersize-past-end.mha",
        &local("HeaderSize = 1000000\n"),
        &["HeaderSize", "past the end"],
    );
    // Finding: ElementDataFile could point anywhere.
    c.file(
        "etc-passwd.mhd",
        mha("", "/etc/passwd").as_bytes(),
        &["ElementDataFile", "outside the header's folder"],
    );
    c.file(
        "dotdot.mhd",
        mha("", "../outside_4x3x2.raw").as_bytes(),
        &["ElementDataFile", "outside the header's folder"],
    );
    c.file(
        "dev-zero.mhd",
        mha("", "/dev/zero").as_bytes(),
        &["ElementDataFile", "regular"],
    )
    .with_args(&["--allow-data-outside"]);
    // Finding: a TransformMatrix with 1000 and 0.001 was accepted.
    c.file(
        "transform-scaled.mha",
        &local("TransformMatrix = 1000 0 0 0 0.001 0 0 0 1\n"),
        &["TransformMatrix", "unit vectors"],
    );
    c.file(
        "bad-type.mha",
        mha("", "LOCAL")
            .replace("MET_UCHAR", "MET_COMPLEX")
            .as_bytes(),
        &["ElementType"],
    );
    c.file(
        "huge-dims.mha",
        mha("", "LOCAL")
            .replace("4 3 2", "4000000000 4000000000 4000000000")
            .as_bytes(),
        &["DimSize"],
    );
    c.file(
        "ndims4.mha",
        mha("", "LOCAL")
            .replace("NDims = 3", "NDims = 4")
            .as_bytes(),
        &["NDims"],
    );
    let mut z = mha("CompressedData = True\n", "LOCAL").into_bytes();
    z.extend_from_slice(&[0x78, 0x9c, 0xde, 0xad, 0xbe, 0xef]);
    c.file("corrupt-zlib.mha", &z, &["zlib"]);
    let mut bomb = mha("CompressedData = True\n", "LOCAL")
        .replace("4 3 2", "4096 4096 4096")
        .into_bytes();
    bomb.extend_from_slice(&zlib(&[0u8; 100]));
    c.file("zlib-claims-too-much.mha", &bomb, &["dimensions", "expand"]);
    c.file(
        "channels.mha",
        &local("ElementNumberOfChannels = 3\n"),
        &["ElementNumberOfChannels"],
    );
    c.file(
        "no-data-file.mha",
        b"ObjectType = Image\nNDims = 3\nDimSize = 4 3 2\nElementType = MET_UCHAR\n",
        &["ElementDataFile", "missing"],
    );
}

/// A DICOM slice of `rows` × `cols` 16-bit pixels; `edit` changes the object
/// before it is written with `syntax`.
pub fn dicom_slice(
    path: &Path,
    rows: u16,
    cols: u16,
    syntax: &str,
    edit: impl FnOnce(&mut InMemDicomObject),
) {
    let mut obj = InMemDicomObject::new_empty();
    let mut put = |tag, vr, value: PrimitiveValue| {
        obj.put(DataElement::new(tag, vr, value));
    };
    put(
        tags::SOP_CLASS_UID,
        VR::UI,
        "1.2.840.10008.5.1.4.1.1.2".into(),
    );
    put(tags::SOP_INSTANCE_UID, VR::UI, "1.2.3.4.5".into());
    put(tags::MODALITY, VR::CS, "CT".into());
    put(tags::SERIES_INSTANCE_UID, VR::UI, "1.2.3.4".into());
    put(tags::IMAGE_POSITION_PATIENT, VR::DS, "0\\0\\0".into());
    put(
        tags::IMAGE_ORIENTATION_PATIENT,
        VR::DS,
        "1\\0\\0\\0\\1\\0".into(),
    );
    put(tags::PIXEL_SPACING, VR::DS, "1\\1".into());
    put(tags::ROWS, VR::US, PrimitiveValue::from(rows));
    put(tags::COLUMNS, VR::US, PrimitiveValue::from(cols));
    put(tags::SAMPLES_PER_PIXEL, VR::US, PrimitiveValue::from(1u16));
    put(
        tags::PHOTOMETRIC_INTERPRETATION,
        VR::CS,
        "MONOCHROME2".into(),
    );
    put(tags::BITS_ALLOCATED, VR::US, PrimitiveValue::from(16u16));
    put(tags::BITS_STORED, VR::US, PrimitiveValue::from(16u16));
    put(tags::HIGH_BIT, VR::US, PrimitiveValue::from(15u16));
    put(
        tags::PIXEL_REPRESENTATION,
        VR::US,
        PrimitiveValue::from(0u16),
    );
    let pixels: Vec<u16> = (0..u32::from(rows) * u32::from(cols))
        .map(|i| (i % 1000) as u16)
        .collect();
    put(tags::PIXEL_DATA, VR::OW, PrimitiveValue::U16(pixels.into()));
    edit(&mut obj);
    obj.with_meta(FileMetaTableBuilder::new().transfer_syntax(syntax))
        .expect("DICOM meta")
        .write_to_file(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
}

/// Explicit VR Little Endian.
pub const EXPLICIT_LE: &str = "1.2.840.10008.1.2.1";
/// RLE Lossless.
pub const RLE_LOSSLESS: &str = "1.2.840.10008.1.2.5";

/// An RLE Lossless DICOM file of 4 × 4 8-bit pixels whose one RLE segment
/// decodes to a single byte: dicom-rs 0.10's RLE decoder indexes past the
/// short segment and panics (`rle_lossless.rs`, index out of bounds), the
/// same panic one flipped byte of a real RLE file gives.
pub fn rle_short_segment(path: &Path) {
    // RLE header: one segment, starting at byte 64; then a literal run of one
    // byte (control 0, value 5).
    let mut fragment = vec![0u8; 64];
    fragment[..4].copy_from_slice(&1u32.to_le_bytes());
    fragment[4..8].copy_from_slice(&64u32.to_le_bytes());
    fragment.extend_from_slice(&[0, 5]);
    dicom_slice(path, 4, 4, RLE_LOSSLESS, |obj| {
        obj.put(DataElement::new(
            tags::BITS_ALLOCATED,
            VR::US,
            PrimitiveValue::from(8u16),
        ));
        obj.put(DataElement::new(
            tags::BITS_STORED,
            VR::US,
            PrimitiveValue::from(8u16),
        ));
        obj.put(DataElement::new(
            tags::HIGH_BIT,
            VR::US,
            PrimitiveValue::from(7u16),
        ));
        obj.put(DataElement::new(
            tags::PIXEL_DATA,
            VR::OB,
            PixelFragmentSequence::new_fragments(vec![fragment]),
        ));
    });
}

/// Finds the explicit-VR header of `tag` with a 4-byte length (VR `vr`, e.g.
/// `OW`) in `bytes` and sets that length to `len`.
///
/// # Panics
/// When the header is not there.
pub fn set_long_length(bytes: &mut [u8], tag: (u16, u16), vr: &[u8; 2], len: u32) {
    let mut header = Vec::new();
    header.extend_from_slice(&tag.0.to_le_bytes());
    header.extend_from_slice(&tag.1.to_le_bytes());
    header.extend_from_slice(vr);
    let at = bytes
        .windows(header.len())
        .position(|w| w == header.as_slice())
        .unwrap_or_else(|| panic!("no element {tag:04x?} {vr:?}"));
    bytes[at + 8..at + 12].copy_from_slice(&len.to_le_bytes());
}

fn dicom_file_cases(c: &mut Corpus) {
    let ds = |obj: &mut InMemDicomObject, tag, value: &str| {
        obj.put(DataElement::new(tag, VR::DS, PrimitiveValue::from(value)));
    };
    let us = |obj: &mut InMemDicomObject, tag, value: u16| {
        obj.put(DataElement::new(tag, VR::US, PrimitiveValue::from(value)));
    };
    // Found by fuzzing: a 2-byte value whose VR says FD (8 bytes each) put
    // dicom-rs out of step; it then allocated a 540 MB "length" from later bytes.
    let fd = c.path("fd-two-bytes.dcm");
    dicom_slice(&fd, 2, 2, EXPLICIT_LE, |obj| {
        obj.put(DataElement::new(
            tags::IMAGED_NUCLEUS,
            VR::SH,
            PrimitiveValue::from("1H"),
        ));
    });
    let mut bytes = std::fs::read(&fd).expect("read");
    let at = bytes
        .windows(8)
        .position(|w| w == b"\x18\x00\x85\x00SH\x02\x00")
        .expect("the ImagedNucleus element");
    bytes[at + 4..at + 6].copy_from_slice(b"FD");
    write(&fd, &bytes);
    c.case(
        "fd-two-bytes.dcm",
        fd,
        &["element (0018,0085)", "expected a multiple of 8"],
    )
    .and_ingest();
    // Finding: a panic in dicom-rs' RLE decoder took the process down.
    let rle = c.path("rle-short-segment.dcm");
    rle_short_segment(&rle);
    c.case(
        "rle-short-segment.dcm",
        rle,
        &["RLE Lossless", "decoder failed"],
    )
    .and_ingest();
    // Finding: an element length of 0xFFFFFFF0 allocated 4.2 GB before refusing.
    let good = c.path("good.dcm");
    dicom_slice(&good, 8, 8, EXPLICIT_LE, |_| {});
    let bytes = std::fs::read(&good).expect("read good.dcm");
    let mut pixel = bytes.clone();
    set_long_length(&mut pixel, (0x7fe0, 0x0010), b"OW", 0xFFFF_FFF0);
    c.file(
        "pixel-length-huge.dcm",
        &pixel,
        &["element (7FE0,0010)", "declares 4294967280"],
    )
    .and_ingest();
    let mut meta = bytes.clone();
    set_long_length(&mut meta, (0x0002, 0x0001), b"OB", 0xFFFF_FFF0);
    c.file(
        "meta-length-huge.dcm",
        &meta,
        &["file meta element", "declares 4294967280"],
    );
    let mut text = bytes.clone();
    // A short-VR element given a 4-byte-length VR (UN) and a huge length.
    let at = text
        .windows(4)
        .position(|w| w == [0x08, 0x00, 0x60, 0x00]) // Modality (0008,0060)
        .expect("modality");
    text.splice(at + 4..at + 8, *b"UN\0\0");
    text.splice(at + 8..at + 8, 0xFFFF_FFF0u32.to_le_bytes());
    c.file("un-length-huge.dcm", &text, &["declares 4294967280"]);
    c.file(
        "truncated.dcm",
        &bytes[..bytes.len() / 2],
        &["declares", "truncated or damaged"],
    );
    c.file(
        "header-only.dcm",
        &bytes[..300],
        &["file meta group", "declares"],
    );
    c.file("not-dicom.dcm", b"hello, not an image", &["DICM"]);
    // Finding: ImageOrientationPatient (2,0,0,0,0.5,0) was accepted.
    c.dicom(
        "orientation-scaled.dcm",
        |o| {
            ds(o, tags::IMAGE_ORIENTATION_PATIENT, "2\\0\\0\\0\\0.5\\0");
        },
        &["ImageOrientationPatient", "unit vectors"],
    );
    c.dicom(
        "bits12.dcm",
        |o| {
            us(o, tags::BITS_ALLOCATED, 12);
        },
        &["BitsAllocated"],
    );
    c.dicom(
        "rows-huge.dcm",
        |o| {
            us(o, tags::ROWS, 65535);
            us(o, tags::COLUMNS, 65535);
        },
        &["Rows", "per slice"],
    );
    c.dicom(
        "rescale-slope-huge.dcm",
        |o| {
            ds(o, tags::RESCALE_SLOPE, "3e38");
        },
        &["RescaleSlope", "physical values within"],
    );
    c.dicom(
        "frames.dcm",
        |o| {
            o.put(DataElement::new(
                tags::NUMBER_OF_FRAMES,
                VR::IS,
                PrimitiveValue::from("1000000"),
            ));
        },
        &["NumberOfFrames"],
    );
    c.dicom(
        "frames-unplaced.dcm",
        |o| {
            o.put(DataElement::new(
                tags::NUMBER_OF_FRAMES,
                VR::IS,
                PrimitiveValue::from("3"),
            ));
        },
        &["PerFrameFunctionalGroupsSequence", "one item per frame"],
    );
}

/// Writes a series of `n` 8 × 8 slices into `folder`, slice `i` at
/// `position(i)`.
fn dicom_series(folder: &Path, n: usize, position: impl Fn(usize) -> [f64; 3]) {
    std::fs::create_dir_all(folder).expect("series folder");
    for i in 0..n {
        let p = position(i);
        dicom_slice(
            &folder.join(format!("s{i:03}.dcm")),
            8,
            8,
            EXPLICIT_LE,
            |o| {
                o.put(DataElement::new(
                    tags::IMAGE_POSITION_PATIENT,
                    VR::DS,
                    PrimitiveValue::from(format!("{}\\{}\\{}", p[0], p[1], p[2])),
                ));
                o.put(DataElement::new(
                    tags::SOP_INSTANCE_UID,
                    VR::UI,
                    PrimitiveValue::from(format!("1.2.3.4.5.{i}")),
                ));
            },
        );
    }
}

fn dicom_folder_cases(c: &mut Corpus) {
    // Stacked along a direction no gantry tilt gives (off the normal, about
    // neither image axis).
    let sheared = c.path("sheared-series");
    dicom_series(&sheared, 4, |i| [i as f64 * 0.5, i as f64 * 0.5, i as f64]);
    c.case(
        "sheared-series",
        sheared,
        &["ImagePositionPatient", "gantry tilt"],
    );
    let gap = c.path("missing-slice");
    dicom_series(&gap, 5, |i| {
        [0.0, 0.0, if i < 2 { i as f64 } else { i as f64 + 1.0 }]
    });
    c.case("missing-slice", gap, &["missing slice"])
        .and_ingest();
    // Finding: symbolic links were ignored and the error said only "none found".
    let links = c.path("links-outside");
    let elsewhere = c.path("elsewhere");
    dicom_series(&elsewhere, 2, |i| [0.0, 0.0, i as f64]);
    std::fs::create_dir_all(&links).expect("links folder");
    for name in ["s000.dcm", "s001.dcm"] {
        symlink(&elsewhere.join(name), &links.join(name));
    }
    c.case(
        "links-outside",
        links,
        &["none found", "symbolic link", "outside the folder"],
    );
    let readme = c.path("only-readme");
    std::fs::create_dir_all(&readme).expect("readme folder");
    write(&readme.join("README.txt"), b"not an image");
    c.case(
        "only-readme",
        readme,
        &["none found", "README.txt", "not DICOM"],
    );
    let bad_file = c.path("broken-slice");
    dicom_series(&bad_file, 3, |i| [0.0, 0.0, i as f64]);
    let mut bytes = std::fs::read(bad_file.join("s001.dcm")).expect("slice");
    set_long_length(&mut bytes, (0x7fe0, 0x0010), b"OW", 0xFFFF_FFF0);
    write(&bad_file.join("s001.dcm"), &bytes);
    c.case(
        "broken-slice",
        bad_file,
        &["s001.dcm", "declares 4294967280"],
    );
    let rle_folder = c.path("rle-folder");
    std::fs::create_dir_all(&rle_folder).expect("rle folder");
    rle_short_segment(&rle_folder.join("only.dcm"));
    c.case(
        "rle-folder",
        rle_folder,
        &["only.dcm", "RLE Lossless", "decoder failed"],
    );
}

/// A symbolic link at `link` to `target`.
///
/// # Panics
/// When it cannot be made.
pub fn symlink(target: &Path, link: &Path) {
    std::os::unix::fs::symlink(target, link)
        .unwrap_or_else(|e| panic!("{} -> {}: {e}", link.display(), target.display()));
}
