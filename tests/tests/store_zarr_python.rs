//! A brick store opens in zarr-python: the OME-Zarr 0.5 metadata, every level's
//! shape and voxels, and the statistics arrays read the same there as here.
//!
//! Needs `python3` with `zarr` 3 (installed by `.ci/prereqs test`). Without it
//! the test says so and skips, unless `VOXSERVE_REQUIRE_ZARR_PYTHON=1` (CI).

use std::process::Command;
use std::sync::Arc;

use blocks::ingest::MemorySource;
use blocks::store::{self, IngestOptions, LEVELS, Store, level_dims};
use voxserve_tests::gpu::report_skip;

#[test]
fn a_store_reads_the_same_in_zarr_python() {
    let test = "a_store_reads_the_same_in_zarr_python";
    let has_zarr = Command::new("python3")
        .args([
            "-c",
            "import zarr, sys; sys.exit(0 if int(zarr.__version__.split('.')[0]) >= 3 else 1)",
        ])
        .status()
        .is_ok_and(|s| s.success());
    if !has_zarr {
        if std::env::var("VOXSERVE_REQUIRE_ZARR_PYTHON").is_ok_and(|v| v == "1") {
            panic!("{test}: VOXSERVE_REQUIRE_ZARR_PYTHON=1 but python3 with zarr 3 is missing");
        }
        report_skip(test, "python3 with zarr 3 is not installed");
        return;
    }
    let dir = tempfile::tempdir().expect("temp");
    let phantom = Arc::new(blocks::phantom::head(40).expect("phantom"));
    let path = dir.path().join("phantom.zarr");
    let mut source = MemorySource::new(phantom.clone(), "phantom-40");
    store::ingest(&mut source, &path, &IngestOptions::default(), &mut |_| {}).expect("ingest");
    let store = Store::open(&path).expect("open");

    let script = r#"
import json, sys
import numpy as np
import zarr
g = zarr.open_group(sys.argv[1], mode="r")
ome = g.attrs["ome"]
ms = ome["multiscales"][0]
out = {"version": ome["version"], "axes": [a["name"] for a in ms["axes"]], "levels": []}
for d in ms["datasets"]:
    a = g[d["path"]]
    v = a[:]
    out["levels"].append({"path": d["path"], "shape": list(a.shape), "dtype": str(a.dtype),
        "sum": int(v.astype(np.int64).sum()), "first": int(v.flat[0]),
        "scale": d["coordinateTransformations"][0]["scale"]})
out["histogram_shape"] = list(g["voxserve/block_histogram"].shape)
out["histogram_sum_level0"] = int(g["voxserve/block_histogram"][0].astype(np.int64).sum())
out["complete"] = g.attrs["voxserve"]["complete"]
print(json.dumps(out))
"#;
    let out = Command::new("python3")
        .args(["-c", script, path.to_str().expect("utf-8")])
        .output()
        .expect("python3");
    assert!(
        out.status.success(),
        "zarr-python failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON from python");
    assert_eq!(json["version"], "0.5");
    assert_eq!(json["axes"], serde_json::json!(["z", "y", "x"]));
    assert_eq!(json["complete"], true);
    for level in 0..LEVELS {
        let l = &json["levels"][level];
        let [x, y, z] = level_dims([40; 3], level);
        assert_eq!(l["shape"], serde_json::json!([z, y, x]), "level {level}");
        assert_eq!(l["dtype"], "uint16");
        // The sum of every voxel of the level, read here block by block.
        let mut sum = 0i64;
        let grid = store.chunk_grid(level);
        for cz in 0..grid[2] {
            for cy in 0..grid[1] {
                for cx in 0..grid[0] {
                    let chunk = store.read_chunk(level, [cx, cy, cz]).expect("chunk");
                    for (i, v) in (0..chunk.len()).map(|i| (i, chunk.get(i))) {
                        let p = [
                            cx * 16 + (i % 16) as u32,
                            cy * 16 + ((i / 16) % 16) as u32,
                            cz * 16 + (i / 256) as u32,
                        ];
                        if p[0] < x && p[1] < y && p[2] < z {
                            sum += v as i64;
                        }
                    }
                }
            }
        }
        assert_eq!(l["sum"], sum, "level {level}");
        let spacing = phantom.geometry.spacing[0] * f64::from(1u32 << level);
        assert!(
            (l["scale"][0].as_f64().unwrap_or(0.0) - spacing).abs() < 1e-9,
            "level {level} scale"
        );
    }
    assert_eq!(
        l0_voxels(&json),
        40 * 40 * 40,
        "level-0 histograms count every voxel"
    );
    assert_eq!(json["histogram_shape"], serde_json::json!([5, 3, 3, 3, 32]));
}

fn l0_voxels(json: &serde_json::Value) -> i64 {
    json["histogram_sum_level0"].as_i64().unwrap_or(-1)
}
