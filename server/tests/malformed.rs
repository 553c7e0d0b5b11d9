//! The real `voxserve` binary on a corpus of malformed and hostile files
//! ([`voxserve_tests::malformed`]): each must end in a clear error — a normal
//! failure (exit 1, not a panic's 101 or a signal) whose message names the
//! file and the field, with no Rust debug text — within [`TIME_LIMIT_S`]
//! seconds and [`MEMORY_LIMIT_MIB`] MiB of peak memory.
//!
//! Peak memory is the child's maximum resident set, as GNU time (`time`
//! package) reports it; the time limit is coreutils' `timeout`.

use std::path::{Path, PathBuf};
use std::process::Command;

use voxserve_tests::malformed::{self, Case, Run};

const VOXSERVE: &str = env!("CARGO_BIN_EXE_voxserve");
/// Seconds one run may take.
const TIME_LIMIT_S: u32 = 20;
/// Peak resident memory one run may reach, MiB: far below the gigabytes a
/// reader that trusts a header's length would allocate.
const MEMORY_LIMIT_MIB: u64 = 512;
/// Text that shows Rust's debug formatting or a crash rather than a message.
const DEBUG_TEXT: [&str; 6] = [
    "Error {",
    "Os {",
    "kind:",
    "panicked at",
    "RUST_BACKTRACE",
    "Custom {",
];

/// What one run of the binary gave.
#[derive(Debug)]
struct Outcome {
    code: Option<i32>,
    stderr: String,
    peak_mib: u64,
}

/// Runs `voxserve ARGS` under `timeout` and GNU time.
fn run(args: &[String], scratch: &Path) -> Outcome {
    let rss = scratch.join("max-rss-kib");
    let time = Path::new("/usr/bin/time");
    assert!(
        time.is_file(),
        "GNU time is needed to measure peak memory: install the `time` package"
    );
    let out = Command::new(time)
        .args(["-f", "%M", "-o"])
        .arg(&rss)
        .args(["timeout", "-s", "KILL", &TIME_LIMIT_S.to_string(), VOXSERVE])
        .args(args)
        .env("NO_COLOR", "1")
        .env_remove("RUST_BACKTRACE")
        .output()
        .unwrap_or_else(|e| panic!("running voxserve {args:?}: {e}"));
    let report = std::fs::read_to_string(&rss).unwrap_or_default();
    // GNU time writes "Command exited with non-zero status N" before the number.
    let peak_kib: u64 = report
        .lines()
        .filter_map(|l| l.trim().parse().ok())
        .next_back()
        .unwrap_or(0);
    Outcome {
        code: out.status.code(),
        stderr: String::from_utf8_lossy(&out.stderr).into_owned(),
        peak_mib: peak_kib / 1024,
    }
}

/// What is wrong with `outcome` for `case`, if anything.
fn judge(case: &Case, command: &str, outcome: &Outcome) -> Option<String> {
    let name = case
        .input
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let mut faults = Vec::new();
    match outcome.code {
        Some(1) => {}
        Some(124 | 137) => faults.push(format!("no answer within {TIME_LIMIT_S} s (killed)")),
        Some(101) => faults.push("panicked (exit 101)".to_owned()),
        Some(0) => faults.push("accepted (exit 0)".to_owned()),
        other => faults.push(format!("exit status {other:?}")),
    }
    if outcome.peak_mib > MEMORY_LIMIT_MIB {
        faults.push(format!(
            "peak memory {} MiB, over {MEMORY_LIMIT_MIB} MiB",
            outcome.peak_mib
        ));
    }
    let expected_words = case.expect.iter().map(String::as_str);
    for word in std::iter::once(name.as_str()).chain(expected_words) {
        if !outcome.stderr.contains(word) {
            faults.push(format!("the error does not say '{word}'"));
        }
    }
    for debug in DEBUG_TEXT {
        if outcome.stderr.contains(debug) {
            faults.push(format!("the error shows '{debug}'"));
        }
    }
    (!faults.is_empty()).then(|| {
        format!(
            "{} ({command}): {}\n    stderr: {}",
            case.name,
            faults.join("; "),
            outcome.stderr.trim().replace('\n', "\n            ")
        )
    })
}

