//! `voxserve bench read`: the raw reader's throughput on a generated volume,
//! every voxel checked.

use std::path::PathBuf;
use std::time::Instant;

use blocks::ingest;

use super::args::BenchReadArgs;
use super::{peak_rss_mib, write_uint16_raw};
use server::commands::say;

/// `voxserve bench read`: writes a generated uint16 volume of N GiB to a
/// temporary raw file, reads it back slab by slab through the raw reader, checks
/// every voxel's value, and reports MB/s and the process's peak memory.
pub fn read(args: &BenchReadArgs) -> anyhow::Result<()> {
    let gib = args.gib;
    const NX: u32 = 2048;
    const NY: u32 = 2048;
    let slice_bytes = u64::from(NX) * u64::from(NY) * 2;
    let nz = ((f64::from(gib) * f64::from(1u32 << 30)) / slice_bytes as f64)
        .ceil()
        .max(1.0) as u32;
    let path = std::env::temp_dir().join(format!(
        "voxserve-bench-{}_{NX}x{NY}x{nz}_uint16.raw",
        std::process::id()
    ));
    // The file goes away however this function ends.
    struct Remove(PathBuf);
    impl Drop for Remove {
        fn drop(&mut self) {
            let _ = std::fs::remove_file(&self.0);
        }
    }
    let _remove = Remove(path.clone());
    // Voxel (x, y, z) holds (x + 3y + 7z) mod 65536: cheap to generate and to check.
    let value =
        |x: u32, y: u32, z: u32| (x.wrapping_add(3 * y).wrapping_add(7 * z) & 0xffff) as u16;
    let start = Instant::now();
    write_uint16_raw(&path, [NX, NY, nz], value)?;
    let write_s = start.elapsed().as_secs_f64();
    let total = slice_bytes * u64::from(nz);

    let mut source = ingest::open(&path, &ingest::OpenOptions::default())?;
    let depth = ingest::slab_depth(source.info());
    let start = Instant::now();
    let mut z = 0;
    let mut mismatches = 0u64;
    while z < nz {
        let d = depth.min(nz - z);
        let slab = source.read_slab(z, d)?;
        let blocks::VoxelData::U16(v) = slab else {
            anyhow::bail!(
                "the raw reader returned {} voxels, expected uint16",
                slab.voxel_type().name()
            );
        };
        for (i, &got) in v.iter().enumerate() {
            let i = i as u64;
            let (x, y, zz) = (
                (i % u64::from(NX)) as u32,
                ((i / u64::from(NX)) % u64::from(NY)) as u32,
                z + (i / (u64::from(NX) * u64::from(NY))) as u32,
            );
            mismatches += u64::from(got != value(x, y, zz));
        }
        z += d;
    }
    let read_s = start.elapsed().as_secs_f64();
    if mismatches > 0 {
        anyhow::bail!("{mismatches} voxels read back wrong");
    }
    let mb = total as f64 / 1e6;
    say(&serde_json::json!({
        "bench": "read",
        "format": "raw",
        "dims": [NX, NY, nz],
        "voxel_type": "uint16",
        "bytes": total,
        "slab_bytes": u64::from(depth) * slice_bytes,
        "write_mb_s": mb / write_s,
        "read_mb_s": mb / read_s,
        "verified_voxels": total / 2,
        "peak_rss_mib": peak_rss_mib(),
    })
    .to_string())
}
