//! The parts of the `nmat` command that read untrusted input and write decoded maps, as a library
//! so the fuzz target `cli` can drive them without a process per input. Not a stable API: use
//! `nmat-core` (Rust) or the C API to read .nmat files from an application.

pub mod gpu_files;
pub mod input;
pub mod manifest;
pub mod output;
pub mod progress;
pub mod report;
pub mod stats;
pub mod transcode;

use std::path::Path;

/// Materials of at most this many texels (over the mips a plan decodes) also have their maps
/// written and their textures transcoded to KTX2/DDS bytes by [`exercise_untrusted`]: each texel
/// costs a network evaluation (and BC7's partition search) under the fuzzer's instrumentation.
/// Materials this small reach the paths of both (several block rows and columns, partial blocks,
/// mip chains; an 8×8 material's mip 0), except `transcode::transcode`'s second batch of 16 block
/// rows, which `transcode_writes_ktx2_and_dds_that_independent_readers_accept` (cli/tests) covers
/// with a 96×80 material.
const SMALL_TEXELS: u64 = 64;

/// The image budget of [`exercise_untrusted`]: 341 texels at 48 bytes each. An image that
/// declares more is refused (the `--max-memory` path) once its header is read, before its pixels
/// are decoded: the pixel decoders are other projects' code (fuzzed there), and decoding the
/// 37×21 JPEG seed took half of the fuzzer's time. The 8×8 PNG seeds decode; a JPEG does once
/// the fuzzer shrinks its declared size.
const IMAGE_BUDGET: u64 = 16 << 10;

/// The command's input paths that need no training, on any bytes (the body of the fuzz target
/// `cli`, and of the test that replays `fuzz/regressions/cli/`): the header checks of `nmat
/// info/decode/eval/bench`, unpacking a packed file, the SOURCE_MAPS section (and the warning for a damaged one), the
/// channel names made safe, `nmat info`'s description and `nmat
/// decode`'s plan (and, for a material of at most [`SMALL_TEXELS`] texels, its maps written to a
/// scratch folder), `nmat transcode`'s textures and file names (and, for such a small material,
/// their KTX2 and DDS bytes), and a map image decoded as `nmat encode` loads it, with a 16 KiB
/// budget. Each ends in a result or an error; a panic is a bug.
#[doc(hidden)]
pub fn exercise_untrusted(data: &[u8]) {
    use nmat_core::{Container, ParseOptions};
    let _ = input::check_head(data.get(..input::HEAD).unwrap_or(data), data.len() as u64);
    let _ = nmat_encode::source_maps::decode(data);
    let options = ParseOptions { verify_checksum: false };
    // A packed file is unpacked first, as `input::read_nmat` does (up to 1 MiB here).
    let unpacked = match nmat_core::unpacked_len(data) {
        Ok(Some(n)) if n <= 1 << 20 => nmat_core::unpack(data, options).ok(),
        _ => None,
    };
    let stored = input::Stored::of(data, unpacked.is_some());
    let data = unpacked.as_deref().unwrap_or(data);
    if let Ok(m) = Container::parse_with(data, options) {
        let stored = if stored.packed { stored } else { input::Stored::fixed(&m) };
        let _ = output::describe(Path::new("fuzz.nmat"), &m, stored);
        let _ = output::damaged_sections(Path::new("fuzz.nmat"), &m);
        for c in m.channels() {
            let _ =
                (nmat_encode::names::for_terminal(c.name), nmat_encode::names::file_name(c.name));
        }
        let all: Vec<u32> = (0..m.mip_count()).collect();
        for (mips, png) in [(&[0][..], false), (&all[..], true)] {
            let Ok(plan) = output::DecodePlan::new(&m, mips, png) else { continue };
            let small = plan.cost(&m).texels <= SMALL_TEXELS;
            if png {
                exercise_transcode(&m, small);
            }
            let _ = (plan.file_names(), plan.memory(&m));
            if small {
                let dir = scratch_dir();
                let with = output::DecodeWith::default();
                let _ = output::write_all_or_nothing(&dir, |d| {
                    output::write_maps(&m, &plan, d, with, &mut |_| {})
                });
                let _ = std::fs::remove_dir_all(&dir);
            }
        }
    }
    let _ = nmat_encode::texset::decode_image(data, Path::new("map"), IMAGE_BUDGET);
}

/// A folder of this process for [`exercise_untrusted`]'s maps, on tmpfs where there is one: the
/// maps are written as `nmat decode` writes them, each file synced to its disk (`write_atomic`),
/// which on a real disk takes milliseconds per file and on tmpfs nothing.
fn scratch_dir() -> std::path::PathBuf {
    let shm = Path::new("/dev/shm");
    let base = if shm.is_dir() { shm.to_path_buf() } else { std::env::temp_dir() };
    base.join(format!("nmat-untrusted-{}", std::process::id()))
}

/// `nmat transcode` on an untrusted material: the plan and file names always (each map's own
/// formats, and `--format bc7`), the files' bytes when `small` — for BC7 only when mip 0 is one
/// block: BC7's partition search over an instrumented build took 57 % of the fuzzer's time on a
/// grown corpus (perf, 2026-11-27), and BC7's encoder is tested on its own (core-nostd's bc
/// tests); what the fuzzer is after here is the plan, the file names and the containers' bytes.
fn exercise_transcode(m: &nmat_core::Material<'_>, small: bool) {
    use transcode::{Choice, Container};
    let bc7 = Choice { all: Some(nmat_core::bc::BcFormat::Bc7Rgb), by_semantic: Vec::new() };
    let (w, h) = m.mip_size(0);
    let one_block = w <= 4 && h <= 4;
    // Prepared once, and only when it is used: for a large material it is most of the cost.
    let decoder = small.then(|| nmat_core::Decoder::new(m));
    for (choice, encode) in [(Choice::default(), true), (bc7, one_block)] {
        let plan = transcode::plan(m, &choice);
        for named in &plan {
            let _ = transcode::file_name(named, Container::Ktx2);
        }
        let textures: Vec<_> = plan.iter().map(|n| n.texture).collect();
        if let Some(decoder) = decoder.as_ref().filter(|_| encode)
            && let Ok(images) = transcode::transcode(m, decoder, &textures, &mut |_| {})
        {
            for image in &images {
                let _ = (Container::Ktx2.bytes(image), Container::Dds.bytes(image));
            }
        }
    }
}
