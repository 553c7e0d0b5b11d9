//! Studies from a real PACS over DICOMweb: Orthanc (with its DICOMweb
//! plugin) on a loopback port, loaded with the VHF head series and the nine
//! transfer-syntax files through its REST API.
//!
//! - `voxserve pacs search` finds the study by PatientID and by a StudyDate
//!   range; `voxserve pacs fetch` makes a store equal, voxel for voxel and
//!   in geometry, to the one `ingest` makes from the same files on disk.
//! - Every transfer syntax arrives as stored and decodes to the same pixels.
//! - An enhanced multi-frame CT made of the VHF slices by highdicom reads
//!   as the classic slices do, from a file and from the PACS, and so does
//!   the series split over two such instances.
//! - Orthanc pushes the VHF study to `serve --receive` with STOW-RS: the
//!   series is bricked once settled, served under its SeriesInstanceUID,
//!   and its store equals the one its files make; a body that is not
//!   multipart (415) and a part that is not DICOM (409) are refused.
//! - dcmtk's `dcmsend` pushes the VHF series to `serve --dicom-port` (the
//!   C-STORE SCP): served, and its store equals the one its files make;
//!   `echoscu` is answered; an association from a calling AE title not
//!   allowed, or calling another title, is rejected, audited, and stores
//!   nothing; a silent connection and one speaking HTTP hold up no one.
//! - `serve --pacs --pacs-cache` searches Orthanc for the study browser
//!   (by PatientID, by StudyDate and modality), lists the series, opens
//!   one (its store equals the one its files make), evicts the store used
//!   least recently past the budget, resolves IID STUDY and PATIENT
//!   requests, and refuses bad ones naming the parameter (a PACS that is
//!   down: 502; a series the PACS lacks: a failed job, nothing cached).
//! - Faults: a PACS that is down, one that never answers (timeout), 404 and
//!   500 answers, malformed JSON, a truncated multipart body, a frame that
//!   fails to decode, a series with a missing slice: each is an error naming
//!   the PACS and the study or series, and no store (nor spool folder) is
//!   left behind.
//!
//! Skipped with a printed reason where Orthanc (or dcmtk) is not installed, unless
//! `VOXSERVE_REQUIRE_PACS=1` (`.ci/run`).

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use blocks::ingest::{self, OpenOptions};
use blocks::store::{self, IngestOptions, LEVELS, Store};
use dicom_dictionary_std::tags;
use server::pacs::fetch::{FetchOptions, fetch_series, open_fetched};
use server::pacs::{DicomWeb, PacsError, StudyQuery, endpoint::parse_pacs};
use voxserve_tests::data::shared_data;
use voxserve_tests::orthanc::Orthanc;

const VOXSERVE: &str = env!("CARGO_BIN_EXE_voxserve");

