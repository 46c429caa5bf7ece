//! The parts of the `nmat` command that read untrusted input and write decoded maps, as a library
//! so the fuzz target `cli` can drive them without a process per input. Not a stable API: use
//! `nmat-core` (Rust) or the C API to read .nmat files from an application.

pub mod gpu_files;
pub mod input;
pub mod output;
pub mod progress;
pub mod transcode;

use std::path::Path;

/// The command's input paths that need no training, on any bytes (the body of the fuzz target
/// `cli`, and of the test that replays `fuzz/regressions/cli/`): the header checks of `nmat
/// info/decode/eval/bench`, the SOURCE_MAPS section, `nmat info`'s description and `nmat
/// decode`'s plan (and, for a small material, its maps written to a temporary folder), `nmat
/// transcode`'s textures and file names (and, for a small material, their KTX2 and DDS bytes), and a map
/// image decoded as `nmat encode` loads it, with a 64 MiB budget. Each ends in a result or an
/// error; a panic is a bug.
#[doc(hidden)]
pub fn exercise_untrusted(data: &[u8]) {
    use nmat_core::{Container, ParseOptions};
    let _ = input::check_head(data.get(..input::HEAD).unwrap_or(data), data.len() as u64);
    let _ = nmat_encode::source_maps::decode(data);
    if let Ok(m) = Container::parse_with(data, ParseOptions { verify_checksum: false }) {
        let _ = output::describe(Path::new("fuzz.nmat"), &m);
        let all: Vec<u32> = (0..m.mip_count()).collect();
        for (mips, png) in [(&[0][..], false), (&all[..], true)] {
            let Ok(plan) = output::DecodePlan::new(&m, mips, png) else { continue };
            if png {
                exercise_transcode(&m, plan.cost(&m).texels <= 1024);
            }
            let _ = (plan.file_names(), plan.memory(&m));
            if plan.cost(&m).texels <= 1024 {
                let name = format!("nmat-untrusted-{}", std::process::id());
                let dir = std::env::temp_dir().join(name);
                let with = output::DecodeWith::default();
                let _ = output::write_all_or_nothing(&dir, |d| {
                    output::write_maps(&m, &plan, d, with, &mut |_| {})
                });
                let _ = std::fs::remove_dir_all(&dir);
            }
        }
    }
    let _ = nmat_encode::texset::decode_image(data, Path::new("map"), 64 << 20);
}

/// `nmat transcode` on an untrusted material: the plan and file names always, the files' bytes
/// when `small`.
fn exercise_transcode(m: &nmat_core::Material<'_>, small: bool) {
    use transcode::{Choice, Container};
    let choice = Choice { all: Some(nmat_core::bc::BcFormat::Bc7Rgb), by_semantic: Vec::new() };
    for choice in [Choice::default(), choice] {
        let plan = transcode::plan(m, &choice);
        let decoder = nmat_core::Decoder::new(m);
        for named in &plan {
            let _ = transcode::file_name(named, Container::Ktx2);
        }
        let textures: Vec<_> = plan.iter().map(|n| n.texture).collect();
        if small && let Ok(images) = transcode::transcode(m, &decoder, &textures, &mut |_| {}) {
            for image in &images {
                let _ = (Container::Ktx2.bytes(image), Container::Dds.bytes(image));
            }
        }
    }
}
