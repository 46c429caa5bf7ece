//! Prints the training PSNR as it goes, to diagnose schedules:
//! `cargo run --release -p nmat-encode --example train_trace -- DIR PROFILE STEPS`.

use nmat_encode::texset::{self, LoadOptions};
use nmat_encode::{EncodeOptions, Profile, TrainOptions, encode};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let files = texset::collect_inputs(&[args[0].clone().into()]).unwrap();
    let set =
        texset::load(&texset::assign_roles(&files, &[]).unwrap(), &LoadOptions::default()).unwrap();
    let profile = Profile::by_name(&args[1]).unwrap();
    let steps: usize = args[2].parse().unwrap();
    let train = TrainOptions { steps, ..TrainOptions::default() };
    let out =
        encode(&set, &EncodeOptions { profile, train, ..EncodeOptions::default() }, &mut |p| {
            if p.step % (steps / 20).max(1) < (steps / 100).max(1) {
                println!("step {:6} {:?} train PSNR {:.2}", p.step, p.phase, p.psnr);
            }
        })
        .unwrap();
    println!("final (integer decoder, whole chain): {:.2} dB", out.quality.psnr);
}
