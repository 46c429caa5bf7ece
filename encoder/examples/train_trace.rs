//! Prints the training PSNR as it goes, to diagnose schedules:
//! `cargo run --release -p nmat-encode --example train_trace -- DIR PROFILE STEPS`.

use nmat_encode::texset::{self, LoadOptions};
use nmat_encode::{EncodeOptions, Profile, TrainOptions, encode};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [dir, profile, steps] = &args[..] else {
        eprintln!("usage: train_trace DIR PROFILE STEPS");
        std::process::exit(2);
    };
    let fail = |e: &dyn std::fmt::Display| -> ! {
        eprintln!("train_trace: {e}");
        std::process::exit(1)
    };
    let files = texset::collect_inputs(&[dir.into()]).unwrap_or_else(|e| fail(&e));
    let roles = texset::assign_roles(&files, &[]).unwrap_or_else(|e| fail(&e));
    let set = texset::load(&roles, &LoadOptions::default()).unwrap_or_else(|e| fail(&e));
    let profile = Profile::by_name(profile).unwrap_or_else(|| fail(&"unknown profile"));
    let steps: usize = steps.parse().unwrap_or_else(|e| fail(&e));
    let train = TrainOptions { steps, ..TrainOptions::default() };
    let out =
        encode(&set, &EncodeOptions { profile, train, ..EncodeOptions::default() }, &mut |p| {
            if p.step % (steps / 20).max(1) < (steps / 100).max(1) {
                println!("step {:6} {:?} train PSNR {:.2}", p.step, p.phase, p.psnr);
            }
        })
        .unwrap_or_else(|e| fail(&e));
    println!(
        "final (integer decoder, whole chain): {:.2} dB at {:.4} BPPC on disk",
        out.quality.psnr, out.quality.bppc
    );
}