/// The `.dcm` files of a folder, sorted.
fn dicom_files(dir: &Path) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .expect("folder")
        .map(|e| e.expect("entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "dcm"))
        .collect();
    files.sort();
    files
}

/// A UID attribute of a DICOM file.
fn uid_of(file: &Path, tag: dicom_core::Tag) -> String {
    let obj = dicom_object::OpenFileOptions::new()
        .read_until(tags::PIXEL_DATA)
        .open_file(file)
        .expect("DICOM file");
    obj.element(tag)
        .expect("attribute")
        .to_str()
        .expect("text")
        .trim_end_matches('\0')
        .trim()
        .to_owned()
}

/// A client of `orthanc`'s DICOMweb service that gives up after `timeout`.
fn client_of(url: &str, timeout: Duration) -> DicomWeb {
    DicomWeb::new(parse_pacs(&format!("t={url}")).expect("endpoint"), timeout).expect("client")
}

/// `voxserve ARGS`, its status and output.
fn voxserve(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(VOXSERVE)
        .args(args)
        .output()
        .expect("run voxserve");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// `store` equals `other` in every voxel of every level, geometry, voxel
/// type, value map, study and statistics (not in name and source, nor in
/// the series' description where `same_series` is false).
fn assert_same_store(store: &Store, other: &Store, same_series: bool) {
    let (mut a, mut b) = (store.meta().clone(), other.meta().clone());
    for m in [&mut a, &mut b] {
        m.name.clear();
        m.source.clear();
        if !same_series {
            m.description = None;
            m.study.series_description = None;
        }
    }
    assert_eq!(a, b, "the stores' metadata");
    for level in 0..LEVELS {
        let (x, y) = (
            store.load_level(level).expect("level"),
            other.load_level(level).expect("level"),
        );
        assert_eq!(x.geometry, y.geometry, "level {level}'s geometry");
        assert!(x.voxels == y.voxels, "level {level}'s voxels differ");
    }
}

/// `voxserve ingest` of `input` into a store at `out`, as the library does it.
fn ingest_to(input: &Path, out: &Path) {
    let mut source = ingest::open(input, &OpenOptions::default()).expect("open");
    store::ingest(source.as_mut(), out, &IngestOptions::default(), &mut |_| {}).expect("ingest");
}

/// Nothing of a failed fetch is left in `dir`: no store, no spool folder.
fn assert_nothing_left(dir: &Path) {
    let left: Vec<_> = std::fs::read_dir(dir)
        .expect("folder")
        .map(|e| e.expect("entry").file_name())
        .collect();
    assert!(
        left.is_empty(),
        "left behind in {}: {left:?}",
        dir.display()
    );
}

#[tokio::test(flavor = "multi_thread")]
async fn a_series_fetched_from_orthanc_makes_the_store_its_files_make_on_disk() {
    let test = "a_series_fetched_from_orthanc_makes_the_store_its_files_make_on_disk";
    let Some(data) = shared_data(test) else {
        return;
    };
    let Some(orthanc) = Orthanc::start_or_skip(test) else {
        return;
    };
    let http = reqwest::Client::new();
    let vhf = data.join("dicom/vhf_head");
    let files = dicom_files(&vhf);
    for f in files
        .iter()
        .chain(&dicom_files(&data.join("dicom/transfer_syntaxes")))
    {
        orthanc.upload(&http, f).await;
    }
    let study = uid_of(&files[0], tags::STUDY_INSTANCE_UID);
    let pacs = format!("t={}", orthanc.dicomweb());

    // Found by PatientID and by a StudyDate range; not by a range without it.
    for keys in [
        &["--patient-id", "000-000-001"][..],
        &["--patient-id", "000-000-*"],
        &["--study-date", "20041201-20050201"],
    ] {
        let (ok, out, err) =
            voxserve(&[&["pacs", "search", "--pacs", &pacs, "--json"][..], keys].concat());
        assert!(ok, "{keys:?}: {err}");
        let found: Vec<serde_json::Value> = out
            .lines()
            .map(|l| serde_json::from_str(l).expect("a JSON line"))
            .collect();
        assert_eq!(found.len(), 1, "{keys:?}: {out}");
        assert_eq!(found[0]["study_uid"], study.as_str());
        assert_eq!(found[0]["patient_name"], "Eve");
        assert_eq!(found[0]["instances"], 234);
    }
    let (ok, out, err) = voxserve(&[
        "pacs",
        "search",
        "--pacs",
        &pacs,
        "--study-date",
        "20060101-",
    ]);
    assert!(ok && !out.contains(&study), "{out}{err}");
    let (ok, _, err) = voxserve(&[
        "pacs",
        "search",
        "--pacs",
        &pacs,
        "--study-date",
        "2005-01-01",
    ]);
    assert!(
        !ok && err.contains("StudyDate") && err.contains("YYYYMMDD"),
        "{err}"
    );

    // Fetched (the study's only series) and bricked; the same files ingested
    // from disk.
    let dir = tempfile::tempdir().expect("tempdir");
    let from_pacs = dir.path().join("pacs.zarr");
    let (ok, out, err) = voxserve(&[
        "pacs",
        "fetch",
        "--pacs",
        &pacs,
        "--study",
        &study,
        "--out",
        from_pacs.to_str().expect("path"),
    ]);
    assert!(ok, "{err}");
    assert!(out.contains("234 instance(s)"), "{out}");
    let from_disk = dir.path().join("disk.zarr");
    ingest_to(&vhf, &from_disk);
    let (pacs_store, disk_store) = (
        Store::open(&from_pacs).expect("open"),
        Store::open(&from_disk).expect("open"),
    );
    assert_same_store(&pacs_store, &disk_store, true);
    assert!(
        pacs_store.meta().source.contains("/dicom-web/studies/")
            && pacs_store.meta().source.contains(&study),
        "the store names where it came from: {}",
        pacs_store.meta().source
    );
    let names: Vec<_> = std::fs::read_dir(dir.path())
        .expect("folder")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    assert!(
        !names.iter().any(|n| n.starts_with(".voxserve-fetch")),
        "the spool folder is removed: {names:?}"
    );

    // A series with a missing slice: refused, naming the series and the gap,
    // and nothing is written.
    let web = client_of(&orthanc.dicomweb(), Duration::from_secs(30));
    let found = web
        .search_studies(&StudyQuery {
            study_uid: Some(study.clone()),
            ..StudyQuery::default()
        })
        .await
        .expect("search");
    assert_eq!(found.len(), 1);
    let gone: serde_json::Value = serde_json::from_slice(
        &http
            .post(format!("{}/tools/lookup", orthanc.url))
            .body(uid_of(&files[117], tags::SOP_INSTANCE_UID))
            .send()
            .await
            .expect("lookup")
            .bytes()
            .await
            .expect("body"),
    )
    .expect("JSON");
    orthanc
        .delete_instance(&http, gone[0]["ID"].as_str().expect("id"))
        .await;
    let gap = tempfile::tempdir().expect("tempdir");
    let out = gap.path().join("gap.zarr");
    let (ok, _, err) = voxserve(&[
        "pacs",
        "fetch",
        "--pacs",
        &pacs,
        "--study",
        &study,
        "--out",
        out.to_str().expect("path"),
    ]);
    let series = uid_of(&files[0], tags::SERIES_INSTANCE_UID);
    assert!(
        !ok && err.contains("missing slice") && err.contains(&series),
        "{err}"
    );
    assert_nothing_left(gap.path());
}

#[tokio::test(flavor = "multi_thread")]
async fn every_transfer_syntax_arrives_as_stored_and_decodes_to_the_same_pixels() {
    let test = "every_transfer_syntax_arrives_as_stored_and_decodes_to_the_same_pixels";
    let Some(data) = shared_data(test) else {
        return;
    };
    let Some(orthanc) = Orthanc::start_or_skip(test) else {
        return;
    };
    let http = reqwest::Client::new();
    let files = dicom_files(&data.join("dicom/transfer_syntaxes"));
    for f in &files {
        orthanc.upload(&http, f).await;
    }
    let web = client_of(&orthanc.dicomweb(), Duration::from_secs(30));
    let study = uid_of(&files[0], tags::STUDY_INSTANCE_UID);
    let series = web.search_series(&study).await.expect("series");
    assert_eq!(series.len(), 1, "{series:?}");
    let instances = web
        .series_instances(&study, &series[0].series_uid)
        .await
        .expect("metadata");
    assert_eq!(instances.len(), files.len());
    let dir = tempfile::tempdir().expect("tempdir");
    let pixels = |file: &Path| {
        let mut source = ingest::open(file, &OpenOptions::default())
            .unwrap_or_else(|e| panic!("{}: {e}", file.display()));
        ingest::load(source.as_mut()).expect("decode").voxels
    };
    let expected = pixels(&files[0]);
    for file in &files {
        let sop = uid_of(file, tags::SOP_INSTANCE_UID);
        let dest = dir.path().join(format!("{sop}.dcm"));
        let bytes = web
            .retrieve_instance(&study, &series[0].series_uid, &sop, &dest, 1 << 30)
            .await
            .unwrap_or_else(|e| panic!("{}: {e}", file.display()));
        assert_eq!(
            std::fs::read(&dest).expect("read"),
            std::fs::read(file).expect("read"),
            "{}: retrieved as stored ({bytes} bytes)",
            file.display()
        );
        assert!(
            pixels(&dest) == expected,
            "{}: other pixels",
            file.display()
        );
    }
}

/// A server that answers every request with `status`, `content_type` and
/// `body` (for faults a real PACS cannot be made to show), on a loopback
/// port; stopped when the runtime ends.
async fn faulty(status: u16, content_type: &'static str, body: &'static [u8]) -> String {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
        .await
        .expect("bind");
    let url = format!("http://{}", listener.local_addr().expect("address"));
    let app = axum::Router::new().fallback(move || async move {
        (
            axum::http::StatusCode::from_u16(status).expect("status"),
            [(axum::http::header::CONTENT_TYPE, content_type)],
            body,
        )
    });
    tokio::spawn(async move { axum::serve(listener, app).await });
    url
}

#[tokio::test(flavor = "multi_thread")]
async fn a_failing_pacs_gives_errors_naming_the_study_or_series_and_bricks_nothing() {
    let test = "a_failing_pacs_gives_errors_naming_the_study_or_series_and_bricks_nothing";
    let (study, series, sop) = ("1.2.3.4", "1.2.3.4.5", "1.2.3.4.5.6");

    // Down: nothing listens.
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("port")
        .port();
    let down = client_of(
        &format!("http://127.0.0.1:{port}/dicom-web"),
        Duration::from_secs(5),
    );
    let e = down.search_series(study).await.expect_err("down");
    assert!(
        matches!(e, PacsError::Unreachable { .. }) && e.retryable(),
        "{e}"
    );
    assert!(
        e.to_string().contains("cannot connect") && e.to_string().contains(study),
        "{e}"
    );

    // Slow: connections accepted, never answered.
    let silent = tokio::net::TcpListener::bind("127.0.0.1:0")
        .await
        .expect("bind");
    let silent_url = format!("http://{}/dicom-web", silent.local_addr().expect("address"));
    tokio::spawn(async move {
        let mut held = Vec::new();
        while let Ok((socket, _)) = silent.accept().await {
            held.push(socket);
        }
    });
    let slow = client_of(&silent_url, Duration::from_secs(1));
    let e = slow
        .series_instances(study, series)
        .await
        .expect_err("slow");
    assert!(matches!(e, PacsError::Timeout { .. }), "{e}");
    assert!(
        e.to_string().contains("no answer within 1 s") && e.to_string().contains(series),
        "{e}"
    );

    // 500, tried again, then given up; the spool folder removed.
    let failing = client_of(
        &faulty(500, "text/plain", b"boom").await,
        Duration::from_secs(5),
    );
    let spool = tempfile::tempdir().expect("tempdir");
    let options = FetchOptions {
        attempts: 2,
        ..FetchOptions::default()
    };
    let e = fetch_series(
        &failing,
        study,
        series,
        spool.path(),
        options,
        &|_, _, _| {},
    )
    .await
    .expect_err("500");
    assert!(
        matches!(e, PacsError::Status { status: 500, .. }) && e.retryable(),
        "{e}"
    );
    assert!(e.to_string().contains(series), "{e}");
    assert_nothing_left(spool.path());

    // Malformed JSON, and JSON that is not DICOM JSON.
    for (body, words) in [
        (&b"[{\"0020000E\": "[..], "expected DICOM JSON"),
        (b"{\"a\": 1}", "not an array of objects"),
        (
            b"[{\"0020000E\": {\"vr\": \"UI\", \"Value\": [\"x\"]}}]",
            "SeriesInstanceUID",
        ),
    ] {
        let web = client_of(
            &faulty(200, "application/dicom+json", body).await,
            Duration::from_secs(5),
        );
        let e = web.search_series(study).await.expect_err("malformed");
        assert!(
            matches!(e, PacsError::Malformed { .. }) && !e.retryable(),
            "{e}"
        );
        assert!(
            e.to_string().contains(words) && e.to_string().contains(study),
            "{e}"
        );
    }

    // A multipart body cut short, one without a boundary, one of another type.
    let dest = spool.path().join("instance.dcm");
    for (content_type, body, words) in [
        (
            "multipart/related; type=\"application/dicom\"; boundary=XX",
            &b"--XX\r\nContent-Type: application/dicom\r\n\r\nDICM and then nothing"[..],
            "truncated",
        ),
        (
            "multipart/related; type=\"application/dicom\"",
            b"",
            "with a boundary",
        ),
        (
            "multipart/related; boundary=XX",
            b"--XX\r\nContent-Type: image/jpeg\r\n\r\nabc\r\n--XX--\r\n",
            "expected application/dicom",
        ),
    ] {
        let web = client_of(
            &faulty(200, content_type, body).await,
            Duration::from_secs(5),
        );
        let e = web
            .retrieve_instance(study, series, sop, &dest, 1 << 20)
            .await
            .expect_err("malformed multipart");
        assert!(matches!(e, PacsError::Malformed { .. }), "{e}");
        assert!(
            e.to_string().contains(words) && e.to_string().contains(sop),
            "{e}"
        );
        if words == "truncated" {
            // All the bytes came: the body itself was cut short, not its transfer.
            let n = body.len();
            assert!(
                e.to_string().contains(&format!(
                    "after {n} of the {n} bytes its Content-Length announced"
                )),
                "{e}"
            );
        }
    }

    // 404 from a real PACS, and a frame that does not decode.
    let Some(data) = shared_data(test) else {
        return;
    };
    let Some(orthanc) = Orthanc::start_or_skip(test) else {
        return;
    };
    let web = client_of(&orthanc.dicomweb(), Duration::from_secs(30));
    let e = web.series_instances(study, series).await.expect_err("404");
    assert!(
        matches!(e, PacsError::Status { status: 404, .. }) && !e.retryable(),
        "{e}"
    );
    assert!(
        e.to_string().contains("not found") && e.to_string().contains(study),
        "{e}"
    );

    // JPEG-LS with its codestream's markers wiped: stored by the PACS,
    // refused when bricked.
    let original = data.join("dicom/transfer_syntaxes/7.dcm");
    let mut bytes = std::fs::read(&original).expect("read");
    let start = bytes
        .windows(4)
        .position(|w| w == [0xFF, 0xD8, 0xFF, 0xF7])
        .expect("a JPEG-LS codestream");
    bytes[start..start + 64].fill(0);
    let broken = spool.path().join("broken.dcm");
    std::fs::write(&broken, &bytes).expect("write");
    orthanc.upload(&reqwest::Client::new(), &broken).await;
    std::fs::remove_file(&broken).expect("remove");
    let (study, series, sop) = (
        uid_of(&original, tags::STUDY_INSTANCE_UID),
        uid_of(&original, tags::SERIES_INSTANCE_UID),
        uid_of(&original, tags::SOP_INSTANCE_UID),
    );
    let out = spool.path().join("broken.zarr");
    let (ok, _, err) = voxserve(&[
        "pacs",
        "fetch",
        "--pacs",
        &format!("t={}", orthanc.dicomweb()),
        "--study",
        &study,
        "--series",
        &series,
        "--out",
        out.to_str().expect("path"),
    ]);
    assert!(!ok && err.contains(&series) && err.contains(&sop), "{err}");
    assert_nothing_left(spool.path());
    // The same through the library: the error names the instance.
    let fetched = fetch_series(
        &web,
        &study,
        &series,
        spool.path(),
        FetchOptions::default(),
        &|_, _, _| {},
    )
    .await
    .expect("fetched");
    let e = open_fetched(&fetched)
        .and_then(|mut s| ingest::load(s.as_mut()).map_err(anyhow::Error::from))
        .expect_err("undecodable");
    assert!(e.to_string().contains(&sop), "{e}");
}

/// `voxserve` run on a Python that imports highdicom, or `None` after saying
/// why `test` is skipped.
fn highdicom_or_skip(test: &str) -> Option<()> {
    let ok = Command::new("python3")
        .args(["-c", "import highdicom"])
        .output()
        .is_ok_and(|o| o.status.success());
    if ok {
        return Some(());
    }
    assert!(
        !std::env::var("VOXSERVE_REQUIRE_PACS").is_ok_and(|v| v == "1"),
        "{test}: VOXSERVE_REQUIRE_PACS=1 but python3 cannot import highdicom (pip install highdicom)"
    );
    voxserve_tests::gpu::report_skip(test, "python3 cannot import highdicom");
    None
}

/// highdicom's legacy conversion: the classic slices in folder `argv[1]` as
/// one Legacy Converted Enhanced CT image at `argv[2]`, and as two (the
/// halves, one series) at `argv[3]` and `argv[4]`.
const ENHANCE: &str = "
import glob, sys, pydicom, highdicom
from highdicom.legacy import LegacyConvertedEnhancedCTImage
slices = [pydicom.dcmread(f) for f in sorted(glob.glob(sys.argv[1] + '/*.dcm'))]
def convert(part, series, number, out):
    LegacyConvertedEnhancedCTImage(
        legacy_datasets=part, series_instance_uid=series, series_number=100,
        sop_instance_uid=highdicom.UID(), instance_number=number,
    ).save_as(out)
convert(slices, highdicom.UID(), 1, sys.argv[2])
half, series = len(slices) // 2, highdicom.UID()
convert(slices[:half], series, 1, sys.argv[3])
convert(slices[half:], series, 2, sys.argv[4])
";

#[tokio::test(flavor = "multi_thread")]
async fn an_enhanced_multi_frame_ct_reads_as_its_classic_slices_from_a_file_and_from_orthanc() {
    let test =
        "an_enhanced_multi_frame_ct_reads_as_its_classic_slices_from_a_file_and_from_orthanc";
    let Some(data) = shared_data(test) else {
        return;
    };
    let Some(()) = highdicom_or_skip(test) else {
        return;
    };
    let vhf = data.join("dicom/vhf_head");
    let dir = tempfile::tempdir().expect("tempdir");
    let enhanced_dir = dir.path().join("enhanced");
    std::fs::create_dir(&enhanced_dir).expect("folder");
    let enhanced = enhanced_dir.join("vhf_enhanced.dcm");
    let split_dir = dir.path().join("split");
    std::fs::create_dir(&split_dir).expect("folder");
    let made = Command::new("python3")
        .args(["-c", ENHANCE])
        .arg(&vhf)
        .arg(&enhanced)
        .arg(split_dir.join("first.dcm"))
        .arg(split_dir.join("second.dcm"))
        .output()
        .expect("python3");
    assert!(
        made.status.success(),
        "{}",
        String::from_utf8_lossy(&made.stderr)
    );

    // From the file, from a folder holding it, and from a folder holding
    // the series as two instances: the classic volume.
    let load = |path: &Path| {
        let mut source = ingest::open(path, &OpenOptions::default())
            .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        ingest::load(source.as_mut()).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
    };
    let classic = load(&vhf);
    for path in [&enhanced, &enhanced_dir, &split_dir] {
        let v = load(path);
        assert_eq!(v.geometry, classic.geometry, "{}: geometry", path.display());
        assert_eq!(
            v.value_map,
            classic.value_map,
            "{}: value map",
            path.display()
        );
        assert!(v.voxels == classic.voxels, "{}: voxels", path.display());
    }

    // From Orthanc: the store of the classic slices on disk.
    let Some(orthanc) = Orthanc::start_or_skip(test) else {
        return;
    };
    orthanc.upload(&reqwest::Client::new(), &enhanced).await;
    let study = uid_of(&enhanced, tags::STUDY_INSTANCE_UID);
    let series = uid_of(&enhanced, tags::SERIES_INSTANCE_UID);
    let out = dir.path().join("enhanced.zarr");
    let (ok, stdout, err) = voxserve(&[
        "pacs",
        "fetch",
        "--pacs",
        &format!("t={}", orthanc.dicomweb()),
        "--study",
        &study,
        "--series",
        &series,
        "--out",
        out.to_str().expect("path"),
    ]);
    assert!(ok, "{err}");
    assert!(stdout.contains("1 instance(s)"), "{stdout}");
    let disk = dir.path().join("classic.zarr");
    ingest_to(&vhf, &disk);
    assert_same_store(
        &Store::open(&out).expect("open"),
        &Store::open(&disk).expect("open"),
        false,
    );
}

/// `GET url` as JSON.
async fn get_json(client: &reqwest::Client, url: &str) -> serde_json::Value {
    let body = client
        .get(url)
        .send()
        .await
        .and_then(reqwest::Response::error_for_status)
        .unwrap_or_else(|e| panic!("GET {url}: {e}"))
        .bytes()
        .await
        .expect("body");
    serde_json::from_slice(&body).expect("JSON")
}

#[tokio::test(flavor = "multi_thread")]
async fn a_study_pushed_with_stow_rs_is_bricked_and_served_as_its_files_on_disk_are() {
    let test = "a_study_pushed_with_stow_rs_is_bricked_and_served_as_its_files_on_disk_are";
    let Some(data) = shared_data(test) else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let received = dir.path().join("received");
    let serve = [
        "serve",
        "--addr",
        "127.0.0.1:0",
        "--phantom-size",
        "32",
        "--receive",
        received.to_str().expect("path"),
        "--receive-settle-s",
        "1",
    ];
    let server = voxserve_tests::server::Spawned::start(VOXSERVE, &serve)
        .await
        .unwrap_or_else(|stderr| panic!("serve exited: {stderr}"));
    let http = reqwest::Client::new();
    let stow = format!("{}/dicom-web/studies", server.url);

    // Not a multipart body: 415. A part that is not DICOM: refused (409),
    // named in the FailedSOPSequence; nothing is served of it.
    let answer = http.post(&stow).body("hello").send().await.expect("POST");
    assert_eq!(answer.status().as_u16(), 415);
    let answer = http
        .post(&stow)
        .header(
            "content-type",
            "multipart/related; type=\"application/dicom\"; boundary=XX",
        )
        .body("--XX\r\nContent-Type: application/dicom\r\n\r\nnot a DICOM file\r\n--XX--\r\n")
        .send()
        .await
        .expect("POST");
    assert_eq!(answer.status().as_u16(), 409);
    let failed: serde_json::Value =
        serde_json::from_slice(&answer.bytes().await.expect("body")).expect("DICOM JSON");
    assert!(
        failed["00081198"]["Value"][0]["00081197"].is_object(),
        "{failed}"
    );
    // A series UID that would name a folder elsewhere: refused.
    let vhf = data.join("dicom/vhf_head");
    let files = dicom_files(&vhf);
    let mut evil = dicom_object::open_file(&files[0]).expect("open");
    evil.put(dicom_core::DataElement::new(
        tags::SERIES_INSTANCE_UID,
        dicom_core::VR::UI,
        dicom_core::PrimitiveValue::from(".."),
    ));
    let mut body = b"--XX\r\nContent-Type: application/dicom\r\n\r\n".to_vec();
    let evil_file = dir.path().join("evil.dcm");
    evil.write_to_file(&evil_file).expect("write");
    body.extend(std::fs::read(&evil_file).expect("read"));
    body.extend(b"\r\n--XX--\r\n");
    let answer = http
        .post(&stow)
        .header(
            "content-type",
            "multipart/related; type=\"application/dicom\"; boundary=XX",
        )
        .body(body)
        .send()
        .await
        .expect("POST");
    assert_eq!(answer.status().as_u16(), 409);
    assert_eq!(
        std::fs::read_dir(received.join("series"))
            .expect("series")
            .count(),
        0,
        "nothing kept of refused instances"
    );

    // Orthanc pushes the VHF head's study with STOW-RS.
    let Some(orthanc) = Orthanc::start_with_or_skip(
        test,
        &serde_json::json!({"voxserve": [format!("{}/dicom-web/", server.url)]}),
    ) else {
        return;
    };
    let mut orthanc_study = String::new();
    for f in &files {
        orthanc_study = orthanc.upload_answer(&http, f).await["ParentStudy"]
            .as_str()
            .expect("a study id")
            .to_owned();
    }
    orthanc
        .post_json(
            &http,
            "/dicom-web/servers/voxserve/stow",
            &serde_json::json!({"Resources": [orthanc_study], "Synchronous": true}),
        )
        .await;

    // Once the series has settled it is bricked and served under its
    // SeriesInstanceUID, and its store equals the one its files make.
    let series = uid_of(&files[0], tags::SERIES_INSTANCE_UID);
    wait_served(&http, &server.url, &series).await;
    let from_disk = dir.path().join("disk.zarr");
    ingest_to(&vhf, &from_disk);
    assert_same_store(
        &Store::open(received.join("stores").join(format!("{series}.zarr"))).expect("open"),
        &Store::open(&from_disk).expect("open"),
        true,
    );
    assert_eq!(
        std::fs::read_dir(received.join("series").join(&series))
            .expect("kept")
            .count(),
        files.len(),
        "every instance kept"
    );

    // A series received but not bricked when the server stopped is bricked
    // when it starts again.
    let _ = server.stop();
    std::fs::remove_dir_all(received.join("stores").join(format!("{series}.zarr")))
        .expect("remove the store");
    let again = voxserve_tests::server::Spawned::start(VOXSERVE, &serve)
        .await
        .unwrap_or_else(|stderr| panic!("serve exited: {stderr}"));
    wait_served(&http, &again.url, &series).await;
    let _ = again.stop();
}

/// Waits (up to 90 s) until the server at `url` serves dataset `id`, a
/// 512 × 512 × 234 volume.
async fn wait_served(http: &reqwest::Client, url: &str, id: &str) {
    let start = std::time::Instant::now();
    loop {
        let list = get_json(http, &format!("{url}/api/datasets")).await;
        let found = list
            .as_array()
            .expect("a list")
            .iter()
            .find(|d| d["id"] == id)
            .cloned();
        if let Some(d) = found {
            assert_eq!(d["dims"], serde_json::json!([512, 512, 234]), "{d}");
            return;
        }
        assert!(
            start.elapsed() < Duration::from_secs(90),
            "series {id} not served after 90 s: {list}"
        );
        tokio::time::sleep(Duration::from_millis(250)).await;
    }
}

/// dcmtk's `tool` (echoscu, storescu, dcmsend) if installed, else `None`
/// after saying why `test` is skipped.
fn dcmtk_or_skip(test: &str, tool: &str) -> Option<PathBuf> {
    let found = std::env::var_os("PATH").and_then(|paths| {
        std::env::split_paths(&paths)
            .map(|p| p.join(tool))
            .find(|p| p.is_file())
    });
    if found.is_none() {
        assert!(
            !std::env::var("VOXSERVE_REQUIRE_PACS").is_ok_and(|v| v == "1"),
            "{test}: VOXSERVE_REQUIRE_PACS=1 but dcmtk's {tool} is not installed (apt install dcmtk)"
        );
        voxserve_tests::gpu::report_skip(test, &format!("dcmtk's {tool} is not installed"));
    }
    found
}

/// Runs a dcmtk tool; its success and what it printed.
fn dcmtk(tool: &Path, args: &[&str]) -> (bool, String) {
    let out = Command::new(tool).args(args).output().expect("run dcmtk");
    (
        out.status.success(),
        format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        ),
    )
}

#[tokio::test(flavor = "multi_thread")]
async fn dcmtk_pushes_the_series_over_dicom_and_it_is_served_as_its_files_on_disk_are() {
    let test = "dcmtk_pushes_the_series_over_dicom_and_it_is_served_as_its_files_on_disk_are";
    let Some(data) = shared_data(test) else {
        return;
    };
    let (Some(echoscu), Some(storescu), Some(dcmsend)) = (
        dcmtk_or_skip(test, "echoscu"),
        dcmtk_or_skip(test, "storescu"),
        dcmtk_or_skip(test, "dcmsend"),
    ) else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let received = dir.path().join("received");
    let audit = dir.path().join("audit.jsonl");
    let serve = [
        "serve",
        "--addr",
        "127.0.0.1:0",
        "--phantom-size",
        "32",
        "--receive",
        received.to_str().expect("path"),
        "--receive-settle-s",
        "1",
        "--dicom-port",
        "0",
        "--ae-title",
        "VOXSERVE",
        "--dicom-allow",
        "MODALITY",
        "--dicom-allow",
        "ROUTER",
        "--audit-log",
        audit.to_str().expect("path"),
    ];
    // Without --dicom-allow, or without --receive, it does not start.
    let (ok, _, err) = voxserve(&serve[..14]);
    assert!(!ok && err.contains("--dicom-allow"), "{err}");
    let (ok, _, err) = voxserve(&["serve", "--dicom-port", "0", "--dicom-allow", "*"]);
    assert!(!ok && err.contains("--receive"), "{err}");
    let (ok, _, err) = voxserve(&["serve", "--ae-title", "A_TITLE_OF_17_CHR"]);
    assert!(!ok && err.contains("--ae-title"), "{err}");

    let server = voxserve_tests::server::Spawned::start(VOXSERVE, &serve)
        .await
        .unwrap_or_else(|stderr| panic!("serve exited: {stderr}"));
    let at = server
        .line
        .split("DICOM as VOXSERVE at ")
        .nth(1)
        .unwrap_or_else(|| panic!("no DICOM address in {:?}", server.line))
        .trim();
    let (host, port) = at.rsplit_once(':').expect("host:port");
    let scp = |caller: &'static str, called: &'static str| {
        vec![
            "-aet".to_owned(),
            caller.to_owned(),
            "-aec".to_owned(),
            called.to_owned(),
            host.to_owned(),
            port.to_owned(),
        ]
    };
    fn args(v: &[String]) -> Vec<&str> {
        v.iter().map(String::as_str).collect()
    }

    // A connection that says nothing, and one that speaks HTTP, hold up
    // no one.
    let silent = tokio::net::TcpStream::connect(at).await.expect("connect");
    let mut http = tokio::net::TcpStream::connect(at).await.expect("connect");
    tokio::io::AsyncWriteExt::write_all(&mut http, b"GET / HTTP/1.1\r\nHost: x\r\n\r\n")
        .await
        .expect("write");
    let mut answer = Vec::new();
    let read = tokio::time::timeout(
        Duration::from_secs(20),
        tokio::io::AsyncReadExt::read_to_end(&mut http, &mut answer),
    )
    .await;
    assert!(
        read.is_ok(),
        "a connection speaking HTTP is still open after 20 s"
    );

    // C-ECHO: answered for an allowed caller calling our title; refused
    // (and audited) otherwise.
    let (ok, out) = dcmtk(&echoscu, &args(&scp("MODALITY", "VOXSERVE")));
    assert!(ok, "echoscu: {out}");
    let (ok, out) = dcmtk(&echoscu, &args(&scp("INTRUDER", "VOXSERVE")));
    assert!(
        !ok && out.contains("Calling AE Title Not Recognized"),
        "echoscu from an AE title not allowed: {out}"
    );
    let (ok, out) = dcmtk(&echoscu, &args(&scp("MODALITY", "ELSEWHERE")));
    assert!(
        !ok && out.contains("Called AE Title Not Recognized"),
        "echoscu calling another AE title: {out}"
    );
    let vhf = data.join("dicom/vhf_head");
    let files = dicom_files(&vhf);
    let mut intruder = scp("INTRUDER", "VOXSERVE");
    intruder.push(files[0].to_string_lossy().into_owned());
    let (ok, out) = dcmtk(&storescu, &args(&intruder));
    assert!(!ok, "storescu from an AE title not allowed: {out}");
    assert_eq!(
        std::fs::read_dir(received.join("series"))
            .expect("series")
            .count(),
        0,
        "nothing kept from an association refused"
    );
    let log = std::fs::read_to_string(&audit).unwrap_or_default();
    assert!(
        log.lines()
            .any(|l| l.contains("\"associate\"") && l.contains("denied") && l.contains("INTRUDER")),
        "the refused association is audited, naming the calling AE title: {log}"
    );

    // dcmsend pushes the VHF head's series; once settled it is bricked,
    // served under its SeriesInstanceUID, and its store equals the one its
    // files make.
    let mut send = scp("MODALITY", "VOXSERVE");
    send.extend([
        "--scan-directories".to_owned(),
        vhf.to_string_lossy().into_owned(),
    ]);
    let (ok, out) = dcmtk(&dcmsend, &args(&send));
    assert!(ok, "dcmsend: {out}");
    let series = uid_of(&files[0], tags::SERIES_INSTANCE_UID);
    let http = reqwest::Client::new();
    wait_served(&http, &server.url, &series).await;
    let from_disk = dir.path().join("disk.zarr");
    ingest_to(&vhf, &from_disk);
    assert_same_store(
        &Store::open(received.join("stores").join(format!("{series}.zarr"))).expect("open"),
        &Store::open(&from_disk).expect("open"),
        true,
    );
    assert_eq!(
        std::fs::read_dir(received.join("series").join(&series))
            .expect("kept")
            .count(),
        files.len(),
        "every instance kept"
    );
    let log = std::fs::read_to_string(&audit).unwrap_or_default();
    assert!(
        log.lines().any(|l| l.contains("\"store\"")
            && l.contains("AE MODALITY")
            && l.contains(&format!("{} instance(s) stored", files.len()))),
        "the association that stored is audited: {log}"
    );
    drop(silent);
    let _ = server.stop();

    // Past --receive-max-mib, instances are refused (out of resources),
    // over DICOM and STOW-RS alike, and nothing more is kept.
    let small = dir.path().join("small");
    let small_serve = [
        "serve",
        "--addr",
        "127.0.0.1:0",
        "--phantom-size",
        "32",
        "--receive",
        small.to_str().expect("path"),
        "--receive-max-mib",
        "1",
        "--dicom-port",
        "0",
        "--dicom-allow",
        "*",
    ];
    let server = voxserve_tests::server::Spawned::start(VOXSERVE, &small_serve)
        .await
        .unwrap_or_else(|stderr| panic!("serve exited: {stderr}"));
    let at = server
        .line
        .split("DICOM as VOXSERVE at ")
        .nth(1)
        .expect("a DICOM address")
        .trim();
    let (host, port) = at.rsplit_once(':').expect("host:port");
    let mut five = vec!["-v", "-aet", "MODALITY", "-aec", "VOXSERVE", host, port];
    let names: Vec<String> = files[..5]
        .iter()
        .map(|f| f.to_string_lossy().into_owned())
        .collect();
    five.extend(names.iter().map(String::as_str));
    let (_, out) = dcmtk(&storescu, &five);
    assert!(
        out.contains("Refused: OutOfResources"),
        "storescu past the budget: {out}"
    );
    let kept = std::fs::read_dir(small.join("series"))
        .expect("series")
        .filter_map(Result::ok)
        .map(|s| std::fs::read_dir(s.path()).expect("series").count())
        .sum::<usize>();
    assert!(kept < 5, "{kept} instances kept past a 1 MiB budget");
    let answer = http
        .post(format!("{}/dicom-web/studies", server.url))
        .header(
            "content-type",
            "multipart/related; type=\"application/dicom\"; boundary=XX",
        )
        .body("--XX\r\nContent-Type: application/dicom\r\n\r\nx\r\n--XX--\r\n")
        .send()
        .await
        .expect("POST");
    assert_eq!(answer.status().as_u16(), 507);
    assert!(
        answer
            .text()
            .await
            .expect("body")
            .contains("--receive-max-mib")
    );
    let _ = server.stop();
}

/// `GET url`: its status and JSON body (`null` when not JSON).
async fn get_answer(http: &reqwest::Client, url: &str) -> (u16, serde_json::Value) {
    let answer = http.get(url).send().await.expect("GET");
    let status = answer.status().as_u16();
    let body = answer.bytes().await.expect("body");
    (status, serde_json::from_slice(&body).unwrap_or_default())
}

/// Waits (up to 90 s) for the job opening `series` to end; its last state.
async fn wait_opened(
    http: &reqwest::Client,
    url: &str,
    study: &str,
    series: &str,
) -> serde_json::Value {
    let start = std::time::Instant::now();
    loop {
        let (status, job) = get_answer(
            http,
            &format!("{url}/api/pacs/open?study={study}&series={series}"),
        )
        .await;
        assert_eq!(status, 200, "{job}");
        if job["state"] == "ready" || job["state"] == "failed" {
            return job;
        }
        assert!(
            start.elapsed() < Duration::from_secs(90),
            "series {series} still {job} after 90 s"
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
}

#[tokio::test(flavor = "multi_thread")]
async fn the_server_searches_the_pacs_opens_series_into_its_cache_and_refuses_bad_requests() {
    let test = "the_server_searches_the_pacs_opens_series_into_its_cache_and_refuses_bad_requests";
    let Some(data) = shared_data(test) else {
        return;
    };
    let Some(orthanc) = Orthanc::start_or_skip(test) else {
        return;
    };
    let http = reqwest::Client::new();
    let dir = tempfile::tempdir().expect("tempdir");
    // Two series of one study: the first 40 VHF slices, and the same
    // slices again as a second series (new series and instance UIDs).
    let vhf = dicom_files(&data.join("dicom/vhf_head"));
    let again = dir.path().join("again");
    std::fs::create_dir_all(&again).expect("folder");
    for (i, f) in vhf[..40].iter().enumerate() {
        orthanc.upload(&http, f).await;
        let mut obj = dicom_object::open_file(f).expect("open");
        for (tag, uid) in [
            (
                tags::SERIES_INSTANCE_UID,
                "1.2.826.0.1.3680043.2.1125.7.2".to_owned(),
            ),
            (
                tags::SOP_INSTANCE_UID,
                format!("1.2.826.0.1.3680043.2.1125.7.2.{}", i + 1),
            ),
            (tags::SERIES_NUMBER, "2".to_owned()),
        ] {
            let vr = if tag == tags::SERIES_NUMBER {
                dicom_core::VR::IS
            } else {
                dicom_core::VR::UI
            };
            obj.put(dicom_core::DataElement::new(
                tag,
                vr,
                dicom_core::PrimitiveValue::from(uid),
            ));
        }
        obj.update_meta(|m| {
            m.media_storage_sop_instance_uid = format!("1.2.826.0.1.3680043.2.1125.7.2.{}", i + 1);
        });
        let copy = again.join(format!("{i}.dcm"));
        obj.write_to_file(&copy).expect("write");
        orthanc.upload(&http, &copy).await;
    }
    let study = uid_of(&vhf[0], tags::STUDY_INSTANCE_UID);
    let first = uid_of(&vhf[0], tags::SERIES_INSTANCE_UID);
    let second = "1.2.826.0.1.3680043.2.1125.7.2";

    let cache = dir.path().join("cache");
    let orthanc_pacs = format!("orthanc={}/dicom-web", orthanc.url);
    let serve = [
        "serve",
        "--addr",
        "127.0.0.1:0",
        "--phantom-size",
        "32",
        "--pacs",
        &orthanc_pacs,
        "--pacs",
        "down=http://127.0.0.1:9/dicom-web",
        "--pacs-cache",
        cache.to_str().expect("path"),
        "--pacs-cache-mib",
        "1",
        "--renderer",
        "cpu",
    ];
    let (ok, _, err) = voxserve(&serve[..9]);
    assert!(!ok && err.contains("--pacs-cache"), "{err}");
    let server = voxserve_tests::server::Spawned::start(VOXSERVE, &serve)
        .await
        .unwrap_or_else(|stderr| panic!("serve exited: {stderr}"));
    let url = &server.url;

    // Search and list through the server.
    let (status, pacs) = get_answer(&http, &format!("{url}/api/pacs")).await;
    assert_eq!(
        (status, &pacs["pacs"]),
        (200, &serde_json::json!(["orthanc", "down"]))
    );
    let (status, found) = get_answer(
        &http,
        &format!("{url}/api/pacs/studies?PatientID=000-000-001"),
    )
    .await;
    assert_eq!(status, 200, "{found}");
    assert_eq!(found[0]["study_uid"], study.as_str(), "{found}");
    let (status, found) = get_answer(
        &http,
        &format!("{url}/api/pacs/studies?StudyDate=20050101-20050102&ModalitiesInStudy=CT"),
    )
    .await;
    assert_eq!(
        (status, found.as_array().map(Vec::len)),
        (200, Some(1)),
        "{found}"
    );
    let (status, series) = get_answer(&http, &format!("{url}/api/pacs/series?study={study}")).await;
    assert_eq!(status, 200, "{series}");
    assert_eq!(series.as_array().map(Vec::len), Some(2), "{series}");
    assert!(
        series
            .as_array()
            .expect("list")
            .iter()
            .all(|s| s["volume"] == true && s["instances"] == 40)
    );

    // A series' thumbnail, as the PACS renders it, within 96².
    let answer = http
        .get(format!(
            "{url}/api/pacs/thumbnail?study={study}&series={first}"
        ))
        .send()
        .await
        .expect("GET");
    assert_eq!(answer.status().as_u16(), 200);
    let png = answer.bytes().await.expect("body");
    let thumb = image::load_from_memory_with_format(&png, image::ImageFormat::Png).expect("a PNG");
    assert!(thumb.width() <= 96 && thumb.height() <= 96 && thumb.width() > 0);

    // Bad requests: named, not passed on.
    for (path, status, words) in [
        ("/api/pacs/studies?StudyDate=2005-01-01", 400, "StudyDate"),
        (
            "/api/pacs/studies?pacs=elsewhere",
            404,
            "expected one of orthanc, down",
        ),
        ("/api/pacs/studies?limit=5000", 400, "limit"),
        ("/api/pacs/series?study=1..2", 400, "study"),
        ("/api/pacs/thumbnail?study=1.2&series=", 400, "series"),
        ("/api/pacs/studies?pacs=down", 502, "down"),
        ("/api/pacs/iid?requestType=SERIES", 400, "STUDY or PATIENT"),
        (
            "/api/pacs/iid?requestType=STUDY&studyUID=1.2.3",
            404,
            "not found on PACS orthanc",
        ),
        (
            "/api/pacs/iid?requestType=PATIENT&patientID=nobody",
            404,
            "patient nobody",
        ),
    ] {
        let (got, body) = get_answer(&http, &format!("{url}{path}")).await;
        assert_eq!(got, status, "{path}: {body}");
        assert!(
            body["error"].as_str().is_some_and(|e| e.contains(words)),
            "{path}: {body}, expected {words:?}"
        );
    }
    // An IID launch is checked, then sent to the viewer with its query.
    let launch = reqwest::Client::builder()
        .redirect(reqwest::redirect::Policy::none())
        .build()
        .expect("client");
    let answer = launch
        .get(format!(
            "{url}/IHEInvokeImageDisplay?requestType=STUDY&studyUID={study}"
        ))
        .send()
        .await
        .expect("GET");
    assert_eq!(answer.status().as_u16(), 303);
    let location = answer.headers()["location"]
        .to_str()
        .expect("text")
        .to_owned();
    assert!(
        location.starts_with("/#iid=requestType%3DSTUDY%26studyUID%3D"),
        "{location}"
    );
    let answer = launch
        .get(format!("{url}/IHEInvokeImageDisplay?requestType=PATIENT"))
        .send()
        .await
        .expect("GET");
    assert_eq!(answer.status().as_u16(), 400);
    assert!(answer.text().await.expect("page").contains("patientID"));
    let (status, resolved) = get_answer(
        &http,
        &format!("{url}/api/pacs/iid?requestType=PATIENT&patientID=000-000-001&mostRecentResults=1&modalitiesInStudy=CT,MR"),
    )
    .await;
    assert_eq!(status, 200, "{resolved}");
    assert_eq!(
        resolved["studies"].as_array().map(Vec::len),
        Some(1),
        "{resolved}"
    );

    // A series the PACS does not hold: the job fails naming it; nothing
    // is served or left in the cache.
    let missing = "1.2.826.0.1.3680043.2.1125.7.3";
    let open = |series: &str| {
        http.post(format!("{url}/api/pacs/open?study={study}&series={series}"))
            .send()
    };
    assert_eq!(open(missing).await.expect("POST").status().as_u16(), 200);
    let job = wait_opened(&http, url, &study, missing).await;
    assert_eq!(job["state"], "failed", "{job}");
    assert!(
        job["error"].as_str().is_some_and(|e| e.contains(missing)),
        "{job}"
    );
    let left: Vec<_> = std::fs::read_dir(&cache).expect("cache").collect();
    assert!(left.is_empty(), "left in the cache: {left:?}");

    // Opened: fetched, bricked, served, and the same as its files make.
    assert_eq!(open(&first).await.expect("POST").status().as_u16(), 200);
    let job = wait_opened(&http, url, &study, &first).await;
    assert_eq!(job["state"], "ready", "{job}");
    assert_eq!(job["fetched"], 40, "{job}");
    let from_disk = dir.path().join("disk.zarr");
    let forty = dir.path().join("forty");
    std::fs::create_dir_all(&forty).expect("folder");
    for f in &vhf[..40] {
        std::fs::copy(f, forty.join(f.file_name().expect("name"))).expect("copy");
    }
    ingest_to(&forty, &from_disk);
    assert_same_store(
        &Store::open(cache.join(format!("{first}.zarr"))).expect("open"),
        &Store::open(&from_disk).expect("open"),
        true,
    );
    let render = |id: String| {
        let http = http.clone();
        async move {
            let answer = http
                .get(format!("{url}/api/datasets/{id}/render?w=64&h=64"))
                .send()
                .await
                .expect("GET");
            let status = answer.status().as_u16();
            (status, answer.text().await.unwrap_or_default())
        }
    };
    let (status, body) = render(first.clone()).await;
    assert_eq!(status, 200, "{body}");
    assert!(
        !cache.join(".preview").exists(),
        "no preview of a series of 40 images"
    );
    // A second series past the 1 MiB budget: the first, used least
    // recently, is removed and no longer offered.
    assert_eq!(open(second).await.expect("POST").status().as_u16(), 200);
    let job = wait_opened(&http, url, &study, second).await;
    assert_eq!(job["state"], "ready", "{job}");
    let list = get_json(&http, &format!("{url}/api/datasets")).await;
    let ids: Vec<&str> = list
        .as_array()
        .expect("list")
        .iter()
        .filter_map(|d| d["id"].as_str())
        .collect();
    assert!(
        ids.contains(&second) && !ids.contains(&first.as_str()),
        "{ids:?}"
    );
    assert!(!cache.join(format!("{first}.zarr")).exists());
    // Opened again, it is fetched anew and drawn from its new store (not
    // from the blocks of the one removed).
    assert_eq!(open(&first).await.expect("POST").status().as_u16(), 200);
    let job = wait_opened(&http, url, &study, &first).await;
    assert_eq!(job["state"], "ready", "{job}");
    let (status, body) = render(first.clone()).await;
    assert_eq!(status, 200, "the series opened again: {body}");
    let _ = server.stop();
}