/// The arguments of `command` on `case`.
fn arguments(case: &Case, command: &str, store: &Path) -> Vec<String> {
    let mut args = vec![command.to_owned(), case.input.display().to_string()];
    if command == "ingest" {
        args.extend(["--out".to_owned(), store.display().to_string()]);
    }
    args.extend(case.args.iter().cloned());
    args
}

#[test]
fn every_malformed_file_gets_a_clear_error_in_bounded_time_and_memory() {
    let dir = tempfile::tempdir().expect("temp dir");
    let files = dir.path().join("corpus");
    std::fs::create_dir_all(&files).expect("corpus folder");
    let mut cases = malformed::corpus(&files);
    cases.extend(real_rle_file_with_a_flipped_byte(dir.path()));
    assert!(cases.len() >= 60, "only {} cases", cases.len());
    let mut failures = Vec::new();
    let mut runs = 0;
    for case in &cases {
        let commands: &[&str] = match case.run {
            Run::Info => &["info"],
            Run::InfoAndIngest => &["info", "ingest"],
            Run::InfoAndVerify => &["info", "verify"],
            Run::Verify => &["verify"],
        };
        for command in commands {
            let store = dir.path().join(format!("store-{runs}"));
            let outcome = run(&arguments(case, command, &store), dir.path());
            runs += 1;
            failures.extend(judge(case, command, &outcome));
            if store.exists() {
                failures.push(format!("{} (ingest): wrote a store", case.name));
            }
        }
    }
    assert!(
        failures.is_empty(),
        "{} of {runs} runs on {} malformed inputs went wrong:\n{}",
        failures.len(),
        cases.len(),
        failures.join("\n")
    );
}

/// The real RLE file of the shared data with the byte found by fuzzing
/// flipped (`transfer_syntaxes/4.dcm`, 0x7f at offset 273422), when the data
/// is there.
fn real_rle_file_with_a_flipped_byte(dir: &Path) -> Option<Case> {
    let data = voxserve_tests::data::shared_data("real_rle_file_with_a_flipped_byte")?;
    let mut bytes = std::fs::read(data.join("dicom/transfer_syntaxes/4.dcm")).ok()?;
    *bytes.get_mut(273_422)? = 0x7f;
    let path: PathBuf = dir.join("4-flipped.dcm");
    malformed::write(&path, &bytes);
    Some(Case {
        name: "4-flipped.dcm (shared data)".to_owned(),
        input: path,
        args: Vec::new(),
        run: Run::InfoAndIngest,
        expect: vec!["RLE Lossless".to_owned()],
    })
}

#[test]
fn a_large_dicom_slice_decodes_in_a_few_bytes_per_pixel() {
    // 8192² 8-bit pixels: 64 MiB. At 16 bytes per pixel, decoding alone
    // would take 1 GiB.
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("large.dcm");
    let side = 8192u16;
    malformed::dicom_slice(&path, side, side, malformed::EXPLICIT_LE, |obj| {
        use dicom_like::*;
        eight_bit(obj, usize::from(side) * usize::from(side));
    });
    let outcome = run(&["info".to_owned(), path.display().to_string()], dir.path());
    assert_eq!(outcome.code, Some(0), "{}", outcome.stderr);
    assert!(
        outcome.peak_mib < MEMORY_LIMIT_MIB,
        "decoding one 64 MiB slice took {} MiB",
        outcome.peak_mib
    );
}

/// Turning the generated 16-bit slice into an 8-bit one.
mod dicom_like {
    use dicom_core::{DataElement, PrimitiveValue, VR};
    use dicom_dictionary_std::tags;
    use dicom_object::InMemDicomObject;

    /// Makes `obj` hold `pixels` 8-bit pixels.
    pub fn eight_bit(obj: &mut InMemDicomObject, pixels: usize) {
        for (tag, value) in [
            (tags::BITS_ALLOCATED, 8u16),
            (tags::BITS_STORED, 8),
            (tags::HIGH_BIT, 7),
        ] {
            obj.put(DataElement::new(tag, VR::US, PrimitiveValue::from(value)));
        }
        let bytes: Vec<u8> = (0..pixels).map(|i| (i % 251) as u8).collect();
        obj.put(DataElement::new(
            tags::PIXEL_DATA,
            VR::OB,
            PrimitiveValue::U8(bytes.into()),
        ));
    }
}
